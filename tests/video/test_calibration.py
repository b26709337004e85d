"""Chessboard calibration on synthetic photographs, `camera make`, undistort_mask."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pinocchio as pin
import pytest

from kms2pin.cli import main
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.raycast import render_mask
from kms2pin.errors import CameraError
from kms2pin.video import calibrate_chessboard, make_camera, undistort_mask

from ._scene import chessboard_images, iou

K_TRUE = np.array([[800.0, 0.0, 322.0], [0.0, 790.0, 236.0], [0.0, 0.0, 1.0]])
DIST_TRUE = np.array([-0.08, 0.05, 0.0005, -0.0008, 0.0])
SIZE = (640, 480)


def _intrinsic_errors(K):
    idx = ([0, 1, 0, 1], [0, 1, 2, 2])
    return np.abs(K[idx] - K_TRUE[idx]) / K_TRUE[idx]


@pytest.mark.parametrize("dist", [None, DIST_TRUE], ids=["pinhole", "distorted"])
def test_calibration_recovers_intrinsics(dist):
    images = chessboard_images(np.random.default_rng(3), K_TRUE, dist, SIZE, count=15)
    res = calibrate_chessboard(images, (9, 6), 0.03, distortion="standard")
    err = _intrinsic_errors(res.camera.K)
    print(f"fx fy cx cy relative errors {np.round(err * 100, 3)} %, RMS {res.rms:.3f} px, {len(res.used)} views")
    assert len(res.used) == 15 and not res.rejected
    assert np.all(err < 0.01)
    assert res.rms < 0.3
    assert res.camera.dist is not None and len(res.camera.dist) == 5
    if dist is not None:
        assert abs(res.camera.dist[0] - dist[0]) < 0.02  # k1 recovered
    else:  # images without distortion: the fitted terms stay near zero
        assert np.abs(res.camera.dist[:4]).max() < 0.01
    assert res.camera.shape == (SIZE[1], SIZE[0])
    assert np.allclose(res.camera.world_T_camera.homogeneous, np.eye(4))


def test_calibrate_cli_lists_rejected_images(tmp_path, capsys):
    images = chessboard_images(np.random.default_rng(5), K_TRUE, DIST_TRUE, SIZE, count=6)
    folder = tmp_path / "shots"
    folder.mkdir()
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / f"view{i}.png"), img)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((SIZE[1], SIZE[0]), 200, np.uint8))
    out = tmp_path / "cam.json"
    assert main(["camera", "calibrate", str(folder), str(blank), "--board", "9x6", "--square", "0.03",
                 "-o", str(out), "--position", "0", "1", "-3", "--look-at", "0", "1", "0"]) == 0
    cap = capsys.readouterr()
    assert "blank.png: chessboard not found" in cap.err
    assert "from 6 of 7 images" in cap.out and "RMS reprojection error" in cap.out
    cam = Camera.from_json(out)
    assert np.all(_intrinsic_errors(cam.K) < 0.01)
    assert cam.dist is not None
    assert np.allclose(cam.centre, [0, 1, -3])
    assert np.allclose(cam.project(np.array([[0.0, 1.0, 5.0]])), cam.K[:2, 2], atol=1e-6)


def test_calibrate_needs_three_views(tmp_path, capsys):
    images = chessboard_images(np.random.default_rng(6), K_TRUE, None, SIZE, count=2)
    paths = []
    for i, img in enumerate([*images, np.full((SIZE[1], SIZE[0]), 255, np.uint8)]):
        paths.append(str(tmp_path / f"v{i}.png"))
        cv2.imwrite(paths[-1], img)
    assert main(["camera", "calibrate", *paths, "--square", "0.03", "-o", str(tmp_path / "c.json")]) == 1
    err = capsys.readouterr().err
    assert "found in 2 of 3 images" in err and "at least 3" in err
    assert not (tmp_path / "c.json").exists()
    assert main(["camera", "make", "--width", "48", "--height", "48", "--fov", "40", "-o", str(tmp_path)]) == 2
    assert f"-o {tmp_path}: a folder; give the camera file's name" in capsys.readouterr().err
    assert main(["camera", "calibrate", str(tmp_path), "--board", "abc", "--square", "0.03",
                 "-o", str(tmp_path / "c.json")]) == 2
    assert "--board: expected COLSxROWS inner corners such as 9x6, got 'abc'" in capsys.readouterr().err
    with pytest.raises(CameraError, match="cols != rows"):
        calibrate_chessboard(images, (6, 6), 0.03)


def test_calibrate_mixed_sizes_and_missing(tmp_path, capsys):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    cv2.imwrite(str(a), np.zeros((480, 640), np.uint8))
    cv2.imwrite(str(b), np.zeros((240, 320), np.uint8))
    assert main(["camera", "calibrate", str(a), str(b), "--square", "0.03", "-o", str(tmp_path / "c.json")]) == 1
    assert "b.png: 320x240 pixels" in capsys.readouterr().err
    assert main(["camera", "calibrate", str(tmp_path / "nope.png"), "--square", "0.03",
                 "-o", str(tmp_path / "c.json")]) == 2


def test_camera_make_default_is_thesis_camera(tmp_path):
    out = tmp_path / "cam.json"
    assert main(["camera", "make", "--width", "320", "--height", "240", "--fov", "40", "-o", str(out)]) == 0
    cam = Camera.from_json(out)
    ref = Camera.default(320, 240, 40.0)
    assert np.allclose(cam.K, ref.K) and np.allclose(cam.world_T_camera.homogeneous, ref.world_T_camera.homogeneous)
    assert np.allclose(cam.project(np.array([[0.0, 0.0, 7.0]])), [[159.5, 119.5]])


def test_camera_make_look_at(tmp_path):
    out = tmp_path / "cam.json"
    pos, target = [3.0, 2.0, -4.0], [0.0, 0.9, 8.0]
    assert main(["camera", "make", "--width", "641", "--height", "481", "--fov", "55", "--position", *map(str, pos),
                 "--look-at", *map(str, target), "--name", "side", "-o", str(out)]) == 0
    cam = Camera.from_json(out)
    assert cam.name == "side" and cam.shape == (481, 641)
    on_axis = np.array(pos) + 0.37 * (np.array(target) - pos)
    assert np.allclose(cam.project(np.vstack([target, on_axis])), [[320.0, 240.0]] * 2, atol=1e-9)
    # vertical field of view: a point at the top edge direction
    f = cam.K[1, 1]
    assert np.isclose(2 * np.degrees(np.arctan(240.5 / f)), 55.0)
    # world +y (up) appears upwards: smaller v
    above = cam.project(np.array(target)[None] + [0.0, 0.5, 0.0])
    assert above[0, 1] < 240.0
    assert json.loads(out.read_text())["name"] == "side"


def test_camera_make_errors(tmp_path, capsys):
    out = str(tmp_path / "c.json")
    with pytest.raises(SystemExit) as exc:  # a usage error, naming the option
        main(["camera", "make", "--width", "320", "--height", "240", "--fov", "190", "-o", out])
    assert exc.value.code == 2
    assert "argument --fov: expected a number in (0, 180)" in capsys.readouterr().err
    # flags that make no camera are usage errors too (exit 2), saying the flags
    assert main(["camera", "make", "--width", "320", "--height", "240", "--fov", "40",
                 "--position", "0", "0", "0", "--look-at", "0", "3", "0", "-o", out]) == 2
    assert "parallel" in capsys.readouterr().err
    assert main(["camera", "make", "--width", "48", "--height", "48", "--fov", "179.99999", "-o", out]) == 2
    err = capsys.readouterr().err
    assert "camera make --width 48 --height 48 --fov 179.99999: " in err and "focal lengths" in err
    with pytest.raises(SystemExit) as exc:
        main(["camera", "make", "--width", "48", "--height", "48", "--fov", "40", "--position", "nan", "0", "0",
              "-o", out])
    assert exc.value.code == 2
    assert "argument --position: expected a finite number, got 'nan'" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()
    with pytest.raises(CameraError):
        make_camera(0, 240, 40)


def test_undistort_mask_matches_pinhole_render():
    ideal = Camera.look_at([0.0, 0.0, -6.0], [0.0, 0.0, 0.0], width=320, height=240, fov_deg=50)
    distorted = Camera(ideal.K, ideal.world_T_camera, 320, 240, dist=[-0.25, 0.08, 0.001, -0.001, 0.0])
    bodies = [(pin.SE3(np.eye(3), np.array([x, 0.3 * x, 0.0])), [0.6, 0.9, 0.5]) for x in (-1.8, 0.0, 1.8)]
    m_dist = render_mask(distorted, bodies)
    m_ideal = render_mask(ideal, bodies)
    assert iou(m_dist, m_ideal) < 0.95  # the distortion matters at these positions
    und, cam = undistort_mask(m_dist, distorted)
    assert cam.dist is None and und.dtype == bool
    assert iou(und, m_ideal) > 0.97
    same, _ = undistort_mask(m_ideal, ideal)
    assert np.array_equal(same, m_ideal)
