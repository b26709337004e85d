"""Camera projection, constructors and JSON validation."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pinocchio as pin
import pytest
from conftest import PNG

from kms2pin.ecm.camera import Camera
from kms2pin.errors import CameraError

from ._util import DIST, random_camera, random_rotation


def _random_points_in_front(rng: np.random.Generator, cam: Camera, n: int) -> np.ndarray:
    local = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(1, 10, n)])
    T = cam.world_T_camera
    return local @ T.rotation.T + T.translation


@pytest.mark.parametrize("with_dist", [False, True])
@pytest.mark.parametrize("seed", range(10))
def test_project_matches_cv2_project_points_for_random_points_and_poses(seed, with_dist):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, kind=2, dist=DIST if with_dist else None)
    pts = _random_points_in_front(rng, cam, 200)
    cTw = cam.camera_T_world
    rvec, _ = cv2.Rodrigues(cTw.rotation)
    dist = DIST if with_dist else np.zeros(5)
    expected, _ = cv2.projectPoints(pts, rvec, cTw.translation, cam.K, dist)
    np.testing.assert_allclose(cam.project(pts), expected.reshape(-1, 2), atol=1e-7)


def test_projection_matrix_agrees_with_project_on_an_undistorted_camera():
    rng = np.random.default_rng(1)
    cam = random_camera(rng, kind=2)
    pts = _random_points_in_front(rng, cam, 50)
    x = np.column_stack([pts, np.ones(len(pts))]) @ cam.P.T
    np.testing.assert_allclose(x[:, :2] / x[:, 2:], cam.project(pts), atol=1e-9)
    np.testing.assert_allclose(x[:, 2], cam.depth(pts), atol=1e-9)


def test_points_behind_the_camera_project_to_nan():
    cam = Camera.default()
    px = cam.project(np.array([[0.0, 0.0, -3.0], [0.1, 0.2, 0.0], [0.0, 0.0, 3.0]]))
    assert np.isnan(px[:2]).all() and np.isfinite(px[2]).all()


def test_points_project_the_same_with_or_without_points_behind_the_camera():
    """A point's pixel does not depend on the other points: all in front (project's
    short path) or among points behind the camera, to the last bit."""
    rng = np.random.default_rng(8)
    for kind in (1, 2):
        cam = random_camera(rng, kind)
        pts = _random_points_in_front(rng, cam, 50)
        behind = cam.centre - 2.0 * (pts - cam.centre)
        mixed = cam.project(np.concatenate([pts, behind]))
        assert np.isnan(mixed[50:]).all()
        np.testing.assert_array_equal(cam.project(pts), mixed[:50])


@pytest.mark.parametrize("with_dist", [False, True])
def test_rays_back_project_pixels_onto_their_own_projection(with_dist):
    rng = np.random.default_rng(7)
    cam = random_camera(rng, kind=1, dist=DIST if with_dist else None)
    pixels = rng.uniform([0, 0], [cam.width, cam.height], size=(100, 2))
    dirs, centre = cam.rays(pixels)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(centre, cam.world_T_camera.translation)
    for s in (0.5, 4.0):
        np.testing.assert_allclose(cam.project(centre + s * dirs), pixels, atol=1e-6)


@pytest.mark.parametrize("factor", [2, 3])
def test_a_binned_cameras_pixel_centres_are_the_centres_of_the_blocks(factor):
    # undistorted: the image plane is linear, so the ray through a binned pixel's
    # centre is the mean of the rays through its block's pixel centres
    cam = random_camera(np.random.default_rng(3), kind=2)
    b = cam.binned(factor)
    assert (b.width, b.height) == (cam.width // factor, cam.height // factor)
    full = cam.ray_grid[: b.height * factor, : b.width * factor]
    blocks = full.reshape(b.height, factor, b.width, factor, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(b.ray_grid, blocks, atol=1e-12)
    np.testing.assert_allclose(b.centre, cam.centre)


@pytest.mark.parametrize("with_dist", [False, True])
def test_a_binned_camera_projects_a_point_to_its_block_coordinates(with_dist):
    # full-resolution pixel x lies at (x - (f - 1) / 2) / f in the binned image
    rng = np.random.default_rng(8)
    cam = random_camera(rng, kind=2, dist=DIST if with_dist else None)
    pts = _random_points_in_front(rng, cam, 100)
    np.testing.assert_allclose(cam.binned(2).project(pts), (cam.project(pts) - 0.5) / 2.0, atol=1e-9)
    assert cam.binned(1) is cam


def test_a_camera_at_the_least_focal_length_bins_without_an_error():
    """A camera file may give fx = fy = MIN_FOCAL; its binned copy (the tracker's coarse
    views) has half that, and is made from the checked camera, not refused without the
    file's name; it still projects to the blocks' coordinates, its caches its own."""
    from kms2pin.ecm.camera import MIN_FOCAL

    cam = Camera([[MIN_FOCAL, 0, 40.0], [0, MIN_FOCAL, 30.0], [0, 0, 1]], pin.SE3.Identity(), 80, 60, name="tiny")
    cam.P  # noqa: B018  (cached on the camera: the binned one must not take it)
    b = cam.binned(4)
    assert b.K[0, 0] == MIN_FOCAL / 4 and b.shape == (15, 20) and b.name == "tiny"
    pts = np.array([[0.5, -0.2, 2.0], [3.0, 1.0, 1e-3]])
    np.testing.assert_allclose(b.project(pts), (cam.project(pts) - 1.5) / 4.0, atol=1e-9)
    np.testing.assert_allclose(b.P, b.K @ np.eye(3, 4))
    assert not b.K.flags.writeable


def test_binning_an_image_smaller_than_the_factor_is_a_camera_error():
    cam = Camera(np.diag([10.0, 10.0, 1.0]), pin.SE3.Identity(), 3, 1)
    with pytest.raises(CameraError, match="cannot bin a 3x1 image by 2"):
        cam.binned(2)


def test_default_camera_sees_a_point_on_its_axis_at_the_image_centre():
    cam = Camera.default()
    np.testing.assert_allclose(cam.project(np.array([[0.0, 0.0, 8.0]])), [[159.5, 119.5]])
    assert cam.depth(np.array([[0.0, 0.0, 8.0]]))[0] == pytest.approx(8.0)


def test_default_camera_shows_world_up_upwards_and_has_a_40_degree_vertical_field_of_view():
    cam = Camera.default()
    up, left = cam.project(np.array([[0.0, 1.0, 8.0], [1.0, 0.0, 8.0]]))
    assert up[1] < 119.5 and up[0] == pytest.approx(159.5)
    assert left[0] < 159.5  # right-handed world, looking along +z with +y up: +x is on the left
    edge = cam.project(np.array([[0.0, 8 * math.tan(math.radians(20)), 8.0]]))[0]
    assert edge[1] == pytest.approx(-0.5)  # the top edge of the top pixel row
    np.testing.assert_allclose(cam.world_T_camera.rotation, np.diag([-1.0, -1.0, 1.0]))
    assert cam.K[0, 0] == cam.K[1, 1]


def test_look_at_puts_the_target_at_the_image_centre_with_up_upwards():
    cam = Camera.look_at([3.0, 2.0, -4.0], [0.5, 0.0, 1.0], up=(0, 1, 0), width=321, height=241)
    c, above = cam.project(np.array([[0.5, 0.0, 1.0], [0.5, 0.5, 1.0]]))
    np.testing.assert_allclose(c, [160.0, 120.0], atol=1e-9)
    assert above[1] < c[1]


def test_look_at_rejects_an_up_vector_along_the_viewing_direction():
    with pytest.raises(CameraError, match="parallel"):
        Camera.look_at([0, 0, 0], [0, 5, 0], up=(0, 1, 0))


def test_json_round_trip_preserves_every_field(tmp_path):
    rng = np.random.default_rng(3)
    cam = random_camera(rng, kind=2, dist=DIST)
    cam = Camera(cam.K, cam.world_T_camera, 640, 480, dist=cam.dist, name="left")
    path = tmp_path / "cam.json"
    cam.to_json(path)
    back = Camera.from_json(path)
    assert back.to_dict() == cam.to_dict()
    assert back.name == "left" and back.shape == (480, 640)
    np.testing.assert_array_equal(back.dist, DIST)
    np.testing.assert_array_equal(back.P, cam.P)


def test_a_list_of_cameras_round_trips_and_a_single_object_reads_as_a_list(tmp_path):
    cams = [Camera.default(), Camera.look_at([1, 2, 3], [0, 0, 0], name="b")]
    Camera.list_to_json(cams, tmp_path / "cams.json")
    back = Camera.list_from_json(tmp_path / "cams.json")
    assert [c.to_dict() for c in back] == [c.to_dict() for c in cams]
    cams[1].to_json(tmp_path / "one.json")
    assert [c.name for c in Camera.list_from_json(tmp_path / "one.json")] == ["b"]


def _valid() -> dict:
    return Camera.default().to_dict()


def _set(path: str, value):
    def edit(d: dict) -> dict:
        keys = path.split(".")
        target = d
        for k in keys[:-1]:
            target = target[k]
        target[keys[-1]] = value
        return d

    return edit


def _drop(path: str):
    def edit(d: dict) -> dict:
        keys = path.split(".")
        target = d
        for k in keys[:-1]:
            target = target[k]
        del target[keys[-1]]
        return d

    return edit


_SCALED = (np.eye(3) * 1.01).tolist()
_REFLECTION = np.diag([1.0, 1.0, -1.0]).tolist()
_NEAR = (np.diag([-1.0, -1.0, 1.0]) + 1e-5 * np.ones((3, 3))).tolist()

INVALID = {
    "missing K": (_drop("K"), "K", "missing field"),
    "missing width": (_drop("width"), "width", "missing field"),
    "missing rotation": (
        _drop("world_T_camera.rotation"),
        "world_T_camera.rotation",
        "missing field",
    ),
    "K not 3x3": (_set("K", [[1, 0, 0], [0, 1, 0]]), "K", "3x3 matrix of numbers"),
    "K with a string": (
        _set("K", [[1, 0, "a"], [0, 1, 0], [0, 0, 1]]),
        "K",
        "3x3 matrix of numbers",
    ),
    "K with a bool": (
        _set("K", [[True, 0, 0], [0, 1, 0], [0, 0, 1]]),
        "K",
        "3x3 matrix of numbers",
    ),
    "K bad last row": (_set("K", [[300, 0, 160], [0, 300, 120], [0, 0, 2]]), "K", "positive focal"),
    "K with skew": (_set("K", [[300, 2, 160], [0, 300, 120], [0, 0, 1]]), "K", "no skew"),
    "K negative focal": (
        _set("K", [[-300, 0, 160], [0, 300, 120], [0, 0, 1]]),
        "K",
        "positive focal",
    ),
    "zero width": (_set("width", 0), "width", "positive integer"),
    "negative height": (_set("height", -5), "height", "positive integer"),
    "fractional height": (_set("height", 2.5), "height", "positive integer"),
    "pose not an object": (_set("world_T_camera", [1, 2]), "world_T_camera", "must be an object"),
    "scaled rotation": (
        _set("world_T_camera.rotation", _SCALED),
        "world_T_camera.rotation",
        "not a rotation",
    ),
    "reflection": (
        _set("world_T_camera.rotation", _REFLECTION),
        "world_T_camera.rotation",
        "det = -1",
    ),
    "rotation off by 1e-5": (
        _set("world_T_camera.rotation", _NEAR),
        "world_T_camera.rotation",
        "not a rotation",
    ),
    "translation of 2": (
        _set("world_T_camera.translation", [1, 2]),
        "world_T_camera.translation",
        "3 numbers",
    ),
    "dist of 3": (_set("dist", [0.1, 0.2, 0.3]), "dist", "4, 5, 8, 12 or 14"),
    "name not a string": (_set("name", 3), "name", "string"),
    "misspelt field": (_set("dsit", [0, 0, 0, 0]), "dsit", "did you mean 'dist'"),
}


@pytest.mark.parametrize("case", sorted(INVALID))
def test_each_invalid_camera_file_gives_a_camera_error_naming_the_file_and_field(tmp_path, case):
    edit, field, reason = INVALID[case]
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(edit(_valid())))
    with pytest.raises(CameraError) as err:
        Camera.from_json(path)
    msg = str(err.value)
    assert msg.startswith(str(path)), msg
    assert f"'{field}'" in msg and reason in msg, msg


def test_nan_in_a_matrix_is_rejected_as_not_finite(tmp_path):
    path = tmp_path / "cam.json"
    d = _valid()
    d["K"][0][2] = float("nan")
    path.write_text(json.dumps(d))
    with pytest.raises(CameraError, match=r"cam\.json \(camera 'default'\): field 'K' must contain finite numbers"):
        Camera.from_json(path)


def test_a_rotation_within_the_tolerance_is_accepted(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(_set("world_T_camera.rotation", (np.diag([-1.0, -1, 1]) + 1e-8).tolist())(_valid())))
    assert Camera.from_json(path).width == 320


def test_a_file_that_is_not_json_reports_the_line_and_column(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text('{\n  "width": 320,\n  "height" 240\n}\n')
    with pytest.raises(CameraError) as err:
        Camera.from_json(path)
    assert str(err.value).startswith(f"{path}:3:12: not valid JSON"), str(err.value)


def test_a_missing_file_is_a_camera_error_naming_it(tmp_path):
    with pytest.raises(CameraError, match="nothere.json: cannot read"):
        Camera.from_json(tmp_path / "nothere.json")


def test_reading_one_camera_from_a_list_file_says_the_file_holds_a_list(tmp_path):
    """The message serves command-line users too: no Python names in it."""
    path = tmp_path / "cams.json"
    path.write_text(json.dumps([_valid(), _valid()]))
    with pytest.raises(CameraError) as err:
        Camera.from_json(path)
    assert str(err.value) == f"{path}: holds a list of 2 cameras, not a single camera"


@pytest.mark.parametrize("read", [Camera.from_json, Camera.list_from_json])
def test_a_binary_file_is_a_camera_error_saying_it_is_not_text(tmp_path, read):
    path = tmp_path / "frame.png"
    path.write_bytes(PNG)
    with pytest.raises(CameraError) as err:
        read(path)
    assert str(err.value) == f"{path}: not a text (JSON) file"


def test_an_error_in_a_camera_list_names_the_cameras_index(tmp_path):
    bad = _set("height", 0)(_valid())
    bad["name"] = "right"
    path = tmp_path / "cams.json"
    path.write_text(json.dumps([_valid(), bad]))
    with pytest.raises(CameraError, match=r"cams\.json\[1\] \(camera 'right'\): field 'height'"):
        Camera.list_from_json(path)


def test_the_constructor_rejects_a_non_rotation_pose():
    with pytest.raises(CameraError, match="not a rotation"):
        Camera(np.eye(3), pin.SE3(np.eye(3) * 2, np.zeros(3)), 10, 10)
    Camera(np.eye(3), pin.SE3(random_rotation(np.random.default_rng(0)), np.zeros(3)), 10, 10)


def test_camera_arrays_are_read_only():
    cam = Camera.default()
    with pytest.raises(ValueError):
        cam.K[0, 0] = 1.0
