"""Write <system>.urdf, <system>.srdf and the mesh they use (``--format urdf``, the
default), or <system>.xml for MuJoCo (``--format mjcf``), for every system of a spec.

A system with loop closures is loaded (its rest pose closed, or a located error): its URDF
is the spanning tree and says so, its SRDF's rest state is the closed rest pose, and its
closures go to <system>.closures.json (:func:`kms2pin.urdf.closures_json`); its MJCF holds
them as equality constraints, a prismatic one left out with a warning."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from ..mesh import MESH_NAME, sphere_obj
from ..mjcf import to_mjcf
from ..robot import Robot, check_free_root
from ..urdf import MESH_DIR, closures_json, to_srdf, to_urdf
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
    for system in systems:  # text only: no Pinocchio model (its construction grows as n^2), but for loops
        if free:
            check_free_root(system, spec)
        robot = Robot(spec, system, args.root) if system.closures else None
        if args.format == "mjcf":
            rest = robot.joint_blocks(robot.q_rest) if robot is not None else None
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                files[out / f"{system.name}.xml"] = to_mjcf(system, source, free, rest)
            for w in caught:
                print(f"kms2pin export: warning: {system.name}.xml: {w.message}", file=sys.stderr)
        else:
            files[out / f"{system.name}.urdf"] = to_urdf(system, source, free_root=free)
            files[out / f"{system.name}.srdf"] = (robot.srdf if robot is not None
                                                  else to_srdf(system, source, free_root=free))
            if robot is not None:
                files[out / f"{system.name}.closures.json"] = closures_json(system, source)
    write_outputs(files, out)
    return 0
