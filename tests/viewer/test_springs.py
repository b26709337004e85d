"""Static-update drawings without a browser: targets, arrows, layouts."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin import static_update
from kms2pin.errors import RobotError, TargetError
from kms2pin.viewer import draw_static_update, show_static_update, target_poses
from kms2pin.viewer.scene import ROOT

from ._util import FakeResult, page_commands


def test_targets_from_maximal_coordinates(puma):
    q = puma.random_configuration(np.random.default_rng(1), 60)
    X = puma.maximal_coordinates(q)
    X[:, 3:] *= 3.0  # not normalised: the drawing normalises
    poses = target_poses(puma, X)
    assert list(poses) == list(puma.bodies)
    for name, M in zip(puma.bodies, puma.body_poses(q)):
        np.testing.assert_allclose(poses[name].homogeneous, M.homogeneous, atol=1e-12)


def test_bad_targets(puma):
    with pytest.raises(TargetError, match="shape"):
        target_poses(puma, np.zeros((2, 7)))
    X = puma.maximal_coordinates(puma.q_rest)
    X[1, 0] = np.nan
    with pytest.raises(TargetError, match="link1"):
        target_poses(puma, X)
    with pytest.raises(RobotError, match="did you mean 'link2'"):
        target_poses(puma, {"link22": pin.SE3.Identity()})


def test_one_arrow_per_sprung_body_and_a_dot_for_a_zero_spring(puma):
    poses = puma.body_poses(puma.q_rest)
    targets = {"link1": poses[1].copy(), "link3": poses[3].copy()}
    targets["link3"].translation = targets["link3"].translation + 0.3  # link1's spring has zero length
    vis = show_static_update(puma, puma.q_rest, targets, FakeResult(q=puma.q_rest.copy()))
    sent = vis.window.sent
    for side in ("before", "after"):
        base = f"/meshcat/{ROOT}/static_update/{side}/springs"
        objs = {c["path"] for c in sent if c["type"] == "set_object" and c["path"].startswith(base)}
        assert objs == {f"{base}/link1/dot", f"{base}/link3/shaft", f"{base}/link3/head"}
        inter = {c["path"] for c in sent if c["type"] == "set_object" and f"{side}/intermediate" in c["path"]}
        assert len(inter) == 2


def test_side_by_side_puts_before_left_of_after(puma):
    X = puma.maximal_coordinates(puma.q_rest)
    d = draw_static_update(puma, puma.q_rest, X, FakeResult(q=puma.q_rest.copy()), camera="front")
    right = d.camera.right
    assert (d.offsets["after"] - d.offsets["before"]) @ right > 0
    assert len(d.springs["before"]) == len(d.springs["after"]) == len(puma.bodies)


def test_animation_layout_toggles_before_and_after(puma):
    X = puma.maximal_coordinates(puma.q_rest)
    d = draw_static_update(puma, puma.q_rest, X, puma.q_rest, layout="animation")  # bare q as the result
    np.testing.assert_allclose(d.offsets["before"], d.offsets["after"])
    (anim,) = [c for c in page_commands(d.vis.static_html()) if c["type"] == "set_animation"]
    tracks = {a["path"]: a["clip"]["tracks"] for a in anim["animations"]}
    before = tracks[f"/meshcat/{ROOT}/static_update/before/primary"][0]
    after = tracks[f"/meshcat/{ROOT}/static_update/after/primary"][0]
    assert before["name"] == ".visible" and before["type"] == "bool"
    assert [k["value"] for k in before["keys"]][:2] == [True, False]
    assert [k["value"] for k in after["keys"]][:2] == [False, True]
    with pytest.raises(TargetError, match="layout"):
        draw_static_update(puma, puma.q_rest, X, puma.q_rest, layout="grid")


def test_dict_targets_as_rows(puma):
    X = puma.maximal_coordinates(puma.q_rest)
    poses = target_poses(puma, {"link1": X[1], "link2": puma.body_poses(puma.q_rest)[2].homogeneous})
    np.testing.assert_allclose(poses["link1"].homogeneous, puma.body_poses(puma.q_rest)[1].homogeneous, atol=1e-12)
    with pytest.raises(TargetError, match="link1"):
        target_poses(puma, {"link1": np.zeros(5)})


def test_with_the_real_static_update(puma):
    q1 = puma.q_rest.copy()
    q1[2] += 0.4
    X = puma.maximal_coordinates(q1)
    X[:, :3] += 0.05
    result = static_update(puma, puma.q_rest, X, 1.0)
    d = draw_static_update(puma, puma.q_rest, X, result, camera="side")
    assert len(d.springs["before"]) == len(d.springs["after"]) == len(puma.bodies)
    np.testing.assert_allclose(d.primaries["after"].q, result.q)
    # each arrow runs from its body's centre (before: the start, after: the result) to the
    # target's centre X[:, :3], both moved by the side's offset: its node's placement, and
    # the shaft's and the head's lengths along the node's y axis
    sent = d.vis.window.sent
    placed = {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in sent if c["type"] == "set_transform"}
    height = {c["path"]: c["object"]["geometries"][0]["height"] for c in sent if c["type"] == "set_object"
              and c["path"].endswith(("/shaft", "/head"))}
    for side, q in (("before", puma.q_rest), ("after", result.q)):
        for k, body in enumerate(puma.bodies):
            start = puma.body_pose(q, body).translation + d.offsets[side]
            end = X[k, :3] + d.offsets[side]
            path = f"/meshcat/{ROOT}/static_update/{side}/springs/{body}"
            M = placed[path]
            np.testing.assert_allclose(M[:3, 3], start, atol=1e-12)
            length = height[f"{path}/shaft"] + height[f"{path}/head"]
            np.testing.assert_allclose(M[:3, :3] @ [0.0, length, 0.0] + start, end, atol=1e-9)
