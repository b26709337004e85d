"""Check a spec and print each system's body tree: joint type, axis, default angle, DoF."""

from __future__ import annotations

import argparse
import json

from ..model import ModelSpec, System
from ._common import add_spec_argument, read_model

NAME = "check"
HELP = "check a spec and print its body tree (--json for machine-readable output)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a tree")


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def describe(spec: ModelSpec) -> dict:
    """The body tree of every system as plain data (what ``check --json`` prints)."""
    systems = []
    for s in spec.systems:
        bodies = []
        for b, j in zip(s.bodies, s.joints):
            bodies.append({
                "name": b.name,
                "parent": j.parent,
                "inner": list(b.inner),
                "outer": list(b.outer),
                "joint": {
                    "name": j.name,
                    "type": j.kind,
                    "parent_bvec": j.parent_bvec.qualified_name,
                    "child_bvec": j.child_bvec.qualified_name,
                    "axis": list(j.parent_bvec.orient),
                    "axis_frame": j.parent or "world",
                    "default_angle_deg": j.default_angle,
                    "limits_deg": list(j.limits) if j.limits is not None else None,
                    "line": j.loc.line,
                },
            })
        systems.append({
            "name": s.name,
            "bodies": bodies,
            "dof": s.dof,
            "revolute_joints": s.dof,
            "fixed_joints": sum(1 for j in s.joints if j.kind == "fixed"),
        })
    return {"path": spec.path, "systems": systems}


def _tree(system: System) -> list[str]:
    lines = ["inertial frame"]

    def walk(parent: str | None, prefix: str) -> None:
        kids = system.children(parent)
        for k, j in enumerate(kids):
            last = k == len(kids) - 1
            angle = f", rest {j.default_angle:g} deg" if j.kind == "revolute" else ""
            if j.limits is not None:
                angle += f", limits {j.limits[0]:g}..{j.limits[1]:g} deg"
            axis = f"axis {_vec(j.parent_bvec.orient)} in {j.parent or 'world'}"
            lines.append(f"{prefix}{'└─ ' if last else '├─ '}{j.child}  [{j.kind} '{j.name}', {axis}{angle}]")
            walk(j.child, prefix + ("   " if last else "│  "))

    walk(None, "")
    return lines


def run(args: argparse.Namespace) -> int:
    spec = read_model(args.spec)
    if args.json:
        print(json.dumps(describe(spec), indent=2))
        return 0
    for s in spec.systems:
        fixed = sum(1 for j in s.joints if j.kind == "fixed")
        print(f"{spec.path}: rigidBodySystem '{s.name}': {len(s.bodies)} bodies, "
              f"{s.dof} degrees of freedom ({s.dof} revolute, {fixed} fixed joints)")
        print("\n".join(_tree(s)))
    return 0
