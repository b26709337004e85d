"""Joint coordinates as the control page's sliders and ``--pose`` strings
(``name=value name=value ...``) <-> ``q``.

One slider per coordinate of :attr:`Robot.coordinate_names` but a free root's: a
revolute joint's angle (degrees), a spherical joint's three X-Y-Z angles ``<joint>_x``,
``<joint>_y``, ``<joint>_z`` (degrees; R = Rx Ry Rz, the URDF's three joints) and a
prismatic joint's offset (spec length units).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..errors import RobotError, did_you_mean
from ..robot import Robot
from .errors import PoseError


@dataclass(frozen=True)
class JointSlider:
    """One slider of the control page.

    ``name`` is the coordinate (:attr:`Robot.coordinate_names`), ``joint`` its Pinocchio
    joint, ``kind`` the joint's type, ``axis`` which of a spherical joint's X-Y-Z angles
    (0, 1, 2), ``idx_q`` the joint's first entry of ``q``; ``lower`` and ``upper`` the
    range in ``unit`` (``"deg"``, or ``"length"``: spec length units).
    """

    name: str
    idx_q: int
    lower: float
    upper: float
    kind: str = "revolute"
    joint: str = ""
    axis: int = 0

    @property
    def unit(self) -> str:
        return "length" if self.kind == "prismatic" else "deg"


def _range(robot: Robot, idx: int, kind: str) -> tuple[float, float]:
    """A slider's range: the spec's limits, else +-180 deg, or +- the model's height for an
    unlimited prismatic joint."""
    lo, hi = robot.lower_limits[idx], robot.upper_limits[idx]
    if np.isfinite(lo):
        return (round(math.degrees(lo), 6), round(math.degrees(hi), 6)) if kind == "revolute" else (lo, hi)
    if kind == "prismatic":
        span = float(f"{robot.height:.2g}")
        return -span, span
    return -180.0, 180.0


def joint_sliders(robot: Robot) -> list[JointSlider]:
    """Every slider of ``robot`` in ``q`` order (a free root has none)."""
    out = []
    for j in robot.joints:
        if j.kind == "spherical":  # the middle X-Y-Z angle spans a half turn
            out += [JointSlider(n, j.idx_q, *((-90.0, 90.0) if k == 1 else (-180.0, 180.0)), j.kind, j.name, k)
                    for k, n in enumerate(j.names)]
        elif j.kind in ("revolute", "prismatic"):
            out.append(JointSlider(j.name, j.idx_q, *_range(robot, j.idx_q, j.kind), j.kind, j.name))
    return out


def revolute_joints(robot: Robot) -> list[JointSlider]:
    """The sliders of ``robot``'s revolute joints, in ``q`` order."""
    return [s for s in joint_sliders(robot) if s.kind == "revolute"]


def wrap_deg(deg: float) -> float:
    """An angle in degrees wrapped into [-180, 180] (+-180 keep their sign)."""
    w = (deg + 180.0) % 360.0 - 180.0
    return 180.0 if (w == -180.0 and deg > 0) else w


def _format(x: float) -> str:
    s = f"{round(x, 3):.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def slider_values(robot: Robot, q: np.ndarray) -> dict[str, float]:
    """Every slider's value at ``q`` (degrees, or spec length units), in ``q`` order."""
    values = dict(zip(robot.coordinate_names, robot.coordinates(np.asarray(q, dtype=float))))
    return {s.name: float(values[s.name]) for s in joint_sliders(robot)}


def joint_angles_deg(robot: Robot, q: np.ndarray) -> dict[str, float]:
    """Revolute joint angles of ``q`` in degrees, in ``q`` order."""
    q = np.asarray(q, dtype=float)
    return {j.name: float(np.degrees(q[j.idx_q])) for j in revolute_joints(robot)}


def pose_string(robot: Robot, q: np.ndarray) -> str:
    """``q`` as a ``--pose`` string: every slider, rounded to 0.001."""
    return " ".join(f"{n}={_format(v)}" for n, v in slider_values(robot, q).items())


def _tokens(pose: str | Iterable[str]) -> list[str]:
    items = [pose] if isinstance(pose, str) else list(pose)
    out = []
    for item in items:
        out.extend(t for t in re.split(r"[\s,;]+", str(item).strip()) if t)
    return out


def _unknown(robot: Robot, name: str, sliders: dict[str, JointSlider]) -> PoseError:
    """The error for ``name`` that names no slider."""
    kinds = {j.name: j.kind for j in robot.system.joints}
    replaced = {j.name for j in robot.system.joints if j.parent is None} if robot.root == "free" else set()
    if name in replaced:
        return PoseError(f"joint '{name}' is the root joint, replaced by a free flyer (root=free)")
    if kinds.get(name) == "fixed":
        return PoseError(f"joint '{name}' is fixed: it has no angle to set")
    if kinds.get(name) == "spherical":
        return PoseError(f"joint '{name}' is spherical: set {name}_x, {name}_y and {name}_z "
                         "(its X-Y-Z angles, degrees)")
    if name in robot.joint_names:
        return PoseError(f"joint '{name}' has more than one coordinate (a free flyer): set it through q")
    choices = list(sliders) + sorted(n for n, k in kinds.items() if k == "fixed")
    return PoseError(f"'{robot.system.name}' has no joint coordinate '{name}'{did_you_mean(name, choices)}; "
                     f"coordinates: {', '.join(sliders)}")


def _value(s: JointSlider, value: str, robot: Robot) -> float:
    """A slider's value from its text, checked against the range (angles of joints
    without limits wrap into [-180, 180])."""
    what = "offset" if s.kind == "prismatic" else "angle"
    try:
        x = float(value)
    except ValueError:
        raise PoseError(f"{what} of joint '{s.name}' is not a number: '{value}'") from None
    if not math.isfinite(x):
        raise PoseError(f"{what} of joint '{s.name}' must be finite, not '{value}'")
    limited = bool(np.isfinite(robot.lower_limits[s.idx_q])) and s.kind != "spherical"
    if limited or (s.kind == "spherical" and s.axis == 1):
        lo, hi = (s.lower, s.upper) if s.kind != "revolute" else (
            math.degrees(robot.lower_limits[s.idx_q]), math.degrees(robot.upper_limits[s.idx_q]))
        unit = "" if s.kind == "prismatic" else " deg"
        if not lo - 1e-9 <= x <= hi + 1e-9:
            why = "its limits" if limited else "the range of the middle X-Y-Z angle"
            raise PoseError(f"{what} of joint '{s.name}' ({_format(x)}{unit}) is outside {why} "
                            f"{_format(lo)}..{_format(hi)}{unit}")
        return min(max(x, lo), hi)
    return x if s.kind == "prismatic" else wrap_deg(x)


def parse_pose(robot: Robot, pose: str | Iterable[str] | None, q: np.ndarray | None = None) -> np.ndarray:
    """Apply ``name=value`` assignments to ``q`` (default: the rest pose); returns a new q.

    ``pose`` is one string (``"a=10 b=-20"``, also comma separated) or several.  Names
    are the sliders' (:func:`joint_sliders`): revolute angles and a spherical joint's
    X-Y-Z angles (``hip_x=10 hip_y=-20 hip_z=5``; those not given keep their current
    value; the middle one within [-90, 90]) in degrees, wrapped into [-180, 180] unless
    the joint has limits in the spec; prismatic offsets in spec length units.  Unknown
    names (with a "did you mean"), fixed joints, a coordinate given twice, values that
    are not finite numbers and values outside a joint's limits raise :class:`PoseError`.
    With loop closures the result is projected onto them with the named joints held (the
    closing joints follow, :meth:`Robot.project`); a pose the loops cannot reach raises
    :class:`PoseError`.
    """
    q = np.array(robot.q_rest if q is None else q, dtype=float)
    if q.shape != (robot.nq,):
        raise PoseError(f"q must have shape ({robot.nq},), not {q.shape}")
    if pose is None:
        return q
    sliders = {s.name: s for s in joint_sliders(robot)}
    values: dict[str, float] = {}
    for tok in _tokens(pose):
        name, sep, value = (part.strip() for part in tok.partition("="))
        if not sep or not name:
            raise PoseError(f"pose entry '{tok}' is not JOINT=DEGREES (JOINT=LENGTH for a prismatic joint)")
        s = sliders.get(name)
        if s is None:
            raise _unknown(robot, name, sliders)
        if name in values:
            raise PoseError(f"joint '{name}' is given twice")
        values[name] = _value(s, value, robot)
    if robot.closures and values:
        return _closed_pose(robot, q, values)
    return robot.with_coordinates(q, values)


#: The largest step of a slider's joint between two projections onto the loops (degrees;
#: a prismatic joint: this many hundredths of the model's height), so that the mechanism
#: follows the joint continuously and stays in its assembly mode.
LOOP_STEP_DEG = 10.0


def _closed_pose(robot: Robot, q: np.ndarray, values: dict[str, float]) -> np.ndarray:
    """``q`` with the named coordinates set, the loops closed after each of a few steps there
    (:data:`LOOP_STEP_DEG`) with those joints held (:meth:`Robot.project`)."""
    target = robot.with_coordinates(q, values)
    joints = robot.coords.joints_of(list(values))
    held = [v for j in joints for v in range(j.idx_v, j.idx_v + (3 if j.kind == "spherical" else 1))]
    d = pin.difference(robot.model, q, target)
    scale = np.full(len(d), math.radians(LOOP_STEP_DEG))
    for j in joints:
        if j.kind == "prismatic":
            scale[j.idx_v] = 0.01 * LOOP_STEP_DEG * robot.height
    steps = max(1, math.ceil(float(np.max(np.abs(d) / scale))))
    try:
        for k in range(1, steps + 1):
            q = robot.with_coordinates(q, values) if k == steps else pin.integrate(robot.model, q, d / steps)
            q = robot.project(q, hold=held)
    except RobotError:
        shown = " ".join(f"{n}={v:g}" for n, v in values.items())
        raise PoseError(f"{shown}: the loops of '{robot.system.name}' cannot be closed with "
                        f"{'this joint' if len(values) == 1 else 'these joints'} there; the pose is unchanged") from None
    return q
