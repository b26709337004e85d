"""Trajectories as meshcat animations inside the standalone page."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.viewer import ViewerError, animate, write_animation_html
from kms2pin.viewer.scene import ROOT

from ._util import joint_q, page_commands


def _trajectory(robot, T=12):
    traj = np.repeat(robot.q_rest[None], T, axis=0)
    traj[:, joint_q(robot, "leftThigh_hip")] += np.linspace(0.0, 1.0, T)
    return traj


def test_animation_html_holds_every_frame(lowerbody, tmp_path):
    traj = _trajectory(lowerbody)
    path = write_animation_html(lowerbody, traj, 24, tmp_path / "walk.html")
    cmds = page_commands(path.read_text())
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    assert cmds[-1] is anim, "the animation comes after the objects it animates"
    clips = {a["path"]: a["clip"] for a in anim["animations"]}
    assert set(clips) == {f"/meshcat/{ROOT}/model/bodies/{b}" for b in lowerbody.bodies}
    shin = clips[f"/meshcat/{ROOT}/model/bodies/leftShin"]
    assert shin["fps"] == 24
    pos = {t["name"]: t for t in shin["tracks"]}[".position"]
    assert [k["time"] for k in pos["keys"]] == list(range(len(traj)))
    for name, clip in clips.items():  # every body, every frame: its centre and its rotation (x, y, z, w)
        body = name.rsplit("/", 1)[1]
        tracks = {t["name"]: t for t in clip["tracks"]}
        for i, x in enumerate(traj):
            pose = lowerbody.body_pose(x, body)
            np.testing.assert_allclose(tracks[".position"]["keys"][i]["value"], pose.translation, atol=1e-12)
            quat = np.array(tracks[".quaternion"]["keys"][i]["value"])
            np.testing.assert_allclose(pin.Quaternion(quat[3], *quat[:3]).toRotationMatrix(), pose.rotation,
                                       atol=1e-9)
    pelvis = {t["name"]: t for t in clips[f"/meshcat/{ROOT}/model/bodies/pelvis"]["tracks"]}[".position"]
    assert np.ptp([k["value"] for k in pelvis["keys"]], axis=0).max() < 1e-12  # the pelvis does not move


def test_animate_into_a_given_visualizer(lowerbody):
    from kms2pin.viewer import new_visualizer

    vis = new_visualizer(serve=False)
    assert animate(lowerbody, _trajectory(lowerbody, 3), 10, vis) is vis
    assert any(c["type"] == "set_animation" for c in vis.window.sent)


@pytest.mark.parametrize("bad", [np.zeros((0, 7)), np.zeros((3, 6)), np.full((2, 7), np.nan)])
def test_bad_trajectories(lowerbody, bad):
    with pytest.raises(ViewerError):
        animate(lowerbody, bad, 10)
    with pytest.raises(ViewerError, match="fps"):
        animate(lowerbody, np.zeros((2, 7)), 0)


def test_animation_html_of_a_trajectory_object_to_a_str_path(lowerbody, tmp_path):
    from kms2pin.ecm import Trajectory

    traj = _trajectory(lowerbody, 5)
    path = write_animation_html(lowerbody, Trajectory(lowerbody, traj), 10, str(tmp_path / "a.html"))
    assert path == tmp_path / "a.html"
    (anim,) = [c for c in page_commands(path.read_text()) if c["type"] == "set_animation"]
    shin = {a["path"]: a["clip"] for a in anim["animations"]}[f"/meshcat/{ROOT}/model/bodies/leftShin"]
    pos = {t["name"]: t for t in shin["tracks"]}[".position"]
    assert len(pos["keys"]) == len(traj)
    expected = lowerbody.body_poses(traj[-1])[lowerbody.index("leftShin")].translation
    np.testing.assert_allclose(pos["keys"][-1]["value"], expected)


def test_animation_draws_the_bodies_at_the_sizes_the_track_measured(lowerbody, tmp_path):
    """The bodies drawn at ``scales`` times the spec's semi-axes, by default the
    trajectory's own (the sizes a tracker measured), an explicit ``scales`` first."""
    from conftest import drawn_semi_axes

    from kms2pin.ecm import Trajectory

    traj = _trajectory(lowerbody, 4)
    rng = np.random.default_rng(3)
    measured, given = rng.uniform(0.7, 1.4, (2, len(lowerbody.bodies), 3))
    for name, kwargs, trajectory, expected in (
        ("spec", {}, traj, np.ones_like(measured)),
        ("array", {"scales": given}, traj, given),
        ("trajectory", {}, Trajectory(lowerbody, traj, scales=measured), measured),
        ("both", {"scales": given}, Trajectory(lowerbody, traj, scales=measured), given),
    ):
        html = write_animation_html(lowerbody, trajectory, 10, tmp_path / f"{name}.html", **kwargs).read_text()
        for kind, spec in (("inner", lowerbody.inner), ("outer", lowerbody.outer)):
            drawn = drawn_semi_axes(html, kind)
            assert set(drawn) == set(lowerbody.bodies)
            for i, body in enumerate(lowerbody.bodies):
                np.testing.assert_allclose(drawn[body], np.asarray(spec(body)) * expected[i], rtol=1e-12, err_msg=name)


@pytest.mark.parametrize("bad", [np.ones((2, 3)), np.zeros((9, 3)), np.full((9, 3), np.nan), [["a"] * 3] * 9])
def test_bad_body_scales_are_refused(lowerbody, bad):
    assert len(lowerbody.bodies) == 9
    with pytest.raises(ViewerError, match="scales must be"):
        animate(lowerbody, _trajectory(lowerbody, 2), 10, scales=bad)
