"""The joint-control page: sliders -> HTTP -> Python configuration -> meshcat transforms.

One meshcat server for the whole module (a server must not see hundreds of
browser connections), always shut down at the end.
"""

from __future__ import annotations

import json
import math
import urllib.error
import urllib.request

import numpy as np
import pytest

from kms2pin.viewer import JointControl, pose_string, read_png, revolute_joints, screenshot
from kms2pin.viewer.render import dump_dom, inner_mask

from ._util import joint_q, load


@pytest.fixture(scope="module")
def control():
    robot = load("lowerbody")
    ctl = JointControl(robot)  # starts and owns its meshcat server
    proc = ctl.vis.window.server_proc
    try:
        yield ctl
    finally:
        ctl.close()
        assert proc.poll() is not None, "closing the control stops its meshcat server"


@pytest.fixture(autouse=True)
def _rest(control):
    control.reset()


def post(url: str, body=None, raw: bytes | None = None) -> tuple[int, dict]:
    data = raw if raw is not None else json.dumps(body or {}).encode()
    req = urllib.request.Request(url, data=data, method="POST", headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=10) as res:
            return res.status, json.loads(res.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def get(url: str) -> tuple[int, str]:
    with urllib.request.urlopen(url, timeout=10) as res:
        return res.status, res.read().decode()


def test_page_has_a_slider_per_revolute_joint(control):
    status, page = get(control.url)
    assert status == 200
    for j in revolute_joints(control.robot):
        assert f'id="j-{j.name}"' in page
        assert f"{j.name} <span class=\"range\">[-180&deg;, 180&deg;]</span>" in page
    assert f'<iframe id="viewer" src="{control.meshcat_url}"' in page
    assert "reset to rest" in page and '<textarea id="pose"' in page
    assert control.meshcat_url.startswith("http://127.0.0.1:")


def test_state(control):
    status, text = get(control.url + "state")
    state = json.loads(text)
    assert status == 200 and state["model"] == "lowerBodyBipedal"
    assert [j["name"] for j in state["joints"]] == [j.name for j in revolute_joints(control.robot)]
    assert state["pose"] == pose_string(control.robot, control.robot.q_rest)


def test_joint_post_changes_q_and_only_the_moved_bodies(control):
    robot = control.robot
    before = dict(control.view.drawing.transforms(control.q))
    n_log = len(control.transform_log)
    status, state = post(control.url + "joint", {"name": "leftShin_knee", "deg": 65})
    assert status == 200
    assert {j["name"]: j["deg"] for j in state["joints"]}["leftShin_knee"] == pytest.approx(65)
    assert "leftShin_knee=65" in state["pose"].split()
    assert math.degrees(control.q[joint_q(robot, "leftShin_knee")]) == pytest.approx(65)
    sent = control.transform_log[n_log:]
    assert len(sent) == len(robot.bodies), "one set_transform per body, no geometry"
    moved = {path.rsplit("/", 1)[1] for path, T in sent if not np.allclose(T, before[path])}
    assert moved == {"leftShin", "leftFoot"}


def test_python_side_set_joint_is_seen_by_the_page(control):
    control.set_joint("rightThigh_hip", -30)
    _, text = get(control.url + "state")
    assert "rightThigh_hip=-30" in json.loads(text)["pose"].split()


def test_bad_requests(control):
    q = control.q
    status, body = post(control.url + "joint", {"name": "leftShin_kne", "deg": 5})
    assert status == 400 and "did you mean 'leftShin_knee'" in body["error"]
    status, body = post(control.url + "joint", {"name": "leftShin_knee", "deg": "abc"})
    assert status == 400 and body["error"] == "bad request: 'deg' must be a number, not 'abc'"
    status, body = post(control.url + "joint", raw=b"{not json")
    assert status == 400
    status, body = post(control.url + "pose", {"pose": "trunk_waist=3"})
    assert status == 400 and "fixed" in body["error"]
    status, body = post(control.url + "nothing", {})
    assert status == 404
    np.testing.assert_array_equal(control.q, q)


def test_pose_and_reset(control):
    robot = control.robot
    pose = "leftThigh_hip=10 rightFoot_ankle=-45.5"
    status, state = post(control.url + "pose", {"pose": pose})
    assert status == 200
    expected = robot.q_rest.copy()
    expected[joint_q(robot, "leftThigh_hip")] = math.radians(10)
    expected[joint_q(robot, "rightFoot_ankle")] = math.radians(-45.5)
    np.testing.assert_allclose(control.q, expected)
    status, state = post(control.url + "reset")
    np.testing.assert_allclose(control.q, robot.q_rest)
    assert state["pose"] == pose_string(robot, robot.q_rest)
    status, _ = post(control.url + "camera", {"view": "side"})
    assert status == 200
    status, body = post(control.url + "camera", {"view": "sid"})
    assert status == 400 and "did you mean 'side'" in body["error"]
    post(control.url + "camera", {"view": "front"})


@pytest.mark.browser
def test_page_sliders_drive_the_model_in_a_browser(control):
    """The page's own JavaScript: ?pose= moves sliders with input events, which POST."""
    robot = control.robot
    n = control.updates
    dom = dump_dom(control.url + "?pose=leftShin_knee=33,rightShin_knee=-12.5")
    assert math.degrees(control.q[joint_q(robot, "leftShin_knee")]) == pytest.approx(33)
    assert math.degrees(control.q[joint_q(robot, "rightShin_knee")]) == pytest.approx(-12.5)
    assert control.updates >= n + 2
    assert 'id="o-leftShin_knee">33</output>' in dom


@pytest.mark.browser
def test_meshcat_page_shows_the_new_configuration(control, tmp_path):
    """Screenshots of the live meshcat page before and after a joint POST differ where the leg moved."""
    screenshot(control.meshcat_url, tmp_path / "rest.png", 320, 400)
    status, _ = post(control.url + "joint", {"name": "leftThigh_hip", "deg": -10})  # leg swung back up
    assert status == 200
    screenshot(control.meshcat_url, tmp_path / "moved.png", 320, 400)
    a, b = inner_mask(read_png(tmp_path / "rest.png")), inner_mask(read_png(tmp_path / "moved.png"))
    assert a.sum() > 2000 and b.sum() > 2000
    assert (a ^ b).sum() > 0.1 * a.sum()


@pytest.fixture(scope="module")
def mixed_control(control):
    """The control page of a model with every joint type, drawn into the same meshcat server."""
    from conftest import MIXED_JOINTS

    import kms2pin

    ctl = JointControl(kms2pin.load(kms2pin.parse(MIXED_JOINTS)), control.vis)
    try:
        yield ctl
    finally:
        ctl.close()


def test_a_spherical_joint_has_three_sliders_and_a_prismatic_one_a_length(mixed_control):
    _, page = get(mixed_control.url)
    for axis, (lo, hi) in zip("xyz", ((-180, 180), (-90, 90), (-180, 180))):
        assert f'b_ball_{axis} <span class="range">[{lo}&deg;, {hi}&deg;]</span>' in page
    assert 'c_slide <span class="range">[-0.4, 0.6]</span>' in page and 'id="j-b_ball"' not in page
    status, state = post(mixed_control.url + "joint", {"name": "b_ball_y", "value": 30})
    assert status == 200
    joints = {j["name"]: j for j in state["joints"]}
    assert joints["b_ball_y"]["value"] == pytest.approx(30) and joints["b_ball_y"]["unit"] == "deg"
    status, state = post(mixed_control.url + "joint", {"name": "c_slide", "value": 0.25})
    joints = {j["name"]: j for j in state["joints"]}
    assert status == 200 and joints["c_slide"]["value"] == 0.25 and joints["c_slide"]["unit"] == "length"
    assert "deg" not in joints["c_slide"] and "c_slide=0.25" in state["pose"].split()
    status, body = post(mixed_control.url + "joint", {"name": "c_slide", "value": 2})
    assert status == 400 and "outside its limits -0.4..0.6" in body["error"]


@pytest.mark.browser
def test_page_sliders_of_the_new_joints_drive_the_model_in_a_browser(mixed_control):
    robot = mixed_control.robot
    dump_dom(mixed_control.url + "?pose=b_ball_z=-25,c_slide=0.35")
    values = dict(zip(robot.coordinate_names, robot.coordinates(mixed_control.q)))
    assert values["b_ball_z"] == pytest.approx(-25, abs=1e-9) and values["c_slide"] == pytest.approx(0.35)
