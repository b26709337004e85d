"""Pictures through headless Chromium: the model is there, has the right shape,
the background is plain, static-update springs are red arrows."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from kms2pin.viewer import RobotView, draw_static_update, read_png
from kms2pin.viewer.render import inner_mask, mask_box, red_mask, render_png
from kms2pin.viewer.robot_view import new_visualizer
from kms2pin.viewer.scene import plain_background

from ._util import FakeResult, joint_q, load

pytestmark = pytest.mark.browser

W, H = 360, 480


def _static_update_case():
    robot = load("puma600")
    q0 = robot.q_rest.copy()
    q1 = q0.copy()
    q1[joint_q(robot, "link2_lowerLink")] += 0.6
    q1[joint_q(robot, "link3_lowerLink")] -= 0.8
    poses = robot.body_poses(q1)
    rng = np.random.default_rng(3)
    targets = {}
    for name in ("link2", "link3", "manipulator"):  # three sprung bodies
        M = poses[robot.index(name)].copy()
        M.translation = M.translation + rng.normal(0.0, 0.15, 3) + np.array([0.0, 0.0, -0.2])
        targets[name] = M
    result = FakeResult(q=0.35 * q0 + 0.65 * q1)
    return robot, q0, targets, result


@pytest.fixture(scope="module")
def pictures(tmp_path_factory):
    out = tmp_path_factory.mktemp("pictures")
    jobs, info = {}, {}
    for name in ("lowerbody", "fullbody"):
        robot = load(name)
        view = RobotView(robot, camera="front", aspect=W / H)
        jobs[name] = (view.static_html(), W, H)
        info[name] = robot
        bare = RobotView(robot, camera="front", aspect=W / H, world_axes=False, joint_axes=False)  # the bodies alone
        jobs[f"{name}/bare"] = (bare.static_html(), W, H)
        info[f"{name}/bare"] = bare.camera_setup
    empty = new_visualizer(serve=False)
    plain_background(empty)
    jobs["empty"] = (empty.static_html(), 200, 200)
    robot, q0, targets, result = _static_update_case()
    drawing = draw_static_update(robot, q0, targets, result, camera="front", aspect=2.0)
    jobs["static_update"] = (drawing.vis.static_html(), 800, 400)
    info["static_update"] = (drawing, targets)

    def shoot(item):
        key, (html, w, h) = item
        return key, read_png(render_png(html, out / f"{key}.png", w, h))

    with ThreadPoolExecutor(2) as pool:  # two Chromiums at a time: ~2x faster on 2+ cores
        images = dict(pool.map(shoot, jobs.items()))
    return images, info


@pytest.mark.parametrize("name", ["lowerbody", "fullbody"])
def test_model_is_drawn_with_the_projected_shape(pictures, name):
    images, info = pictures
    img, robot = images[name], info[name]
    assert img.shape == (H, W, 3)
    mask = inner_mask(img)
    assert mask.sum() > 0.04 * W * H, "the inner ellipsoids' orange should cover a good part of the picture"
    r0, r1, c0, c1 = mask_box(mask)
    height, width = r1 - r0 + 1, c1 - c0 + 1
    assert height > width * 1.5, "a human model is taller than wide from the front"
    # the bodies alone, where a pinhole camera at the page's camera (three.js: vertical field
    # of view) sees the inner ellipsoids' surface points: the drawn box within 3 pixels
    cam = info[f"{name}/bare"]
    f = (H / 2) / np.tan(np.radians(cam.fov_deg) / 2)
    rng = np.random.default_rng(0)
    px = []
    for P, b in zip(robot.body_poses(robot.q_rest), robot.bodies):
        u = rng.normal(size=(4000, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        w = (P.rotation @ (u * robot.inner(b)).T).T + P.translation - cam.position
        x, y, z = w @ cam.right, w @ cam.up, w @ cam.forward
        px.append(np.c_[H / 2 - f * y / z, W / 2 + f * x / z])
    px = np.concatenate(px)
    drawn = mask_box(inner_mask(images[f"{name}/bare"]))
    np.testing.assert_allclose(drawn, [px[:, 0].min(), px[:, 0].max(), px[:, 1].min(), px[:, 1].max()], atol=3.0)
    # framed: fills most of the height, roughly centred
    assert height > 0.7 * H
    assert abs((c0 + c1) / 2 - W / 2) < 0.12 * W
    assert abs((r0 + r1) / 2 - H / 2) < 0.12 * H


def test_background_is_plain_white(pictures):
    images, _ = pictures
    for key in ("lowerbody", "empty"):
        img = images[key]
        for corner in (img[0, 0], img[0, -1], img[-1, 0], img[-1, -1]):
            assert tuple(corner) == (255, 255, 255)


def test_empty_scene_has_no_model_colours(pictures):
    img = pictures[0]["empty"]
    assert inner_mask(img).sum() == 0
    assert red_mask(img).sum() == 0
    assert (img == 255).all(axis=2).mean() > 0.99


def test_static_update_has_one_red_arrow_per_spring(pictures):
    images, info = pictures
    drawing, targets = info["static_update"]
    for side in ("before", "after"):
        assert len(drawing.springs[side]) == len(targets) == 3
        assert sorted(p.rsplit("/", 1)[1] for p in drawing.springs[side]) == sorted(targets)
    # the arrow objects created in the scene: one shaft per spring and side
    shafts = [c["path"] for c in drawing.vis.window.sent
              if c["type"] == "set_object" and "/springs/" in c["path"] and c["path"].endswith("/shaft")]
    assert len(shafts) == 2 * len(targets)
    img = images["static_update"]
    red = red_mask(img)
    assert red.sum() > 150
    assert red[:, : img.shape[1] // 2].sum() > 50, "springs of the 'before' picture (left)"
    assert inner_mask(img).sum() > 0.03 * img.shape[0] * img.shape[1]
