"""Small helpers shared by the ECM geometry modules (poses and semi-axes)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin


def pose_arrays(world_T_body: pin.SE3 | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(R, t)`` (3x3, 3) of a pose given as ``pin.SE3`` or a 4x4 matrix."""
    if isinstance(world_T_body, pin.SE3):
        return np.asarray(world_T_body.rotation, dtype=float), np.asarray(world_T_body.translation, dtype=float)
    m = np.asarray(world_T_body, dtype=float)
    if m.shape != (4, 4):
        raise ValueError(f"pose must be a pin.SE3 or a 4x4 matrix, got shape {m.shape}")
    return m[:3, :3].copy(), m[:3, 3].copy()


def semi_axes_array(semi_axes: Sequence[float] | np.ndarray, what: str = "semi_axes") -> np.ndarray:
    """Validate ellipsoid semi-axes: three finite positive lengths."""
    a = np.asarray(semi_axes, dtype=float)
    if a.shape != (3,) or not (a > 0).all() or not np.isfinite(a).all():
        raise ValueError(f"{what} must be three finite positive lengths, got {semi_axes!r}")
    return a


def inner_outer_arrays(
    inner: Sequence[float] | np.ndarray, outer: Sequence[float] | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Validate a concentric inner/outer pair: the outer must contain the inner."""
    li = semi_axes_array(inner, "inner")
    lo = semi_axes_array(outer, "outer")
    if (lo < li).any():
        raise ValueError(f"outer semi-axes {lo.tolist()} must be >= inner {li.tolist()} on every axis")
    return li, lo
