"""Write <system>.urdf, <system>.srdf and the mesh they use for every system of a spec."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..mesh import MESH_NAME, sphere_obj
from ..robot import check_free_root
from ..urdf import MESH_DIR, to_srdf, to_urdf
from ._common import add_spec_argument, read_model, write_outputs

NAME = "export"
HELP = "compile a spec to URDF + SRDF (default output folder urdf_out/)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("-o", "--output", default="urdf_out", metavar="DIR", help="output folder (default: urdf_out)")
    p.add_argument("--root", choices=("spec", "free"), default="spec",
                   help="'free': replace the joint to the inertial frame by a floating base (no world link)")
    p.add_argument("--system", help="export only this rigidBodySystem")


def run(args: argparse.Namespace) -> int:
    spec = read_model(args.spec)
    systems = [spec.system(args.system)] if args.system else list(spec.systems)
    out = Path(args.output)
    files: dict[Path, str] = {out / MESH_DIR / MESH_NAME: sphere_obj()}
    source = os.path.basename(spec.path)
    for system in systems:  # text only: no Pinocchio model (its construction grows as n^2)
        if args.root == "free":
            check_free_root(system)
        files[out / f"{system.name}.urdf"] = to_urdf(system, source, free_root=args.root == "free")
        files[out / f"{system.name}.srdf"] = to_srdf(system, source, free_root=args.root == "free")
    write_outputs(files, out)
    return 0
