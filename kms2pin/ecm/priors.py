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

__all__ = ["DepthPrior", "RestPrior", "UprightPrior"]


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
