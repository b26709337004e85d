"""A model of a BVH skeleton (``kms2pin import``) and its motion as that model's configurations.

Bodies.  A BVH joint J starts a bone: from J's point to the mean of its child joints' points
and End Sites (all in J's frame F_J).  Each bone becomes the body J, an inner ellipsoid
centred halfway along it with semi-axis :data:`~kms2pin.bvh.anthropometry.ALONG` of its
length along it and the anthropometric table's cross-section across
(:mod:`kms2pin.bvh.anthropometry`); the body's axes R_b are F_J's turned by the least
rotation that lays the basis axis nearest the bone along it (at most 54.7 deg).  A joint
whose children spread around it (their mean nearer than :data:`SPREAD` of the farthest) keeps
F_J's axes and the table's three semi-axes.  Bones of zero length (every child and End Site
within :data:`ZERO` H of the joint): the root keeps a body (the table's pelvis, or its own
segment); another joint is merged into each child, which then hangs from the merged joint's
parent body at its point and turns by R_J R_child; a leaf is skipped.

Joints.  The link from body P to body K turns by the BVH rotations of its chain (the merged
joints, then K's own): R_chain, in F_P's axes.  Their bodies' relative rotation is
R_PK = R_bP^T R_chain R_bK.  Its orients are chosen so that R_align (eq. 2.12) is
M = R_bP^T R_bK: o_ji a unit vector across M's axis, o_ij = M o_ji (then the least rotation
from o_ji to o_ij is M itself).  So the rest pose (every R_chain = I) has every coordinate 0,
and a spherical joint's quaternion is R_bP^T R_chain R_bP: the BVH rotation in P's axes.  A
chain with one one-channel joint is revolute about that axis, exactly; ``--hinge`` makes a
link revolute about the principal axis of its rotation vectors over the motion (signed so
that its mean angle is positive), the angle of each frame the twist of R_chain about it.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import BvhError, Diagnostic, UsageError, did_you_mean
from ..lang import parse_text
from ..lang.symbols import MAX_LENGTH, MIN_LENGTH
from ..model import alignment_matrix, axis_angle_matrix, perpendicular_axis
from ..robot import Robot
from .anthropometry import ALONG, OTHER_RATIO, OUTER, segment_of
from .motion import Skeleton, choose_up, skeleton
from .reader import BvhFile

#: A bone shorter than this fraction of the skeleton's height has zero length.
ZERO = 1e-9
#: A joint's children spread around it when their mean point is nearer than this fraction of the farthest.
SPREAD = 0.25
#: The least semi-axis of a body, as a fraction of the skeleton's height.
MIN_SEMI = 1e-3
#: How far (fraction of the height) the position channels of a joint below the root may vary.
STILL = 1e-6
#: Joint rotations below this (radians) are the rest's: what is left of rounding the orients to 12 decimals.
STILL_ANGLE = 1e-10
_KEYWORDS = {"double", "bool", "if", "else", "bvec", "ellipsoidBody", "rigidBodySystem", "constraint", "true",
             "false", "world"}


@dataclass(frozen=True)
class ImportOptions:
    """``scale``: metres per file unit; ``up``: the file's up axis, ``"y"``, ``"z"`` or
    ``"auto"``; ``fps``: resample the motion at this rate (None: the file's); ``hinges``:
    BVH joints to model as revolute joints; ``name``: the rigidBodySystem's."""

    scale: float = 1.0
    up: str = "auto"
    fps: float | None = None
    hinges: tuple[str, ...] = ()
    name: str = "skeleton"


@dataclass(frozen=True)
class ImportedModel:
    """The model's spec ``text``, loaded as ``robot`` (a free root), and ``q`` (frames, nq)
    its configurations over the motion at ``fps``; ``up`` the file's up axis and why,
    ``height`` the rest pose's (m); ``merged`` and ``skipped`` BVH joints of zero length."""

    text: str
    robot: Robot
    q: np.ndarray
    fps: float
    up: tuple[str, str]
    height: float
    merged: tuple[str, ...]
    skipped: tuple[str, ...]


@dataclass
class _Body:
    joint: int
    name: str
    axes: np.ndarray  # R_b: the body's axes (columns) in F_J
    centre: np.ndarray  # in F_J
    inner: np.ndarray
    segment: str
    bvecs: dict[str, list] = field(default_factory=dict)  # name -> [pos in F_J, orient in the body frame]


@dataclass
class _Link:
    parent: int | None  # body index; None: the inertial frame
    child: int
    chain: tuple[int, ...]  # BVH joints below the parent body down to the child's
    kind: str = "spherical"
    axis: np.ndarray | None = None  # a revolute link's axis (in F_P, then in the parent body's frame)
    rest: float = 0.0  # a revolute link's rest angle, degrees
    hinge: bool = False  # made revolute by --hinge
    o_ij: np.ndarray | None = None  # the parent end's orient (the inertial bvec's for the root)


def identifier(name: str) -> str:
    """``name`` as a name of the language: [A-Za-z_][A-Za-z0-9_]*, not a keyword."""
    out = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    if out[0].isdigit():
        out = "_" + out
    return out + "_" if out in _KEYWORDS else out


def _unique(names: list[str], taken: set[str] | None = None) -> list[str]:
    seen, out = set(taken or ()), []
    for n in names:
        k, m = n, 2
        while k in seen:
            k, m = f"{n}_{m}", m + 1
        seen.add(k)
        out.append(k)
    return out


def import_bvh(bvh: BvhFile, options: ImportOptions = ImportOptions()) -> ImportedModel:
    """The model of ``bvh``'s skeleton and its motion (module docstring)."""
    sk = skeleton(bvh, options.scale, options.up, options.fps)
    size = sk.height or float(np.ptp(np.vstack([sk.offsets, *sk.ends]), axis=0).max())
    if size <= 0:
        raise BvhError(f"{bvh.path}: the skeleton has no extent: every OFFSET and End Site is zero")
    points = _points(sk, size)
    links, kept, merged, skipped = _plan(sk, points, size)
    _check_hinges(sk, options.hinges, links, merged)
    # 'joint' and 'end' name bvecs of every body, and a body 'root' would have the joint 'root_joint', a free root's name
    names = _unique([identifier(j.name) + ("_" if identifier(j.name) == "root" else "") for j in bvh.joints],
                    {"joint", "end"})
    children = _children(sk)
    bodies: dict[int, _Body] = {}
    for j in kept:  # parents first: a revolute link's child takes its axes from its parent's
        link = links[j]
        if link.hinge:
            link.axis = _principal_axis(sk, link, bodies[link.parent].axes)
        reference = bodies[link.parent].axes if link.kind == "revolute" else np.eye(3)
        bodies[j] = _geometry(sk, j, children[j], points, names[j], size, reference, link.axis)
    _orients(sk, bodies, links, points, names)
    _check_sizes(bodies, points, options.scale)
    text = _text(bvh, sk, options, bodies, links, names, (merged, skipped), size)
    spec = parse_text(text, f"{options.name}.kms")
    robot = Robot(spec, spec.system(), "free")
    q = _configurations(robot, sk, bodies, links)
    return ImportedModel(text, robot, q, sk.fps, choose_up(bvh, options.up), sk.height,
                         tuple(bvh.joints[k].name for k in merged), tuple(bvh.joints[k].name for k in skipped))


def _points(sk: Skeleton, size: float) -> list[np.ndarray]:
    """Each joint's point in its parent's frame (metres): its offset, or for a joint below
    the root with position channels their value, which must not vary (BvhError)."""
    points = []
    for k, j in enumerate(sk.bvh.joints):
        p = sk.offsets[k]
        if k and any(c.endswith("position") for c in j.channels) and sk.frames:
            t = sk.translations[:, k]
            moved = float(np.abs(t - t[0]).max())
            if moved > STILL * size:
                raise BvhError(Diagnostic(
                    sk.bvh.path, j.channels_line, 1,
                    f"joint '{j.name}' moves: its position channels vary by up to {moved:.4g} m over the motion; "
                    "kms2pin models the joints below the root as rotations about a point").format())
            p = t[0]
        points.append(np.asarray(p, dtype=float))
    return points


def _children(sk: Skeleton) -> list[list[int]]:
    out: list[list[int]] = [[] for _ in sk.bvh.joints]
    for k, j in enumerate(sk.bvh.joints):
        if j.parent is not None:
            out[j.parent].append(k)
    return out


def _plan(sk: Skeleton, points, size: float):
    """The links (one per kept non-root joint, with its chain of merged joints), the kept
    joints, the merged and the skipped ones (module docstring)."""
    children = _children(sk)
    zero = [all(np.linalg.norm(points[c]) <= ZERO * size for c in children[k])
            and all(np.linalg.norm(e) <= ZERO * size for e in sk.ends[k]) for k in range(len(children))]
    kept = [k for k in range(len(children)) if k == 0 or not zero[k]]
    keep = set(kept)
    merged = [k for k in range(1, len(children)) if zero[k] and children[k]]
    skipped = [k for k in range(1, len(children)) if zero[k] and not children[k]]
    links = {0: _Link(None, 0, (0,))}
    for k in kept[1:]:
        chain, p = [k], sk.parent(k)
        while p not in keep:
            chain.insert(0, p)
            p = sk.parent(p)
        rotating = [j for j in chain if sk.axes[j]]
        link = _Link(p, k, tuple(chain), "fixed" if not rotating else "spherical")
        if len(rotating) == 1 and len(sk.axes[rotating[0]]) == 1:
            link.kind, link.axis = "revolute", np.asarray(sk.axes[rotating[0]][0], dtype=float)  # in F_P for now
        links[k] = link
    return links, kept, merged, skipped


def _geometry(sk: Skeleton, j: int, children: list[int], points, name: str, size: float, reference: np.ndarray,
              hinge: np.ndarray | None) -> _Body:
    """Body ``j``: its axes, centre and inner semi-axes (module docstring).  The axes are
    ``reference`` (F_J's, or a revolute link's parent body's) turned to lay the one nearest
    the bone along it: by the least rotation, or about an axis across ``hinge`` (the link's
    axis, in F_J) so that the link's R_align turns about its axis too."""
    pts = [points[k] for k in children] + list(sk.ends[j])
    far = max((float(np.linalg.norm(p)) for p in pts), default=0.0)
    mean = np.mean(pts, axis=0) if pts else np.zeros(3)
    seg = segment_of(sk.bvh.joints[j].name, [sk.bvh.joints[k].name for k in children], root=j == 0)
    if far <= ZERO * size or np.linalg.norm(mean) < SPREAD * far:
        axes, centre = reference, mean
        inner = size * np.array([seg.across[0], seg.length, seg.across[1]]) if seg else \
            np.full(3, ALONG * far)
    else:
        length = float(np.linalg.norm(mean))
        d = mean / length
        local = reference.T @ d
        k = int(np.argmax(np.abs(local)))
        a = reference[:, k] * math.copysign(1.0, local[k])
        turn = alignment_matrix(d, a) if hinge is None else _turn_about(hinge, a, d)
        axes, centre = turn @ reference, mean / 2
        inner = np.empty(3)
        inner[k] = ALONG * length
        across = [a for a in (0, 2, 1) if a != k]
        inner[across] = size * np.array(seg.across) if seg else OTHER_RATIO * length
    inner = np.maximum(inner, MIN_SEMI * size)
    return _Body(j, name, axes, centre, inner, seg.name if seg else "")


def _turn_about(u: np.ndarray, a: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A rotation about an axis n across unit ``u`` taking unit ``a`` to unit ``d``: n = u x (a - d)."""
    n = np.cross(u, a - d)
    if np.linalg.norm(n) < 1e-12:
        if np.linalg.norm(a - d) < 1e-12:
            return np.eye(3)
        n = np.cross(u, a) if np.linalg.norm(np.cross(u, a)) > 1e-12 else perpendicular_axis(u)
    n = n / np.linalg.norm(n)
    pa, pd = a - (a @ n) * n, d - (d @ n) * n
    return axis_angle_matrix(n, math.atan2(float(n @ np.cross(pa, pd)), float(pa @ pd)))


def _chain_rotation(sk: Skeleton, chain: tuple[int, ...]) -> Rotation:
    R = sk.rotations[chain[0]]
    for j in chain[1:]:
        R = R * sk.rotations[j]
    return R


def _check_hinges(sk: Skeleton, hinges: tuple[str, ...], links: dict, merged: list[int]) -> None:
    """Mark the links of the BVH joints ``hinges`` revolute (UsageError for a name that cannot be one)."""
    index = {j.name: k for k, j in enumerate(sk.bvh.joints)}
    for name in hinges:
        if name not in index:
            raise UsageError(f"--hinge: {sk.bvh.path} has no joint '{name}'{did_you_mean(name, index)}")
        k = index[name]
        if k == 0:
            raise UsageError(f"--hinge: '{name}' is the root, whose joint is free")
        if k in merged:
            below = [sk.bvh.joints[c].name for c in _children(sk)[k]]
            raise UsageError(f"--hinge: '{name}' has a bone of zero length and is merged into {', '.join(below)}; "
                             "hinge one of them")
        if k not in links:
            raise UsageError(f"--hinge: '{name}' has a bone of zero length and no children: it is left out")
        if links[k].kind == "fixed":
            raise UsageError(f"--hinge: '{name}' does not turn (no rotation channels)")
        links[k].kind, links[k].hinge = "revolute", True


def _principal_axis(sk: Skeleton, link: _Link, parent_axes: np.ndarray) -> np.ndarray:
    """The axis (in F_P) a hinged link mostly turns about: the principal axis of the rotation
    vectors of R_chain over the motion, signed so that its mean angle is positive."""
    Rb = Rotation.from_matrix(parent_axes)
    E = Rb.inv() * _chain_rotation(sk, link.chain) * Rb  # R_chain in the parent body's axes
    w = E.as_rotvec().reshape(-1, 3)
    vals, vecs = np.linalg.eigh(w.T @ w)
    u = vecs[:, -1] if len(w) and vals[-1] > 0 else np.array([1.0, 0.0, 0.0])
    if len(w) and twist(E, u).mean() < 0:
        u = -u
    return parent_axes @ u


def twist(R: Rotation, u: np.ndarray) -> np.ndarray:
    """The angles (radians, in [-pi, pi]) of the rotations about unit ``u`` nearest ``R``:
    2 atan2(v . u, w) of its quaternions (v, w) with w >= 0."""
    quat = R.as_quat().reshape(-1, 4)
    quat = quat * np.where(quat[:, 3:] < 0, -1.0, 1.0)
    return 2.0 * np.arctan2(quat[:, :3] @ u, quat[:, 3])


def _across(M: np.ndarray) -> np.ndarray:
    """A unit vector across the axis of rotation ``M`` (the x axis, or nearest it)."""
    rv = Rotation.from_matrix(M).as_rotvec()
    angle = float(np.linalg.norm(rv))
    x = np.array([1.0, 0.0, 0.0])
    if angle < 1e-12:
        return x
    n = rv / angle
    v = x - (x @ n) * n
    return v / np.linalg.norm(v) if np.linalg.norm(v) > 0.1 else perpendicular_axis(n)


def _orients(sk: Skeleton, bodies: dict, links: dict, points, names: list[str]) -> None:
    """Every body's bvecs: 'joint' at its point (its link to its parent), one per child link
    at the child's point, markers at merged and skipped joints' points, 'end' at End Sites."""
    for k, link in links.items():
        child = bodies[k]
        M = child.axes if link.parent is None else bodies[link.parent].axes.T @ child.axes
        if link.kind == "revolute":
            o_ij = bodies[link.parent].axes.T @ link.axis
            o_ji = M.T @ o_ij
            R_align = alignment_matrix(o_ij, o_ji)
            link.axis = o_ij
            link.rest = math.degrees(float(twist(Rotation.from_matrix(M @ R_align.T), o_ij)[0]))
        else:
            o_ji = _across(M)
            o_ij = M @ o_ji
        child.bvecs["joint"] = [np.zeros(3), o_ji]
        link.o_ij = o_ij
        if link.parent is not None:
            bodies[link.parent].bvecs[names[k]] = [points[link.chain[0]], o_ij]
    holder = {}
    for k, j in enumerate(sk.bvh.joints):
        if k and k not in bodies:
            p = j.parent
            holder[k] = (p, points[k]) if p in bodies else (holder[p][0], holder[p][1] + points[k])
            body = bodies[holder[k][0]]
            body.bvecs.setdefault(names[k], [holder[k][1], np.array([1.0, 0.0, 0.0])])
    for k, body in bodies.items():
        for e, name in zip(sk.ends[k], _unique(["end"] * len(sk.ends[k]), set(body.bvecs))):
            body.bvecs[name] = [e, np.array([1.0, 0.0, 0.0])]


def _check_sizes(bodies: dict, points, scale: float) -> None:
    """BvhError if a body or a point is out of the language's range at this scale."""
    small = min(float(b.inner.min()) for b in bodies.values())
    large = max([float(b.inner.max()) * OUTER for b in bodies.values()] + [float(np.abs(p).max()) for p in points])
    if small < MIN_LENGTH or large > MAX_LENGTH:
        raise BvhError(f"at --scale {scale:g} (metres per file unit) the bodies span {small:.3g} to {large:.3g} m; "
                       f"a model's lengths must lie within [{MIN_LENGTH:g}, {MAX_LENGTH:g}]: give the file's unit")


def _num(x: float, places: int = 12) -> str:
    s = f"{round(float(x), places):.12g}"
    return "0" if s == "-0" else s


def _vec(v, places: int = 12) -> str:
    """Coordinates rounded to ``places`` decimals (1e-12 m: far below what matters)."""
    return ", ".join(_num(x, places) for x in v)


def _text(bvh: BvhFile, sk: Skeleton, options: ImportOptions, bodies: dict, links: dict, names, dropped,
          size: float) -> str:
    """The .kms text of the model."""
    merged, skipped = ([bvh.joints[k].name for k in ks] for ks in dropped)
    up, why = choose_up(bvh, options.up)
    lines = [
        f"// {options.name}.kms: the skeleton of {os.path.basename(bvh.path)}, imported by kms2pin (docs/bvh.md).",
        f"// {len(bvh.joints)} BVH joints -> {len(bodies)} bodies, one per bone; bones of zero length merged into their "
        f"children: {', '.join(merged) or 'none'}; left out: {', '.join(skipped) or 'none'}.",
        f"// Metres ({options.scale:g} m per file unit); +y up (the file is {up.upper()}-up: {why}).",
        "// Rest pose: the file's offsets (every BVH rotation zero), where every joint coordinate is 0; the root's",
        "// joint is replaced by a free one (root='free'), as motion.csv's root_x ... root_qw columns are.",
        f"// Sizes: along a bone {ALONG:g} of its length; across, the anthropometric table (skeleton height "
        f"H = {size:.4g} m); the outer ellipsoid {OUTER:g} times the inner.",
        "",
        f"bvec origin {{ pos({_vec(sk.offsets[0])}); orient({_vec(links[0].o_ij)}); }}",
        "",
        f"rigidBodySystem {options.name} {{",
    ]
    for body in bodies.values():
        reach = max(float(np.linalg.norm(pos)) for pos, _ in body.bvecs.values())
        bone = f"its bone {reach:.3g} m long" if reach > ZERO * size else "no bone: its children start at its joint"
        what = f"{body.segment}, " if body.segment else ""
        lines.append(f"    ellipsoidBody {body.name} {{  // {what}{bone}")
        lines.append(f"        innerLam({_vec(body.inner, 4)});")
        lines.append(f"        outerLam({_vec(OUTER * body.inner, 4)});")
        for name, (pos, orient) in body.bvecs.items():
            local = body.axes.T @ (np.asarray(pos) - body.centre)
            lines.append(f"        bvec {name} {{ pos({_vec(local)}); orient({_vec(orient)}); }}")
        lines.append("    }")
    for k, link in links.items():
        if link.parent is None:
            continue
        ends = f"{bodies[link.parent].name}.{names[k]}, {bodies[k].name}.joint"
        if link.kind == "revolute":
            hinge = "  // --hinge" if bvh.joints[k].name in options.hinges else ""
            lines.append(f"    constraint revolute({ends}, {_num(link.rest)});{hinge}")
        else:
            lines.append(f"    constraint {link.kind}({ends});")
    lines += ["}", "", f"constraint spherical(origin, {options.name}.{bodies[0].name}.joint);", ""]
    return "\n".join(lines)


def _configurations(robot: Robot, sk: Skeleton, bodies: dict, links: dict) -> np.ndarray:
    """(frames, nq): the motion as ``robot``'s configurations (module docstring)."""
    q = np.tile(robot.q_rest, (sk.frames, 1))
    if not sk.frames:
        return q
    by_name = {b.name: k for k, b in bodies.items()}
    for jc in robot.joints:
        if jc.kind == "free":
            q[:, :3] = sk.translations[:, 0]
            q[:, 3:7] = (sk.rotations[0] * Rotation.from_matrix(bodies[0].axes)).as_quat()
            continue
        if jc.kind == "fixed":
            continue
        k = by_name[jc.spec.child]
        link = links[k]
        Rp, Rk = (Rotation.from_matrix(bodies[i].axes) for i in (link.parent, k))
        R_align = alignment_matrix(np.asarray(jc.spec.parent_bvec.orient), np.asarray(jc.spec.child_bvec.orient))
        Q = Rp.inv() * _chain_rotation(sk, link.chain) * Rk * Rotation.from_matrix(R_align).inv()
        if jc.kind == "spherical":
            quat = Q.as_quat().reshape(-1, 4)
            quat[np.linalg.norm(Q.as_rotvec().reshape(-1, 3), axis=1) < STILL_ANGLE] = (0.0, 0.0, 0.0, 1.0)
            q[:, jc.idx_q : jc.idx_q + 4] = quat
        else:
            angle = np.unwrap(twist(Q, np.asarray(jc.spec.parent_bvec.orient)))
            q[:, jc.idx_q] = np.where(np.abs(angle) < STILL_ANGLE, 0.0, angle)
    return q
