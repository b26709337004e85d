"""Body sizes: the subject's semi-axes measured on the first frame and refined as it turns.

The model's sizes rarely match the subject's.  In one view a body that is too long or
too wide is otherwise explained by tilting or turning it (a 10 % length error equals a
26° tilt), so the first frame, whose pose is known, is used to measure them: per body
and axis a log-scale is fit by Gauss-Newton to the M-step's silhouette cost
(:func:`kms2pin.ecm.mstep.fit_body_scale`), alternating with the E-step as the edge
width anneals.  Later frames add their evidence: the sizes are the information-weighted
mean of every frame's fit, pulled towards the spec's by :data:`SIZE_PRIOR` of the
largest information, ``x = (Σ H_k + λ I)⁻¹ Σ H_k x_k`` (``x`` the log semi-axes).  An
axis no camera sees (along the viewing ray) keeps its estimate until a frame shows it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from ..errors import OptionError
from ..robot import Robot
from .mstep import fit_body_scale

__all__ = ["SCALE_MAX", "SCALE_MIN", "SIZE_PRIOR", "BodySizes"]

#: bounds of the measured body sizes relative to the spec's
SCALE_MIN, SCALE_MAX = float(np.exp(-0.35)), float(np.exp(0.35))
#: pull of the refined sizes towards the spec's, relative to a body's largest size information
SIZE_PRIOR = 0.01

#: an E-step at a configuration and edge width: (body poses, each body's views)
EStep = Callable[[np.ndarray, float], tuple[list, list]]


class BodySizes:
    """The inner and outer semi-axes (n_bodies, 3) the tracker uses: the spec's times
    :attr:`scales`, and the evidence on them so far."""

    def __init__(self, robot: Robot, scales=None):
        self.spec_inner = np.array([robot.inner(b) for b in robot.bodies], dtype=float).reshape(-1, 3)
        self.spec_outer = np.array([robot.outer(b) for b in robot.bodies], dtype=float).reshape(-1, 3)
        self.scales = np.ones((len(robot.bodies), 3))
        if scales is not None:
            sc = np.asarray(scales, dtype=float)
            if sc.shape != self.scales.shape or not np.all(sc > 0):
                raise OptionError(f"scales must be positive, shape {self.scales.shape}; got shape {sc.shape}")
            self.scales = sc.copy()
        self.inner = self.spec_inner * self.scales
        self.outer = self.spec_outer * self.scales
        self.calibrated = False
        # per body the sum of its size fits' Gauss-Newton matrices (in log semi-axes), and
        # of those matrices times the fitted log-scales
        self._info = np.zeros((len(robot.bodies), 3, 3))
        self._rhs = np.zeros((len(robot.bodies), 3))

    def set_scales(self, i: int, scales: np.ndarray) -> None:
        """Body ``i``'s semi-axis factors (clipped to [SCALE_MIN, SCALE_MAX]) and its inner
        and outer ellipsoids to match."""
        self.scales[i] = np.clip(scales, SCALE_MIN, SCALE_MAX)
        self.inner[i] = self.spec_inner[i] * self.scales[i]
        self.outer[i] = self.spec_outer[i] * self.scales[i]

    def set_all(self, scales) -> None:
        """Every body's semi-axis factors (n_bodies, 3), as :meth:`set_scales`."""
        for i, sc in enumerate(np.asarray(scales, dtype=float).reshape(self.scales.shape)):
            self.set_scales(i, sc)

    def remeasured(self, frames: Iterable[tuple[EStep, np.ndarray]], delta: float) -> np.ndarray:
        """(n_bodies, 3) the sizes from the evidence of ``frames`` alone (each an E-step at
        the sizes in use and the configuration it is held at): every frame's fit from the
        sizes in use, combined as :meth:`refine` combines them (module docstring), in any
        order the same; this object is left as it was."""
        info, rhs = np.zeros_like(self._info), np.zeros_like(self._rhs)
        for e_step, q in frames:
            poses, views = e_step(q, delta)
            for i, v in enumerate(views):
                H, r = self._evidence(i, v, poses[i])
                info[i] += H
                rhs[i] += r
        out = self.scales.copy()
        for i in range(len(out)):
            x = _pooled(info[i], rhs[i])
            if x is not None:  # a body no frame saw keeps its size
                out[i] = np.clip(np.exp(x), SCALE_MIN, SCALE_MAX)
        return out

    def calibrate(self, e_step: EStep, q: np.ndarray, rounds: int, delta_start: float, delta_final: float) -> None:
        """Fit every body's semi-axes with the configuration held at ``q``: ``rounds`` of
        E-step and size fit as the edge width halves from ``delta_start`` to
        ``delta_final`` pixels.  The last round's fits start the evidence afresh."""
        delta = delta_start
        for _ in range(max(1, rounds)):
            poses, views = e_step(q, delta)
            for i, v in enumerate(views):
                f, H = fit_body_scale(v, poses[i], self.inner[i], iterations=2)
                self.set_scales(i, self.scales[i] * f)
                self._info[i] = H
                self._rhs[i] = H @ np.log(self.scales[i])
            delta = max(delta_final, 0.5 * delta)
        self.calibrated = True

    def refine(self, e_step: EStep, q: np.ndarray, delta: float) -> None:
        """Fold one tracked frame's evidence, fitted with the pose held at ``q``, into the
        sizes (module docstring)."""
        poses, views = e_step(q, delta)
        for i, v in enumerate(views):
            H, r = self._evidence(i, v, poses[i])
            self._info[i] += H
            self._rhs[i] += r
            x = _pooled(self._info[i], self._rhs[i])
            if x is not None:  # something seen of this body
                self.set_scales(i, np.exp(x))

    def _evidence(self, i: int, view, pose) -> tuple[np.ndarray, np.ndarray]:
        """Body ``i``'s size fit on one frame's ``view`` from the sizes in use: the terms
        (H, H x) that :meth:`refine` and :meth:`remeasured` sum (``x`` its log-scales)."""
        f, H = fit_body_scale(view, pose, self.inner[i], iterations=2)
        return H, H @ np.log(self.scales[i] * f)


def _pooled(info: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """The log-scales of one body's summed evidence, pulled towards the spec's by
    :data:`SIZE_PRIOR` of its largest information (module docstring); None if it has none."""
    lam = SIZE_PRIOR * float(np.max(np.diag(info)))
    return None if lam <= 0.0 else np.linalg.solve(info + lam * np.eye(3), rhs)
