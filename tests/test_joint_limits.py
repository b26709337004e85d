"""Joint limits: ``revolute(a, b, defaultAngle, lower, upper)`` (a kms2pin extension)
from the spec to the URDF, Pinocchio, the synthetic motions and the tracker."""

from __future__ import annotations

import json
import math
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from _interop import check_urdf_exe as _check_urdf
from conftest import SPECS

from kms2pin import SpecError, parse_text
from kms2pin.cli import main
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.robot import load

LEG = """bvec origin {{ pos(0, 0, 8); orient(0, 1, 0); }}
rigidBodySystem leg {{
    ellipsoidBody thigh {{ innerLam(0.23, 0.23, 0.41); outerLam(0.29, 0.29, 0.51);
                          bvec hip  {{ pos(0, 0,  0.33); orient(0, 1, 0); }}
                          bvec knee {{ pos(0, 0, -0.33); orient(-1, 0, 0); }} }}
    ellipsoidBody shin {{ innerLam(0.2, 0.2, 0.5); outerLam(0.25, 0.25, 0.6);
                         bvec knee {{ pos(0, 0, 0.45); orient(-1, 0, 0); }} }}
    constraint revolute(thigh.knee, shin.knee, {knee});
}}
constraint revolute(leg.thigh.hip, origin, {hip});
"""


def leg(knee: str = "20, 0, 150", hip: str = "170, 100, 250") -> str:
    return LEG.format(knee=knee, hip=hip)


def spec_error(text: str) -> str:
    with pytest.raises(SpecError) as err:
        parse_text(text, "leg.kms")
    return str(err.value)


def test_limits_are_parsed_in_degrees_and_are_optional():
    joints = {j.name: j for j in parse_text(leg()).systems[0].joints}
    assert joints["shin_knee"].limits == (0.0, 150.0)
    assert joints["thigh_hip"].limits == (100.0, 250.0)
    assert joints["thigh_hip"].default_angle == 170.0
    plain = parse_text(leg(knee="20", hip="0")).systems[0].joints
    assert all(j.limits is None for j in plain)


@pytest.mark.parametrize(
    "knee, line_col, words",
    [
        ("20, 150, 0", "8:52", "lower joint limit (150 deg) must be below the upper one (0 deg)"),
        ("200, 0, 150", "8:48", "default angle 200 deg is outside the joint limits 0..150"),
        ("20, 0", "8:5", "takes 2, 3 or 5 arguments, not 4"),
        ("20, -100, 300", "8:52", "span more than a full turn"),
        ("20, 0, true", "8:55", "upper joint limit must be a double (degrees), not bool"),
    ],
)
def test_bad_limits_point_at_the_argument(knee, line_col, words):
    msg = spec_error(leg(knee=knee))
    assert f"leg.kms:{line_col}: error:" in msg
    assert words in msg


def test_fixed_joints_take_no_limits():
    text = leg().replace("revolute(thigh.knee, shin.knee, 20, 0, 150)", "fixed(thigh.knee, shin.knee, 0, 1)")
    assert "constraint fixed(a, b) takes 2 arguments, not 4" in spec_error(text)


def test_urdf_srdf_and_pinocchio_carry_the_limits(tmp_path):
    spec = tmp_path / "leg.kms"
    spec.write_text(leg())
    assert main(["export", str(spec), "-o", str(tmp_path / "out")]) == 0
    urdf = tmp_path / "out" / "leg.urdf"
    out = subprocess.run([_check_urdf(), str(urdf)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    limits = {j.get("name"): j.find("limit") for j in ET.parse(urdf).getroot().iter("joint")}
    assert float(limits["shin_knee"].get("lower")) == 0.0
    assert float(limits["shin_knee"].get("upper")) == pytest.approx(math.radians(150), abs=1e-12)
    assert float(limits["thigh_hip"].get("lower")) == pytest.approx(math.radians(100), abs=1e-12)
    # a limited rest angle is written as given (170 deg), not wrapped into (-180, 180]
    rest = {j.get("name"): float(j.get("value")) for j in ET.parse(urdf.with_suffix(".srdf")).getroot().iter("joint") if j.get("value")}
    assert rest["thigh_hip"] == pytest.approx(math.radians(170), abs=1e-12)

    robot = load(spec)
    idx = {robot.model.names[j]: robot.model.joints[j].idx_q for j in range(1, robot.model.njoints)}
    for name, lo, hi in (("thigh_hip", 100, 250), ("shin_knee", 0, 150)):
        k = idx[name]
        assert robot.model.lowerPositionLimit[k] == pytest.approx(math.radians(lo))
        assert robot.model.upperPositionLimit[k] == pytest.approx(math.radians(hi))
        assert robot.lower_limits[k] == pytest.approx(math.radians(lo))
        assert robot.upper_limits[k] == pytest.approx(math.radians(hi))
    assert np.degrees(robot.q_rest[idx["thigh_hip"]]) == pytest.approx(170.0)
    clamped = robot.clamp(np.radians([300.0, -10.0]))
    assert np.degrees(clamped) == pytest.approx([250.0, 0.0])


def test_thesis_specs_have_no_limits_and_the_anatomical_ones_do(tmp_path):
    assert not load(SPECS / "lowerbody.kms").has_limits
    for name in ("lowerbody", "fullbody"):
        path = SPECS / "anatomical" / f"{name}.kms"
        robot = load(path, root="free")
        assert robot.has_limits
        assert np.all(robot.q_rest >= robot.lower_limits) and np.all(robot.q_rest <= robot.upper_limits)
        assert main(["export", str(path), "-o", str(tmp_path / name)]) == 0
        urdf = next((tmp_path / name).glob("*.urdf"))
        out = subprocess.run([_check_urdf(), str(urdf)], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stdout + out.stderr
        # the same bodies and joints as the thesis's model: only the limits differ
        thesis = load(SPECS / f"{name}.kms", root="free")
        assert robot.joint_names == thesis.joint_names
        assert np.allclose(robot.q_rest, thesis.q_rest)


def test_check_reports_the_limits(capsys):
    assert main(["check", str(SPECS / "anatomical" / "lowerbody.kms"), "--json"]) == 0
    bodies = {b["name"]: b for b in json.loads(capsys.readouterr().out)["systems"][0]["bodies"]}
    assert bodies["leftShin"]["joint"]["limits_deg"] == [0.0, 150.0]
    assert bodies["pelvis"]["joint"]["limits_deg"] is None


def test_synthetic_motions_stay_within_the_limits():
    robot = load(SPECS / "anatomical" / "lowerbody.kms", root="free")
    q = make_motion(robot, "sweep", 120)  # +-40 deg about the rest angles: the knees hit 0
    assert np.all(q >= robot.lower_limits - 1e-12) and np.all(q <= robot.upper_limits + 1e-12)
    knee = robot.model.joints[robot.model.getJointId("leftShin_knee")].idx_q
    assert np.isclose(q[:, knee].min(), 0.0)


def test_the_tracker_keeps_a_joint_within_its_limits():
    # silhouettes of a knee bent 40 deg backwards: the anatomical model's knee stops at 0
    robot = load(SPECS / "anatomical" / "lowerbody.kms", root="free")
    m = robot.model
    knee = m.joints[m.getJointId("leftShin_knee")].idx_q
    shown = robot.q_rest.copy()
    shown[knee] = math.radians(-40.0)
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    q0 = robot.q_rest.copy()
    q0[knee] = math.radians(5.0)
    tr = Tracker(robot, cams, q0=q0, calibrate_sizes=False, max_iterations=10)
    r = tr.step(render(robot, shown, cams))
    assert 0.0 <= r.q[knee] < math.radians(3.0)  # pressed against the limit
    assert np.all(r.q >= robot.lower_limits) and np.all(r.q <= robot.upper_limits)
    # the thesis's model, without limits, follows the knee backwards
    thesis = load(SPECS / "lowerbody.kms", root="free")
    r = Tracker(thesis, cams, q0=q0, calibrate_sizes=False, max_iterations=10).step(render(thesis, shown, cams))
    assert r.q[knee] < math.radians(-25.0)


def _spring_energy(robot, q, targets) -> float:
    """1/2 sum (q_max - q')^2 over the bodies' maximal coordinates (eq. 2.33, k = 1),
    each target's Euler parameters on the primary's side (§2.2.1): from Pinocchio's
    forward kinematics alone."""
    X = robot.maximal_coordinates(q)
    T = targets.copy()
    flip = np.einsum("ij,ij->i", X[:, 3:], T[:, 3:]) < 0
    T[flip, 3:] *= -1
    return 0.5 * float(((X - T) ** 2).sum())


def test_static_update_stops_at_a_limit_at_the_bounded_minimum():
    """Springs pull the knee 30 deg past straight; with the anatomical limits the update
    ends at the knee's limit (0) and at the same configuration and energy as a bounded
    quasi-Newton minimisation (SciPy's L-BFGS-B) of the spring energy."""
    from scipy.optimize import minimize

    from kms2pin.virtual_work import static_update

    robot = load(SPECS / "anatomical" / "lowerbody.kms")
    m = robot.model
    knee = m.joints[m.getJointId("leftShin_knee")].idx_q
    shown = robot.q_rest.copy()
    shown[knee] = math.radians(-30.0)
    shown[m.joints[m.getJointId("rightThigh_hip")].idx_q] += math.radians(15.0)
    targets = robot.maximal_coordinates(shown)
    targets[:, :3] += np.random.default_rng(4).normal(0, 0.02, (len(targets), 3))  # not exactly reachable

    res = static_update(robot, robot.q_rest, targets)
    assert res.converged, res.message
    assert res.q[knee] == pytest.approx(0.0, abs=1e-12)  # held at its lower limit
    assert np.all(res.q >= robot.lower_limits) and np.all(res.q <= robot.upper_limits)

    bounds = list(zip(robot.lower_limits, robot.upper_limits))
    bounds = [(None if not np.isfinite(a) else a, None if not np.isfinite(b) else b) for a, b in bounds]
    ref = minimize(lambda q: _spring_energy(robot, q, targets), robot.q_rest, method="L-BFGS-B", bounds=bounds,
                   options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 5000})
    assert res.energy == pytest.approx(_spring_energy(robot, res.q, targets), rel=1e-9)
    assert res.energy <= ref.fun * (1 + 1e-6)
    np.testing.assert_allclose(res.q, ref.x, atol=2e-3)

    free = static_update(load(SPECS / "lowerbody.kms"), robot.q_rest, targets)  # the thesis's model
    assert free.q[knee] < math.radians(-20.0) and free.energy < res.energy
