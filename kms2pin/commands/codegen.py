"""Write the constraint equations C(q) and their Jacobian C_q of every system of a spec as
C (<system>_constraints.h/.c) or Python (<system>_constraints.py) code, derived with SymPy
(thesis §3.2.2)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_spec_argument, read_model, write_outputs

NAME = "codegen"
HELP = "generate C or Python code for the constraints C(q) and their Jacobian C_q"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("--lang", choices=("c", "python"), default="c", help="output language (default: c)")
    p.add_argument("-o", "--output", default=".", metavar="DIR", help="output folder (default: .)")
    p.add_argument(
        "--root",
        choices=("spec", "free"),
        default="spec",
        help="'free': no constraint between the root body and the inertial frame",
    )
    p.add_argument("--system", help="generate only this rigidBodySystem")


def run(args: argparse.Namespace) -> int:
    from ..reference import generate_c, generate_python, symbolic_model  # SymPy is slow to import

    spec = read_model(args.spec)
    systems = [spec.system(args.system)] if args.system else list(spec.systems)
    out = Path(args.output)
    files: dict[Path, str] = {}
    for system in systems:
        model = symbolic_model(system, args.root)
        stem = f"{system.name}_constraints"
        if args.lang == "c":
            header, source = generate_c(model)
            files[out / f"{stem}.h"] = header
            files[out / f"{stem}.c"] = source
        else:
            files[out / f"{stem}.py"] = generate_python(model)
    write_outputs(files, out)
    return 0
