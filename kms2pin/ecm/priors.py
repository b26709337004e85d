"""Priors of the tracker's static update: springs on what the images do not fix.

Each prior is a :class:`kms2pin.virtual_work.SpringTerm`: its stiffness is its weight
times a stiffness the data sets (the springs' own Newton matrix at the start of the
update), and it adds its energy, gradient and Gauss-Newton matrix to the update's
Newton system in joint velocities (Pinocchio's tangent space; the free root's first
three are its local linear velocity, the next three its local angular velocity).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import pinocchio as pin

from ..native import kernels
from .limbs import hinged_bodies, sides, twin_name

__all__ = ["MIDLINE_MARGIN", "DepthPrior", "GroundPrior", "MidlinePrior", "RestPrior", "TwistPrior", "UprightPrior",
           "feet", "standing_priors"]

#: the share of its offset from the midline at rest that a twin limb's root keeps before the
#: midline prior pushes it out, for the arms and for the legs (None: that kind left out): a
#: real walker's collars and upper arms keep 0.8-0.9 of theirs.  Its thighs come to 0.17, and
#: the legs at 0.1 held the kick on more runs but lost others: left out by default
#: (docs/design/tracking-history.md)
MIDLINE_MARGIN: Mapping[str, float | None] = MappingProxyType({"arms": 0.5, "legs": None})


@dataclass(frozen=True)
class DepthPrior:
    """Holds a free root's distance along each camera's ray at ``anchor`` (world, the
    frame's prediction): energy ½ k Σ_c (n_c · (p - anchor))², n_c the unit ray from
    camera centre c to the anchor, p the root's position.  Stiffness: ``weight`` times
    the root translation's mean stiffness."""

    weight: float
    anchor: np.ndarray
    centres: Sequence[np.ndarray]

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * float(np.trace(A[:3, :3])) / 3.0

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        root = data.oMi[1]
        p, R = root.translation, root.rotation
        energy = 0.0
        for centre in self.centres:
            n = self.anchor - centre
            n /= max(float(np.linalg.norm(n)), 1e-300)
            jac = n @ R  # d(n . p) / d(root's local linear velocity)
            r = float(n @ (p - self.anchor))
            A[:3, :3] += k * np.outer(jac, jac)
            g[:3] += k * jac * r
            energy += 0.5 * k * r * r
        return energy


#: the feet of :class:`GroundPrior`: bodies whose lowest point at the first pose lies within
#: this share of the model's height above the lowest
FOOT_MARGIN = 0.05


def lowest_points(poses: Sequence[pin.SE3], inner: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n, 3) each ellipsoid's lowest point along ``up`` (world): with ``w = Rᵀ up`` and
    semi-axes L, ``t - R (L² w) / |L w|`` (the support point along -up)."""
    out = np.empty((len(poses), 3))
    for i, (P, L) in enumerate(zip(poses, inner)):
        w = P.rotation.T @ up
        Lw = L * w
        out[i] = P.translation - P.rotation @ (L * Lw) / max(float(np.linalg.norm(Lw)), 1e-300)
    return out


def feet(robot, q: np.ndarray, inner: np.ndarray, up, margin: float = FOOT_MARGIN) -> tuple[tuple[int, ...], float]:
    """The bodies whose lowest point at ``q`` lies within ``margin`` of the model's height
    above the lowest body point (along ``up``, normalized here; world), and that lowest height."""
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    lows = lowest_points(robot.body_poses(q), inner, up) @ up
    return tuple(int(i) for i in np.flatnonzero(lows <= lows.min() + margin * robot.height)), float(lows.min())


@dataclass(frozen=True)
class GroundPrior:
    """Ground contact: the feet's lowest point stands on the floor, and no foot goes
    through it.  With ``h_i = up · p_i - height`` the height above the floor of foot i's
    lowest point p_i (its inner ellipsoid's support point along -``up``; world, spec
    units), energy ½ k max(min_i h_i, 0)² + ½ k Σ_i min(h_i, 0)²: the lowest foot
    pulled down onto the floor, any foot below it pushed up.  One view's unknown depth
    is then fixed where the floor meets the ray through the foot.

    p_i moves with its body to first order (the support point's own slide along the
    surface does not change its height), so dh_i/dv = upᵀ J_v(p_i) + (r_i × up)ᵀ J_ω,
    J the body's joint Jacobian in world-aligned axes at the joint origin o_i and
    r_i = p_i - o_i; each active point adds k ∇h ∇hᵀ and k h ∇h to the Newton system
    (the springs' static update, §2.3.3, eq. 2.28; a spring like eq. 2.33's on one
    coordinate).  Stiffness: ``weight`` times the root translation's mean stiffness.

    ``feet``: body indices; ``inner``: (n_bodies, 3) semi-axes, read at each call (the
    tracker's measured sizes).
    """

    weight: float
    model: pin.Model
    up: np.ndarray
    height: float
    feet: tuple[int, ...]
    inner: np.ndarray
    joints: tuple[int, ...]  # each foot's Pinocchio joint
    offsets: tuple[pin.SE3, ...]  # each foot's centre frame in its joint's frame

    @classmethod
    def of(cls, weight: float, robot, up, inner: np.ndarray, q: np.ndarray, height: float | None = None,
           margin: float = FOOT_MARGIN) -> GroundPrior:
        """The prior on ``robot``'s feet: the bodies whose lowest point at ``q`` lies within
        ``margin`` of the model's height above the lowest body point; the floor at
        ``height`` along ``up``, or (None) at that lowest point."""
        up = np.asarray(up, dtype=float) / np.linalg.norm(up)
        on, lowest = feet(robot, q, inner, up, margin)
        frames = [robot.model.frames[robot.frame_ids[i]] for i in on]
        return cls(weight, robot.model, up, lowest if height is None else float(height), on, inner,
                   tuple(int(f.parentJoint) for f in frames), tuple(pin.SE3(f.placement) for f in frames))

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * float(np.trace(A[:3, :3])) / 3.0

    def heights(self, data: pin.Data) -> tuple[np.ndarray, np.ndarray]:
        """The feet's lowest points (n, 3; world) and their heights above the floor (n,)
        after a forward pass into ``data``."""
        poses = [data.oMi[j] * M for j, M in zip(self.joints, self.offsets)]
        low = lowest_points(poses, self.inner[list(self.feet)], self.up)
        return low, low @ self.up - self.height

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        """As the protocol; ``data`` must hold the joint Jacobians at ``q``
        (``pin.computeJointJacobians``, as the static update computes them)."""
        low, h = self.heights(data)
        lowest = int(np.argmin(h))
        active = [(i, min(float(h[i]), 0.0)) for i in range(len(h)) if h[i] < 0.0]
        if h[lowest] > 0.0:
            active.append((lowest, float(h[lowest])))
        energy = 0.0
        for i, r in active:
            J = pin.getJointJacobian(self.model, data, self.joints[i], pin.LOCAL_WORLD_ALIGNED)
            lever = low[i] - data.oMi[self.joints[i]].translation
            grad = self.up @ J[:3] + np.cross(lever, self.up) @ J[3:]
            A += k * np.outer(grad, grad)
            g += k * r * grad
            energy += 0.5 * k * r * r
        return energy


@dataclass(frozen=True)
class MidlinePrior:
    """Twin limbs keep to their side of the body: the root of each (a collar and an upper
    arm, a thigh: :func:`~kms2pin.ecm.limbs.sides`) keeps its centre at least a share
    (:data:`MIDLINE_MARGIN`, the arms' or the legs') of its offset at rest from the
    sagittal plane of the body it hangs from (the chest, the pelvis).  Two views of a
    walker do not always tell a collar pushed through the chest, or a thigh pulled onto
    its twin's image in a kick, and once a limb is across, ECM carries it over
    (docs/design/tracking-history.md).  The legs are the limbs that hold one of ``feet``
    (by default left out).

    With ``s_k = ±n_aᵀ (t_b - t_a)`` body b's signed offset (n_a the plane's normal in the
    anchor a's axes, turned with it; t the bodies' centres, world; the sign its side at
    rest) and ``h_k = s_k - m_k s_k(rest)`` (m_k the margin), energy ½ k Σ_k min(h_k, 0)²:
    one-sided springs, off while every root keeps past its margin.  With J a body's joint
    Jacobian (world axes at its joint's origin o) and r = t - o, dt = J_v + J_ω × r (so
    nᵀ dt = nᵀ J_v + (r × n)ᵀ J_ω) and dn_a = J_ω,a × n_a, so ∇s = ±(n_aᵀ J_v,b
    + (r_b × n_a)ᵀ J_ω,b - n_aᵀ J_v,a - (r_a × n_a)ᵀ J_ω,a + (n_a × (t_b - t_a))ᵀ J_ω,a);
    each active root adds k ∇h ∇hᵀ and k h ∇h to the Newton system (§2.3.3, eq. 2.28).
    Stiffness: ``weight`` times the root translation's mean stiffness, as the ground prior's."""

    weight: float
    model: pin.Model
    joints: np.ndarray  # (k, 2) the Pinocchio joints of body b and anchor a
    offsets: tuple[pin.SE3, ...]  # (2k,) each one's centre frame in its joint's frame, b then a
    normal: np.ndarray  # (k, 3) the plane's normal in the anchor's axes, times the side at rest
    least: np.ndarray  # (k,) the offset each keeps: its margin times its offset at rest

    @classmethod
    def of(cls, weight: float, robot, feet: Sequence[int] = (),
           margins: Mapping[str, float | None] | None = None) -> MidlinePrior | None:
        """The prior on the roots of ``robot``'s twin limbs, the legs those that hold one
        of the bodies ``feet`` (indices), each kind with its margin (``margins``, by default
        :data:`MIDLINE_MARGIN`; None leaves it out); None if no root is left."""
        margins = MIDLINE_MARGIN if margins is None else margins
        sd = sides(robot, hinged_bodies(robot))
        if sd is None:
            return None
        m = robot.model
        joint_of = [int(m.frames[f].parentJoint) for f in robot.frame_ids]
        foot_joints = {joint_of[i] for i in feet}
        # a leg's root is any root on the anchor of one that holds a foot (a thigh raised at
        # the first pose is still a leg: its twin, standing, names the pelvis)
        legs = {int(a) for b, a in zip(sd.body, sd.anchor) if foot_joints & set(m.subtrees[joint_of[int(b)]])}
        for kind, x in margins.items():
            if x is not None and not 0.0 <= x <= 1.0:
                raise ValueError(f"the midline margin of the {kind} must be in [0, 1] or None, not {x!r}")
        share = [margins.get("legs" if int(a) in legs else "arms") for a in sd.anchor]
        rows = [k for k, x in enumerate(share) if x is not None]
        if not rows:
            return None
        body, anchor, normal = sd.body[rows], sd.anchor[rows], sd.normal[rows] * sd.sign[rows, None]
        frames = [m.frames[robot.frame_ids[int(i)]] for pair in zip(body, anchor) for i in pair]
        poses = robot.body_poses(robot.q_rest)
        rest = np.array([float((poses[a].rotation @ n) @ (poses[b].translation - poses[a].translation))
                         for b, a, n in zip(body, anchor, normal)])
        joints = np.array([int(f.parentJoint) for f in frames]).reshape(-1, 2)
        return cls(weight, m, joints, tuple(pin.SE3(f.placement) for f in frames), normal,
                   np.array([share[k] for k in rows]) * rest)

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * float(np.trace(A[:3, :3])) / 3.0

    def clearances(self, data: pin.Data) -> np.ndarray:
        """Each root's signed offset from its anchor's midline less the one it keeps
        (``h``; negative: pushed out) after a forward pass into ``data``."""
        return np.array([self._offset(data, k)[0] for k in range(len(self.least))])

    def _offset(self, data: pin.Data, k: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """Root k's ``h``, its anchor's normal (world), and both centres (world)."""
        jb, ja = (int(j) for j in self.joints[k])
        tb = (data.oMi[jb] * self.offsets[2 * k]).translation
        Pa = data.oMi[ja] * self.offsets[2 * k + 1]
        n = Pa.rotation @ self.normal[k]
        return float(n @ (tb - Pa.translation)) - float(self.least[k]), n, tb, Pa.translation

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        """As the protocol; ``data`` must hold the joint Jacobians at ``q``
        (``pin.computeJointJacobians``, as the static update computes them)."""
        energy = 0.0
        for row in range(len(self.least)):
            h, n, tb, ta = self._offset(data, row)
            if h >= 0.0:
                continue
            jb, ja = (int(j) for j in self.joints[row])
            Jb = pin.getJointJacobian(self.model, data, jb, pin.LOCAL_WORLD_ALIGNED)
            Ja = pin.getJointJacobian(self.model, data, ja, pin.LOCAL_WORLD_ALIGNED)
            rb, ra = tb - data.oMi[jb].translation, ta - data.oMi[ja].translation
            grad = (n @ Jb[:3] + np.cross(rb, n) @ Jb[3:] - n @ Ja[:3] - np.cross(ra, n) @ Ja[3:]
                    + np.cross(n, tb - ta) @ Ja[3:])
            A += k * np.outer(grad, grad)
            g += k * h * grad
            energy += 0.5 * k * h * h
        return energy


@dataclass(frozen=True)
class UprightPrior:
    """Keeps along ``up`` (world, unit) the free root's axis that is so at the start:
    energy ½ k |R u - up|², R the root's rotation, u that axis in the root's frame (zero
    for any turn about ``up``).  With ω the root's local angular velocity,
    J = d(R u)/dω = -[R u]x R, so JᵀJ = I - u uᵀ and the gradient Jᵀ(R u - up) = Rᵀ (up x R u).
    Stiffness: ``weight`` times the root rotation's mean stiffness."""

    weight: float
    up: np.ndarray
    axis: np.ndarray  # u, root frame
    _projector: np.ndarray = field(init=False, repr=False)
    _skew: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_projector", np.eye(3) - np.outer(self.axis, self.axis))
        object.__setattr__(self, "_skew", pin.skew(self.up))

    @classmethod
    def at(cls, weight: float, up, root_xyzquat: np.ndarray) -> UprightPrior:
        """The prior for a root placed at ``root_xyzquat`` (q[:7]) at the start."""
        up = np.asarray(up, dtype=float)
        return cls(weight, up, pin.XYZQUATToSE3(root_xyzquat).rotation.T @ up)

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * float(A[3, 3] + A[4, 4] + A[5, 5]) / 3.0

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        R = data.oMi[1].rotation
        Ru = R @ self.axis
        A[3:6, 3:6] += k * self._projector
        g[3:6] += k * (R.T @ (self._skew @ Ru))
        d = Ru - self.up
        return 0.5 * k * float(d @ d)


@dataclass(frozen=True)
class RestPrior:
    """Pulls the joints at velocity indices ``dofs`` (every joint, not a free root)
    towards ``q_rest``: energy ½ k Σ_j (q ⊖ q_rest)_j² (``pin.difference``).  Stiffness:
    ``weight`` times those joints' mean stiffness."""

    weight: float
    model: pin.Model
    q_rest: np.ndarray
    dofs: np.ndarray

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * (float(np.add.reduce(A.diagonal()[self.dofs])) / len(self.dofs))  # np.mean's sum

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        d = pin.difference(self.model, self.q_rest, q)[self.dofs]
        A[self.dofs, self.dofs] += k
        g[self.dofs] += k * d
        return 0.5 * k * float(d @ d)


def spine_joints(robot) -> list:
    """The spherical joints on the way from a free root's body to each body that twin
    joints (``left*`` / ``right*`` and the like, :func:`~kms2pin.ecm.limbs.twin_name`) both leave:
    a spine from the pelvis to the chest the arms hang from.  Empty for a fixed root, or
    when the twins branch from the root's body itself."""
    if robot.root != "free":
        return []
    by_child = {j.child: j for j in robot.system.joints if j.child is not None}
    lower = {j.name.lower(): j for j in robot.system.joints}
    coords = {j.name: j for j in robot.joints}
    found: set[str] = set()
    for low, j in lower.items():
        twin = lower.get(twin_name(low, lower))
        if twin is None or twin is j or twin.parent != j.parent:
            continue
        body = j.parent
        while body in by_child and by_child[body].parent is not None:
            up = by_child[body]
            if up.name in coords and coords[up.name].kind == "spherical":
                found.add(up.name)
            body = up.parent
    return [coords[j.name] for j in robot.system.joints if j.name in found]


def bone_axis(robot, joint) -> np.ndarray | None:
    """The unit direction, in ``joint``'s axes, from its point on its child body to the
    mean of that body's other bound vectors' points (the bone a twist turns about); None
    if the body has no other bound vector or they coincide."""
    spec = joint.spec
    body = robot.system.body(spec.child)
    start = np.asarray(spec.child_bvec.pos, dtype=float)
    ends = [np.asarray(b.pos, dtype=float) for name, b in body.bvecs.items() if name != spec.child_bvec.name]
    if not ends:
        return None
    d = np.mean(ends, axis=0) - start
    n = float(np.linalg.norm(d))
    if n < 1e-9 * max(1.0, float(np.abs(start).max())):
        return None
    R_align = robot.model.frames[robot.model.getFrameId(spec.child, pin.FrameType.BODY)].placement.rotation
    return R_align @ (d / n)


def _twist_entry(robot, joint, axis: np.ndarray) -> tuple[int, int, np.ndarray, np.ndarray]:
    """A :class:`TwistPrior` joint: its q and v indices, ``axis`` and its rest quaternion."""
    return joint.idx_q, joint.idx_v, axis, robot.q_rest[joint.idx_q : joint.idx_q + 4].copy()


@dataclass(frozen=True)
class TwistPrior:
    """Holds each listed spherical joint's twist about its child's long axis near rest: a
    body of revolution (an upper arm, a thigh) shows no twist in a silhouette, and only
    the body below it fixes it, barely when that joint is nearly straight.

    With ``Δ = R_restᵀ R = (w, v)`` the joint's rotation relative to rest (a unit
    quaternion, in the joint's axes) and ``a`` the child's long axis in those axes, the
    twist (swing-twist decomposition) is ``θ = 2 atan2(v·a, w)``; energy ½ k Σ θ².  For
    ``R ← R Exp(ω)`` (Pinocchio's spherical joint velocity, local), ``dθ/dω = (w² a +
    w a×v + (v·a) v) / (w² + (v·a)²)``.  Stiffness: ``weight`` times the joints' mean
    stiffness (as :class:`RestPrior`).  With ``free`` > 0 (rad) a twist within ±``free``
    of rest costs nothing: a soft limit, energy ½ k Σ (|θ| - free)² over the joints past it.

    ``joints``: (q index, v index, unit axis a, rest quaternion (x, y, z, w)) per joint.
    """

    weight: float
    joints: Sequence[tuple[int, int, np.ndarray, np.ndarray]]
    dofs: np.ndarray
    free: float = 0.0
    _arrays: tuple = field(init=False, repr=False, compare=False)  # the joints' four fields as float arrays (the kernel's)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_arrays", tuple(np.array([j[m] for j in self.joints], dtype=float) for m in range(4)))

    @classmethod
    def of(cls, weight: float, robot, dofs: np.ndarray, roundness: float = 0.25,
           free_deg: float = 0.0) -> TwistPrior | None:
        """The prior on ``robot``'s spherical joints whose child's inner ellipsoid is nearly
        a body of revolution about its longest axis (the other two semi-axes within
        ``roundness`` of each other), free within ±``free_deg``, or None if there are none."""
        joints = []
        for j in robot.joints:
            if j.kind != "spherical":
                continue
            L = np.asarray(robot.inner(j.spec.child), dtype=float)
            k = int(np.argmax(L))
            other = np.delete(L, k)
            if other.max() > (1.0 + roundness) * other.min() or L[k] < 1.5 * other.max():
                continue
            R_align = robot.model.frames[robot.model.getFrameId(j.spec.child, pin.FrameType.BODY)].placement.rotation
            joints.append(_twist_entry(robot, j, R_align[:, k]))  # the long axis in the joint's axes
        return cls(weight, joints, dofs, np.radians(free_deg)) if joints else None

    @classmethod
    def spine(cls, weight: float, robot, dofs: np.ndarray, free_deg: float = 0.0) -> TwistPrior | None:
        """The prior on a free root's spine (:func:`spine_joints`), each joint's twist taken
        about its child's bone (:func:`bone_axis`), or None if there is none.  A trunk
        turned half a turn, its arms exchanged, casts the same silhouettes (an ellipsoid
        is symmetric under a half turn, the arms are twins): only a prior tells the two
        apart (docs/design/tracking-history.md)."""
        joints = [_twist_entry(robot, j, a) for j in spine_joints(robot) if (a := bone_axis(robot, j)) is not None]
        return cls(weight, joints, dofs, np.radians(free_deg)) if joints else None

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * (float(np.add.reduce(A.diagonal()[self.dofs])) / len(self.dofs))  # np.mean's sum

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        return kernels.twist_prior(q, *self._arrays, self.free, k, A, g)


def standing_priors(robot, pri, q: np.ndarray, inner: np.ndarray) -> list:
    """The priors a tracker holds on every frame, from its :class:`~kms2pin.ecm.options.PriorOptions`
    ``pri`` (each with a weight above 0) for ``robot`` starting at ``q`` with semi-axes
    ``inner``: the upright, rest, twist, spine-twist and midline priors (the depth prior is
    the frame's, the ground prior set once the sizes are measured)."""
    free = robot.root == "free"
    joint_dofs = np.arange(6 if free else 0, robot.model.nv)  # every dof but a free root's six
    out: list = []
    if free and pri.upright > 0:
        out.append(UprightPrior.at(pri.upright, pri.up, q[:7]))
    if pri.rest_prior > 0 and joint_dofs.size:
        rest = q.copy() if pri.rest_pose == "start" else robot.q_rest
        out.append(RestPrior(pri.rest_prior, robot.model, rest, joint_dofs))
    twists = (TwistPrior.of(pri.twist_prior, robot, joint_dofs, free_deg=pri.twist_free) if pri.twist_prior > 0 else None,
              TwistPrior.spine(pri.spine_twist, robot, joint_dofs, pri.spine_free) if pri.spine_twist > 0 else None)
    out += [p for p in twists if p is not None]  # None: no joint to hold
    if free and pri.midline > 0:
        midline = MidlinePrior.of(pri.midline, robot, feet(robot, q, inner, pri.up)[0],
                                  {**MIDLINE_MARGIN, "legs": pri.midline_legs})
        out += [midline] if midline is not None else []
    return out
