"""Write <system>.urdf, <system>.srdf and the mesh they use (``--format urdf``, the
default), or <system>.xml for MuJoCo (``--format mjcf``), for every system of a spec."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..mesh import MESH_NAME, sphere_obj
from ..mjcf import to_mjcf
from ..robot import check_free_root
from ..urdf import MESH_DIR, to_srdf, to_urdf
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
    source = os.path.basename(spec.path)
    free = args.root == "free"
    for system in systems:  # text only: no Pinocchio model (its construction grows as n^2)
        if free:
            check_free_root(system)
        if args.format == "mjcf":
            files[out / f"{system.name}.xml"] = to_mjcf(system, source, free)
        else:
            files[out / f"{system.name}.urdf"] = to_urdf(system, source, free_root=free)
            files[out / f"{system.name}.srdf"] = to_srdf(system, source, free_root=free)
    write_outputs(files, out)
    return 0
