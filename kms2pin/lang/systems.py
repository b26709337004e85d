"""The checks that need the whole spec, and each system's joint graph made a spanning tree
with loop closures (thesis §3.2.1, §4.2): every body and bound vector complete and in
range, every body reached from the inertial frame, joints named; the frozen
:class:`~kms2pin.model.System`."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping

import numpy as np

from ..model import WORLD, Body, BoundVector, Joint, System
from .symbols import MAX_LENGTH, MIN_LENGTH, BodyB, BvecB, JointB, Reporter, SystemB


class SystemBuilder:
    """Checks the bodies, bound vectors and joints a spec built and freezes its systems
    (errors go to ``report``; a system with any error gives no model)."""

    def __init__(self, report: Reporter, systems: list[SystemB], inertial: Mapping[str, BvecB],
                 joints: list[JointB], constraint_failed: bool):
        self.report = report
        self.systems = systems
        self.inertial = inertial
        self.joints = joints
        self.constraint_failed = constraint_failed  # then reachability errors would only echo it

    def joint_system(self, j: JointB) -> SystemB | None:
        systems = []
        for e in j.ends:
            if e.body is not None and e.body.system not in systems:
                systems.append(e.body.system)
        return systems[0] if len(systems) == 1 else None

    def finish(self) -> list[System]:
        for j in self.joints:
            names = sorted({e.body.system.name for e in j.ends if e.body is not None})
            if len(names) > 1:
                self.report.error(j.loc, f"a joint cannot connect two rigidBodySystems ({' and '.join(names)})")
            elif not names:
                self.report.error(j.loc, "this joint connects two inertial bound vectors and no body")
        for system in self.systems:
            for body in system.bodies.values():
                self.check_body(body)
        for b in self.inertial.values():
            self.check_bvec(b)
        return [s for s in (self.build_system(sys) for sys in self.systems) if s is not None]

    def check_body(self, body: BodyB) -> None:
        for bv in body.bvecs.values():
            self.check_bvec(bv)
        if body.poisoned:
            return
        for what, lam, loc in (("innerLam", body.inner, body.inner_loc), ("outerLam", body.outer, body.outer_loc)):
            if lam is None:
                if not body.failed:
                    self.report.error(body.loc, f"body '{body.name}' has no {what}(x, y, z)", body.calls)
                body.poisoned = True
            elif min(lam) <= 0:
                self.report.error(loc, f"{what} semi-axes must be positive, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
            elif min(lam) < MIN_LENGTH:
                self.report.error(loc, f"{what} semi-axes must be at least {MIN_LENGTH:g}, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
            elif max(lam) > MAX_LENGTH:
                self.report.error(loc, f"{what} semi-axes must be at most {MAX_LENGTH:g}, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
        if body.poisoned:
            return
        if any(o < i for o, i in zip(body.outer, body.inner)):
            self.report.error(
                body.outer_loc,
                f"the outer ellipsoid ({_fmt(body.outer)}) of body '{body.name}' does not enclose "
                f"the inner one ({_fmt(body.inner)}): each outerLam semi-axis must be >= the innerLam one",
                body.def_calls,
            )
            body.poisoned = True

    def check_bvec(self, bv: BvecB) -> None:
        if bv.poisoned:
            return
        owner = f" of body '{bv.body.name}'" if bv.body else ""
        for what, val in (("pos", bv.pos), ("orient", bv.orient)):
            if val is None:
                self.report.error(bv.loc, f"bound vector '{bv.name}'{owner} has no {what}(x, y, z)", bv.calls)
                bv.poisoned = True
        if bv.pos is not None and max(abs(x) for x in bv.pos) > MAX_LENGTH:
            self.report.error(bv.pos_loc, f"pos coordinates of '{bv.name}'{owner} must be within +-{MAX_LENGTH:g}, "
                                   f"got ({_fmt(bv.pos)})", bv.calls)
            bv.poisoned = True
        if bv.orient is not None and _norm(bv.orient) < 1e-12:
            self.report.error(
                bv.orient_loc,
                f"orient vector of '{bv.name}'{owner} is zero; a bound vector needs a direction",
                bv.calls,
            )
            bv.poisoned = True

    def build_system(self, sb: SystemB) -> System | None:
        """Check the joint graph of one system and orient it as a spanning tree plus loop
        closures (thesis §3.2.1, §4.2): breadth first from the inertial frame, each body's
        joints in spec order; a joint that reaches a body already reached closes a loop."""
        joints = [j for j in self.joints if self.joint_system(j) is sb]
        bad = False
        adjacency: dict[str | None, list[tuple[str | None, JointB]]] = {None: []}
        for b in sb.bodies:
            adjacency[b] = []
        seen_pairs: dict[frozenset, JointB] = {}
        for j in joints:  # in spec order
            a = j.ends[0].body.name if j.ends[0].body else None
            b = j.ends[1].body.name if j.ends[1].body else None
            if a == b:
                self.report.error(j.loc, f"this joint connects body '{a}' to itself")
                bad = True
                continue
            pair = frozenset((a, b))
            if pair in seen_pairs:
                names = " and ".join("the inertial frame" if n is None else f"'{n}'" for n in (a, b))
                self.report.error(j.loc, f"a second joint between {names} (the first is on line {seen_pairs[pair].loc.line})")
                bad = True
                continue
            seen_pairs[pair] = j
            bad = bad or j.ends[0].poisoned or j.ends[1].poisoned
            adjacency[a].append((b, j))
            adjacency[b].append((a, j))
        children, closures = self.spanning_tree(adjacency)
        if not adjacency[None]:
            if not self.constraint_failed:
                self.report.error(sb.loc, f"rigidBodySystem '{sb.name}' has no joint to the inertial frame")
            return None
        # preorder, each body's children in spec order; an explicit stack, not recursion,
        # so a chain of any length is traversed
        order: list[tuple[str, JointB, str | None]] = []
        stack = [(c, j, None) for c, j in reversed(children[None])]
        while stack:
            child, j, parent = stack.pop()
            order.append((child, j, parent))
            stack.extend((c, k, child) for c, k in reversed(children.get(child, [])))
        reached = {name for name, _, _ in order}
        for name, body in sb.bodies.items():
            if name not in reached and not body.poisoned and not self.constraint_failed:
                self.report.error(
                    body.loc,
                    f"body '{name}' has no path to the inertial frame (no chain of joints connects it)",
                    body.calls,
                )
                bad = True
        for j in closures:
            if j.value_loc is not None:
                self.report.error(j.value_loc, f"this {j.kind} joint closes a kinematic loop, and a loop-closing joint takes "
                                        "no rest value or limits: its value follows from the joints of the tree "
                                        "(leave them out, or write the joints so that another one closes the loop)")
                bad = True
        if bad or self.report.diags or any(sb.bodies[n].poisoned for n, _, _ in order):
            return None  # with any error there is no model (and bvecs may be incomplete)
        return self.frozen_system(sb, order, closures)

    def spanning_tree(self, adjacency: Mapping[str | None, list[tuple[str | None, JointB]]]):
        """Breadth first from the inertial frame (None), each node's joints in spec order:
        (each node's tree children as (child, joint) in spec order, the closures in spec order)."""
        rank = {id(j): i for i, j in enumerate(self.joints)}
        children: dict[str | None, list[tuple[str, JointB]]] = {}
        reached: set[str | None] = {None}
        done: set[int] = set()
        closures = []
        queue: deque[str | None] = deque([None])
        while queue:
            node = queue.popleft()
            for other, j in sorted(adjacency[node], key=lambda t: rank[id(t[1])]):
                if id(j) in done:
                    continue
                done.add(id(j))
                if other in reached:
                    closures.append(j)
                    continue
                reached.add(other)
                children.setdefault(node, []).append((other, j))
                queue.append(other)
        children.setdefault(None, [])
        return children, sorted(closures, key=lambda j: rank[id(j)])

    def frozen_system(self, sb: SystemB, order, closures: list[JointB]) -> System:
        """The checked system: bodies in preorder with their tree joints, then the closures
        (parent: the first argument's body, child: the second's)."""
        bodies = []
        out_joints = []
        frozen_bvecs: dict[str, dict[str, BoundVector]] = {}
        used: set[str] = set()
        for name, j, parent in order:
            b = sb.bodies[name]
            bvecs = frozen_bvecs[name] = {n: freeze_bvec(v) for n, v in b.bvecs.items()}
            bodies.append(Body(name, b.inner, b.outer, bvecs, sb.name, b.loc))
            child_end = j.ends[0] if (j.ends[0].body and j.ends[0].body.name == name) else j.ends[1]
            parent_end = j.ends[1] if child_end is j.ends[0] else j.ends[0]
            jname = self.joint_name(name, child_end.name, j.kind, used, sb.bodies)
            out_joints.append(
                Joint(jname, j.kind, parent, name, freeze_bvec(parent_end), bvecs[child_end.name], j.angle,
                      j.loc, j.limits, j.rotation, j.offset)
            )

        def end(e: BvecB) -> BoundVector:
            return frozen_bvecs[e.body.name][e.name] if e.body is not None else freeze_bvec(e)

        out_closures = []
        for j in closures:
            parent, child = (e.body.name if e.body is not None else None for e in j.ends)
            jname = self.joint_name(child or WORLD, j.ends[1].name, j.kind, used, sb.bodies)
            out_closures.append(Joint(jname, j.kind, parent, child, end(j.ends[0]), end(j.ends[1]), loc=j.loc))
        return System(sb.name, tuple(bodies), tuple(out_joints), sb.loc, tuple(out_closures))

    def joint_name(self, body: str, bvec: str, kind: str, used: set[str], bodies: Mapping[str, object]) -> str:
        """``<body>_<bvec>``, with a suffix ``_2``, ``_3``, ... if taken (body 'a_b' + bvec 'c' and
        body 'a' + bvec 'b_c'; a spherical joint also takes the names of its three URDF joints
        and two links, :func:`kms2pin.urdf.spherical_parts`); recorded in ``used``."""
        jname, k = f"{body}_{bvec}", 2
        while not self.names_free(jname, kind, used, bodies):
            jname, k = f"{body}_{bvec}_{k}", k + 1
        used.add(jname)
        if kind == "spherical":
            used.update(f"{jname}_{a}" for a in "xyz")
        return jname

    @staticmethod
    def names_free(name: str, kind: str, used: set[str], bodies: Mapping[str, object]) -> bool:
        """Whether joint ``name`` (with a spherical joint's URDF joints ``name_x|y|z`` and
        links ``name_x_link``, ``name_y_link``) clashes with no joint and no body so far."""
        if kind != "spherical":
            return name not in used
        derived = [name, *(f"{name}_{a}" for a in "xyz")]
        links = [f"{name}_{a}_link" for a in "xy"]
        return not any(n in used for n in derived) and not any(n in bodies or n == WORLD for n in links)


def freeze_bvec(bv: BvecB) -> BoundVector:
    """The checked bound vector, its orient made a unit vector."""
    o = np.asarray(bv.orient, dtype=float)
    o = o / np.max(np.abs(o))  # first scale, so that huge or tiny vectors do not overflow
    o = o / np.linalg.norm(o)
    return BoundVector(
        bv.name,
        tuple(float(x) for x in bv.pos),
        tuple(float(x) for x in o),
        bv.body.name if bv.body else None,
        bv.loc,
    )


def _norm(v) -> float:
    """Euclidean norm without overflow for huge components (math.hypot scales)."""
    return math.hypot(*v)


def _fmt(v) -> str:
    return ", ".join(f"{x:g}" for x in v)
