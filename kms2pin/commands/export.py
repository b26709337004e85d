"""Write <system>.urdf, <system>.srdf and the mesh they use (``--format urdf``, the
default), or <system>.xml for MuJoCo (``--format mjcf``), for every system of a spec."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..mesh import MESH_NAME, sphere_obj
from ..mjcf import to_mjcf
from ..robot import Robot
from ..urdf import MESH_DIR
from ._common import add_spec_argument, read_model, write_outputs
from ._outputs import owns_output

NAME = "export"
HELP = "compile a spec to URDF + SRDF, or to MuJoCo's MJCF (default output folder urdf_out/)"
FORMATS = ("urdf", "mjcf")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("-o", "--output", default="urdf_out", metavar="DIR", help="output folder (default: urdf_out)")
    p.add_argument("--format", choices=FORMATS, default="urdf",
                   help="'urdf' (default): <system>.urdf, <system>.srdf and meshes/; 'mjcf': <system>.xml for MuJoCo")
    p.add_argument("--root", choices=("spec", "free"), default="spec",
                   help="'free': replace the joint to the inertial frame by a floating joint 'root_joint' from world")
    p.add_argument("--system", help="export only this rigidBodySystem")


@owns_output
def run(args: argparse.Namespace) -> int:
    spec = read_model(args.spec)
    systems = [spec.system(args.system)] if args.system else list(spec.systems)
    out = Path(args.output)
    files: dict[Path, str] = {}
    if args.format == "urdf":
        files[out / MESH_DIR / MESH_NAME] = sphere_obj()
    for system in systems:
        robot = Robot(spec, system, args.root)  # loading in Pinocchio validates the model
        if args.format == "mjcf":
            files[out / f"{system.name}.xml"] = to_mjcf(system, os.path.basename(spec.path), args.root == "free")
        else:
            files[out / f"{system.name}.urdf"] = robot.urdf
            files[out / f"{system.name}.srdf"] = robot.srdf
    write_outputs(files, out)
    return 0
