"""Check a spec and print each system's body tree: joint type, degrees of freedom, axis,
rest pose (angle, rotation or offset) and limits; then each loop closure and the loop it
closes.  A system with loops is loaded, so a loop that cannot be closed at rest is an error
here too, and its degrees of freedom are those left once the loops are closed (the tree's
less the rank of the closures' constraints at rest)."""

from __future__ import annotations

import argparse
import json

from ..model import Joint, ModelSpec, System
from ..robot import Robot
from ._common import add_spec_argument, read_model

NAME = "check"
HELP = "check a spec and print its body tree (--json for machine-readable output)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a tree")


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def describe(spec: ModelSpec, mobility: dict[str, int] | None = None) -> dict:
    """The body tree and loop closures of every system as plain data (what ``check --json``
    prints); ``mobility``: the degrees of freedom of each system with loops, by name."""
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
                    "dof": j.dof,
                    "parent_bvec": j.parent_bvec.qualified_name,
                    "child_bvec": j.child_bvec.qualified_name,
                    "axis": list(j.parent_bvec.orient),
                    "axis_frame": j.parent or "world",
                    "default_angle_deg": j.default_angle,
                    "limits_deg": list(j.limits) if j.limits is not None and j.kind == "revolute" else None,
                    **_new_joint_fields(j),
                    "line": j.loc.line,
                },
            })
        systems.append({
            "name": s.name,
            "bodies": bodies,
            "dof": s.dof,
            **{f"{kind}_joints": s.count(kind) for kind in KINDS},
            "closures": [_closure_fields(s, j) for j in s.closures],
            "mobility": (mobility or {}).get(s.name, s.dof),
        })
    return {"path": spec.path, "systems": systems}


def _closure_fields(system: System, j: Joint) -> dict:
    """A loop closure as plain data: its ends, the bodies of its loop (None: the inertial
    frame) and the tree joints on it."""
    bodies, joints = system.loop(j)
    return {"name": j.name, "type": j.kind, "parent": j.parent, "child": j.child,
            "parent_bvec": j.parent_bvec.qualified_name, "child_bvec": j.child_bvec.qualified_name,
            "loop": bodies, "loop_joints": [t.name for t in joints], "line": j.loc.line}


KINDS = ("revolute", "spherical", "prismatic", "fixed")


def _new_joint_fields(j: Joint) -> dict:
    """The JSON fields of a spherical joint's rest rotation or a prismatic joint's offset."""
    if j.kind == "spherical":
        return {"default_rotation_deg": list(j.default_rotation)}
    if j.kind == "prismatic":
        return {"default_offset": j.default_offset, "limits": list(j.limits) if j.limits is not None else None}
    return {}


def _rest(j: Joint) -> str:
    """A joint's rest pose and limits as the tree shows them."""
    if j.kind == "revolute":
        out = f", rest {j.default_angle:g} deg"
        return out + (f", limits {j.limits[0]:g}..{j.limits[1]:g} deg" if j.limits is not None else "")
    if j.kind == "spherical":
        return f", rest rotation {_vec(j.default_rotation)} deg in {j.parent or 'world'}"
    if j.kind == "prismatic":
        out = f", rest offset {j.default_offset:g}"
        return out + (f", limits {j.limits[0]:g}..{j.limits[1]:g}" if j.limits is not None else "")
    return ""


#: Deeper bodies are drawn at this depth, with their depth written out: the indentation of a
#: long chain would otherwise grow with its square (a 10000-body chain: 150 million spaces).
MAX_INDENT = 32


def _tree(system: System) -> list[str]:
    lines = ["inertial frame"]
    stack = [(j, "", k == 0, 1) for k, j in enumerate(reversed(system.children(None)))]
    while stack:  # depth first without recursion (chains of any length)
        j, prefix, last, depth = stack.pop()
        axis = f"axis {_vec(j.parent_bvec.orient)} in {j.parent or 'world'}"
        deep = f"(depth {depth}) " if depth > MAX_INDENT else ""
        lines.append(f"{prefix}{'└─ ' if last else '├─ '}{deep}{j.child}  "
                     f"[{j.kind} '{j.name}', {j.dof} DoF, {axis}{_rest(j)}]")
        inner = prefix + ("   " if last else "│  ") if depth < MAX_INDENT else prefix
        stack.extend((k, inner, n == 0, depth + 1) for n, k in enumerate(reversed(system.children(j.child))))
    return lines


def _counts(system: System) -> str:
    """"12 revolute, 3 fixed joints", with spherical and prismatic joints where there are some."""
    shown = [k for k in KINDS if k in ("revolute", "fixed") or system.count(k)]
    return ", ".join(f"{system.count(k)} {k}" for k in shown) + " joints"


def _closures(system: System) -> list[str]:
    """Each loop closure: its joint and the loop it closes."""
    lines = ["loop closures:"]
    for k, j in enumerate(system.closures):
        bodies, _ = system.loop(j)
        loop = " -> ".join("inertial frame" if b is None else b for b in [*bodies, bodies[0]])
        lines.append(f"{'└─ ' if k == len(system.closures) - 1 else '├─ '}{j.name}  [{j.kind}, "
                     f"{j.parent_bvec.qualified_name} -> {j.child_bvec.qualified_name}] closes {loop}")
    return lines


def run(args: argparse.Namespace) -> int:
    spec = read_model(args.spec)
    # a system with loops is loaded: its rest pose must close them, and its mobility is numerical
    mobility = {s.name: Robot(spec, s).mobility for s in spec.systems if s.closures}
    if args.json:
        print(json.dumps(describe(spec, mobility), indent=2))
        return 0
    for s in spec.systems:
        dof = f"{s.dof} degrees of freedom ({_counts(s)})"
        if s.closures:
            n = len(s.closures)
            m = mobility[s.name]
            dof = (f"{m} degree{'s' if m != 1 else ''} of freedom with its {n} loop{'s' if n > 1 else ''} closed "
                   f"({s.dof} in its tree: {_counts(s)}; {n} loop closure{'s' if n > 1 else ''})")
        print(f"{spec.path}: rigidBodySystem '{s.name}': {len(s.bodies)} bodies, {dof}")
        print("\n".join(_tree(s)))
        if s.closures:
            print("\n".join(_closures(s)))
    return 0
