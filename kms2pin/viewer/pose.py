"""Joint angles in degrees: ``--pose`` strings (``name=deg name=deg ...``) <-> ``q``."""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..errors import did_you_mean
from ..robot import Robot
from .errors import PoseError


@dataclass(frozen=True)
class JointSlider:
    """One revolute joint as the control page shows it."""

    name: str
    idx_q: int
    lower_deg: float
    upper_deg: float


def revolute_joints(robot: Robot) -> list[JointSlider]:
    """The one-angle joints of ``robot`` in ``q`` order (the free-flyer root is skipped)."""
    m = robot.model
    out = []
    for jid in range(1, m.njoints):
        j = m.joints[jid]
        if j.nq != 1:
            continue
        lo = round(float(np.degrees(m.lowerPositionLimit[j.idx_q])), 6)
        hi = round(float(np.degrees(m.upperPositionLimit[j.idx_q])), 6)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            lo, hi = -180.0, 180.0
        out.append(JointSlider(m.names[jid], j.idx_q, lo, hi))
    return out


def wrap_deg(deg: float) -> float:
    """An angle in degrees wrapped into [-180, 180] (+-180 keep their sign)."""
    w = (deg + 180.0) % 360.0 - 180.0
    return 180.0 if (w == -180.0 and deg > 0) else w


def _format(deg: float) -> str:
    s = f"{round(deg, 3):.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def joint_angles_deg(robot: Robot, q: np.ndarray) -> dict[str, float]:
    """Revolute joint angles of ``q`` in degrees, in ``q`` order."""
    q = np.asarray(q, dtype=float)
    return {j.name: float(np.degrees(q[j.idx_q])) for j in revolute_joints(robot)}


def pose_string(robot: Robot, q: np.ndarray) -> str:
    """``q`` as a ``--pose`` string, every revolute joint, degrees rounded to 0.001."""
    return " ".join(f"{n}={_format(d)}" for n, d in joint_angles_deg(robot, q).items())


def _tokens(pose: str | Iterable[str]) -> list[str]:
    items = [pose] if isinstance(pose, str) else list(pose)
    out = []
    for item in items:
        out.extend(t for t in re.split(r"[\s,;]+", str(item).strip()) if t)
    return out


def parse_pose(robot: Robot, pose: str | Iterable[str] | None, q: np.ndarray | None = None) -> np.ndarray:
    """Apply ``name=deg`` assignments to ``q`` (default: the rest pose); returns a new q.

    ``pose`` is one string (``"a=10 b=-20"``, also comma separated) or several.
    Angles are degrees, wrapped into [-180, 180] unless the joint has limits in the
    spec.  Unknown names (with a "did you mean"), fixed joints, a joint given twice,
    values that are not finite numbers and angles outside a joint's limits raise
    :class:`PoseError`.
    """
    q = np.array(robot.q_rest if q is None else q, dtype=float)
    if q.shape != (robot.nq,):
        raise PoseError(f"q must have shape ({robot.nq},), not {q.shape}")
    if pose is None:
        return q
    joints = {j.name: j for j in revolute_joints(robot)}
    fixed = {j.name for j in robot.system.joints if j.kind == "fixed"}
    replaced = {j.name for j in robot.system.joints if j.parent is None} if robot.root == "free" else set()
    seen: set[str] = set()
    for tok in _tokens(pose):
        name, sep, value = tok.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name:
            raise PoseError(f"pose entry '{tok}' is not JOINT=DEGREES")
        if name not in joints:
            if name in fixed:
                raise PoseError(f"joint '{name}' is fixed: it has no angle to set")
            if name in robot.joint_names:
                raise PoseError(f"joint '{name}' has more than one coordinate (a free flyer): set it through q")
            if name in replaced:
                raise PoseError(f"joint '{name}' is the root joint, replaced by a free flyer (root=free)")
            choices = list(joints) + sorted(fixed)
            raise PoseError(f"'{robot.system.name}' has no revolute joint '{name}'{did_you_mean(name, choices)}; "
                            f"joints: {', '.join(joints)}")
        if name in seen:
            raise PoseError(f"joint '{name}' is given twice")
        seen.add(name)
        try:
            deg = float(value)
        except ValueError:
            raise PoseError(f"angle of joint '{name}' is not a number: '{value}'") from None
        if not math.isfinite(deg):
            raise PoseError(f"angle of joint '{name}' must be finite, not '{value}'")
        idx = joints[name].idx_q
        if math.isfinite(robot.lower_limits[idx]):  # the spec's limits: no wrapping, checked
            lo, hi = math.degrees(robot.lower_limits[idx]), math.degrees(robot.upper_limits[idx])
            if not lo - 1e-9 <= deg <= hi + 1e-9:
                raise PoseError(f"angle of joint '{name}' ({_format(deg)} deg) is outside its limits "
                                f"{_format(lo)}..{_format(hi)} deg")
            q[idx] = math.radians(min(max(deg, lo), hi))
        else:
            q[idx] = math.radians(wrap_deg(deg))
    return q
