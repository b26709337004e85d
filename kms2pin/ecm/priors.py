"""Priors of the tracker's static update: springs on what the images do not fix.

Each prior is a :class:`kms2pin.virtual_work.SpringTerm`: its stiffness is its weight
times a stiffness the data sets (the springs' own Newton matrix at the start of the
update), and it adds its energy, gradient and Gauss-Newton matrix to the update's
Newton system in joint velocities (Pinocchio's tangent space; the free root's first
three are its local linear velocity, the next three its local angular velocity).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

__all__ = ["DepthPrior", "RestPrior", "TwistPrior", "UprightPrior"]


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
        return self.weight * float(np.mean(A[self.dofs, self.dofs]))

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        d = pin.difference(self.model, self.q_rest, q)[self.dofs]
        A[self.dofs, self.dofs] += k
        g[self.dofs] += k * d
        return 0.5 * k * float(d @ d)


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
    stiffness (as :class:`RestPrior`).

    ``joints``: (q index, v index, unit axis a, rest quaternion (x, y, z, w)) per joint.
    """

    weight: float
    joints: Sequence[tuple[int, int, np.ndarray, np.ndarray]]
    dofs: np.ndarray

    @classmethod
    def of(cls, weight: float, robot, dofs: np.ndarray, roundness: float = 0.25) -> TwistPrior | None:
        """The prior on ``robot``'s spherical joints whose child's inner ellipsoid is nearly
        a body of revolution about its longest axis (the other two semi-axes within
        ``roundness`` of each other), or None if there are none."""
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
            axis = R_align[:, k]  # the long axis in the joint's axes
            joints.append((j.idx_q, j.idx_v, axis, robot.q_rest[j.idx_q : j.idx_q + 4].copy()))
        return cls(weight, joints, dofs) if joints else None

    def stiffness(self, A: np.ndarray) -> float:
        return self.weight * float(np.mean(A[self.dofs, self.dofs]))

    def add(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, data: pin.Data, k: float) -> float:
        iq, iv, a, rest = self._arrays
        x = q[iq[:, None] + np.arange(4)]  # (n, 4) x y z w
        rv, rw, xv, xw = rest[:, :3], rest[:, 3], x[:, :3], x[:, 3]
        w = rw * xw + np.einsum("ij,ij->i", rv, xv)  # conj(rest) * x
        v = rw[:, None] * xv - xw[:, None] * rv - np.cross(rv, xv)
        flip = w < 0.0  # the same rotation: the twist in (-pi, pi]
        w, v = np.where(flip, -w, w), np.where(flip[:, None], -v, v)
        norm = np.sqrt(w * w + np.einsum("ij,ij->i", v, v))  # q need not be exactly unit
        w, v = w / norm, v / norm[:, None]
        t = np.einsum("ij,ij->i", v, a)
        theta = 2.0 * np.arctan2(t, w)
        den = np.maximum(w * w + t * t, 1e-300)
        J = ((w * w)[:, None] * a + w[:, None] * np.cross(a, v) + t[:, None] * v) / den[:, None]
        for m, col in enumerate(iv):
            A[col : col + 3, col : col + 3] += k * np.outer(J[m], J[m])
            g[col : col + 3] += k * J[m] * theta[m]
        return 0.5 * k * float(theta @ theta)

    @property
    def _arrays(self):
        arrays = self.__dict__.get("_cached")
        if arrays is None:
            arrays = (np.array([j[0] for j in self.joints]), np.array([j[1] for j in self.joints]),
                      np.array([j[2] for j in self.joints]), np.array([j[3] for j in self.joints]))
            object.__setattr__(self, "_cached", arrays)
        return arrays
