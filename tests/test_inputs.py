"""What a user can name as an input file: each bad kind gets one line and its exit status.

A spec must be a regular file of at most 16 MiB (a FIFO or a device refused at once,
exit 2); a symbolic-link loop, an unreadable file or a folder is a usage error too;
numbers outside the accepted ranges (docs/language.md) are located spec errors
(exit 1); a camera file nested 100,000 deep, a camera at 1e308 or one of 20000x20000
pixels is one line (exit 1); an image over 8192 pixels a side is refused before it is
decoded; a 10 MB one-line spec gives a message of a few hundred bytes.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import SPECS

from kms2pin.cli import main
from kms2pin.errors import shorten_quoted
from kms2pin.userfile import MAX_SPEC_BYTES

CAMERA = {"width": 64, "height": 48, "K": [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]],
          "world_T_camera": {"rotation": [[-1, 0, 0], [0, -1, 0], [0, 0, 1]], "translation": [0, 0, 0]}}


def run(argv, capsys) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# ----------------------------------------------------------------------------- the spec file


def run_process(argv, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """``kms2pin ARGV`` in a child process that must end within ``timeout`` seconds (no hang)."""
    return subprocess.run([sys.executable, "-m", "kms2pin.cli", *map(str, argv)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_as_the_spec_is_refused_at_once(tmp_path):
    fifo = tmp_path / "model.kms"
    os.mkfifo(fifo)  # nobody ever writes: reading it would block forever
    r = run_process(["check", fifo])
    assert r.returncode == 2
    assert one_line(r.stderr) == f"kms2pin check: error: {fifo}: not a regular file (a FIFO)"


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_dev_zero_as_the_spec_is_refused_at_once():
    r = run_process(["export", "/dev/zero", "-o", "/nonexistent/never-written"])
    assert r.returncode == 2
    assert one_line(r.stderr) == "kms2pin export: error: /dev/zero: not a regular file (a character device)"


def test_a_symlink_loop_is_a_usage_error(tmp_path, capsys):
    a, b = tmp_path / "a.kms", tmp_path / "b.kms"
    a.symlink_to(b)
    b.symlink_to(a)
    code, err = run(["check", a], capsys)
    assert code == 2
    assert one_line(err) == f"kms2pin check: error: {a}: {os.strerror(errno.ELOOP)}"


def test_an_unreadable_spec_is_a_usage_error(tmp_path, capsys, monkeypatch):
    spec = tmp_path / "secret.kms"
    spec.write_text((SPECS / "puma600.kms").read_text())
    spec.chmod(0)
    if os.geteuid() == 0:  # root reads anything: make the open fail as it would for a user
        real_open = os.open

        def denied(path, *args, **kw):
            if os.fspath(path) == str(spec):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(path))
            return real_open(path, *args, **kw)

        monkeypatch.setattr(os, "open", denied)
    code, err = run(["check", spec], capsys)
    assert code == 2
    assert one_line(err) == f"kms2pin check: error: {spec}: {os.strerror(errno.EACCES)}"


def test_a_folder_as_the_spec_is_a_usage_error(tmp_path, capsys):
    code, err = run(["check", tmp_path], capsys)
    assert (code, one_line(err)) == (2, f"kms2pin check: error: {tmp_path}: is a directory")


def test_a_spec_over_the_size_limit_is_refused(tmp_path, capsys):
    spec = tmp_path / "huge.kms"
    with open(spec, "wb") as f:
        f.truncate(MAX_SPEC_BYTES + 1)  # sparse: no 16 MiB written
    code, err = run(["check", spec], capsys)
    assert code == 2
    assert one_line(err) == f"kms2pin check: error: {spec}: file too large (more than 16 MiB, the limit)"


def test_a_ten_megabyte_one_line_spec_gives_a_short_message_with_the_caret_in_place(tmp_path, capsys):
    spec = tmp_path / "garbage.kms"
    text = "/*" + "x" * 5_000_000 + "*/ @ " + "y" * 5_000_000  # 10 MB, the error mid-way
    spec.write_text(text)
    code, err = run(["check", spec], capsys)
    assert code == 1
    head, shown, caret = err.rstrip("\n").split("\n")
    column = text.index("@") + 1
    assert head == f"{spec}:1:{column}: error: syntax error: unexpected character '@'"
    assert len(err) < 400
    assert shown.startswith("    ...") and shown.endswith("...")
    assert shown[caret.index("^")] == "@"  # the caret under the culprit
    assert shown[7:-3] in text


def test_possessives_far_apart_are_no_quoted_name_to_cut():
    message = "the root's joint takes the name; " + "x " * 40 + "or keep the spec's root"
    assert shorten_quoted(message) == message
    name = "n" * 30 + "m" * 40 + "o" * 30
    assert shorten_quoted(f"body '{name}' of the root's") == f"body '{'n' * 30}...{'o' * 30}' of the root's"


def test_a_huge_name_is_cut_in_the_message(tmp_path, capsys):
    spec = tmp_path / "long.kms"
    name = "b" * 10 + "a" * 1_000_000 + "c" * 10 + "d" * 20
    spec.write_text(f"rigidBodySystem s {{ ellipsoidBody {name} {{ }} }}")
    code, err = run(["check", spec], capsys)
    assert code == 1
    assert len(err) < 3000
    # cut in its middle: its first 30 characters and its last 30
    assert f"body '{'b' * 10}{'a' * 20}...{'c' * 10}{'d' * 20}' has no innerLam(x, y, z)" in err


@pytest.mark.parametrize("command", ["check", "export"])
@pytest.mark.parametrize("statement, message", [
    ("innerLam(1e-300, 0.2, 0.2);", "innerLam semi-axes must be at least 1e-06, got (1e-300, 0.2, 0.2)"),
    ("innerLam(2e6, 0.2, 0.2);", "innerLam semi-axes must be at most 1e+06, got (2e+06, 0.2, 0.2)"),
])
def test_absurd_sizes_are_refused_by_check_and_export(tmp_path, capsys, command, statement, message):
    text = (SPECS / "puma600.kms").read_text()
    first = text.index("innerLam(")
    end = text.index(";", first) + 1
    spec = tmp_path / "absurd.kms"
    spec.write_text(text[:first] + statement + text[end:])
    line = text.count("\n", 0, first) + 1
    column = first - text.rfind("\n", 0, first)
    code, err = run([command, spec, "-o", tmp_path / "out"] if command == "export" else [command, spec], capsys)
    assert code == 1
    assert err.splitlines()[0] == f"{spec}:{line}:{column}: error: {message}"
    assert not (tmp_path / "out").exists()


def test_a_bound_vector_at_1e308_is_refused_with_its_place(tmp_path, capsys):
    text = (SPECS / "puma600.kms").read_text()
    first = text.index("pos(")
    end = text.index(";", first) + 1
    spec = tmp_path / "far.kms"
    spec.write_text(text[:first] + "pos(0, 0, 1e308);" + text[end:])
    code, err = run(["check", spec], capsys)
    assert code == 1
    head = err.splitlines()[0]
    assert head.startswith(f"{spec}:{text.count(chr(10), 0, first) + 1}:{first - text.rfind(chr(10), 0, first)}: ")
    assert head.endswith("must be within +-1e+06, got (0, 0, 1e+308)")


# ----------------------------------------------------------------------------- cameras and images


def write_camera(path, **changes) -> str:
    cam = json.loads(json.dumps(CAMERA))
    for key, value in changes.items():
        if key == "translation":
            cam["world_T_camera"]["translation"] = value
        else:
            cam[key] = value
    path.write_text(json.dumps(cam))
    return str(path)


def test_a_camera_nested_100k_deep_is_one_line(tmp_path, capsys):
    cam = tmp_path / "deep.json"
    cam.write_text("[" * 100_000 + "]" * 100_000)
    code, err = run(["synth", SPECS / "lowerbody.kms", "--cameras", cam, "--frames", "1", "-o", tmp_path / "o"],
                    capsys)
    assert (code, one_line(err)) == (1, f"{cam}: not valid JSON: nested too deeply")


def test_synth_with_a_20000_pixel_camera_is_refused_before_any_allocation(tmp_path, capsys):
    cam = write_camera(tmp_path / "big.json", width=20000, height=20000)
    code, err = run(["synth", SPECS / "lowerbody.kms", "--cameras", cam, "--frames", "1", "-o", tmp_path / "o"],
                    capsys)
    assert code == 1
    assert one_line(err) == (f"{cam}: field 'width' is 20000 pixels; images of at most 8192 pixels a side are "
                             "supported")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("change, message", [
    (dict(translation=[0, 0, 1e308]), "field 'world_T_camera.translation' must be within +-1e+06 (world units)"),
    (dict(K=[[1e300, 0, 31.5], [0, 60, 23.5], [0, 0, 1]]), "focal lengths fx, fy must be in [0.001, 1e+06] pixels"),
    (dict(K=[[60, 0, 1e9], [0, 60, 23.5], [0, 0, 1]]), "must be within +-1e+06 pixels for the principal point"),
    (dict(dist=[1e300, 0, 0, 0]), "field 'dist' must be within +-1e+06"),
    (dict(height=8193), "field 'height' is 8193 pixels; images of at most 8192 pixels a side are supported"),
])
def test_absurd_camera_values_are_refused_when_the_file_is_read(tmp_path, capsys, change, message):
    cam = write_camera(tmp_path / "cam.json", **change)
    code, err = run(["synth", SPECS / "lowerbody.kms", "--cameras", cam, "--frames", "1", "-o", tmp_path / "o"],
                    capsys)
    assert code == 1
    line = one_line(err)
    assert line.startswith(f"{cam}: ") and message in line


def test_camera_make_refuses_a_width_over_8192_as_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["camera", "make", "--width", "20000", "--height", "100", "--fov", "40", "-o", str(tmp_path / "c.json")])
    assert exit_.value.code == 2
    assert "--width: expected a whole number in [1, 8192], got '20000'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["synth", str(SPECS / "lowerbody.kms"), "--frames", "99999999999999999999", "-o", "o"],
     "--frames: expected a whole number in [1, 1e+06], got '99999999999999999999'"),
    (["segment", "frames", "--history", "3000000000", "-o", "o"],
     "--history: expected a whole number in [1, 2.14748e+09], got '3000000000'"),
    (["view", str(SPECS / "lowerbody.kms"), "--port", "-1"], "--port: expected a whole number in [0, 65535], got '-1'"),
    (["view", str(SPECS / "lowerbody.kms"), "--port", "99999"], "--port: expected a whole number in [0, 65535]"),
])
def test_counts_past_what_the_tools_can_take_are_usage_errors(tmp_path, capsys, monkeypatch, argv, message):
    """A frame count that would be allocated, OpenCV's int, a TCP port: refused by the parser
    (exit 2) before anything runs, nothing written."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_frames_of_one_pixel_are_refused_naming_the_image(tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"f{k}.png"), np.zeros((1, 1, 3), np.uint8))
    code, err = run(["segment", frames, "-o", tmp_path / "o", "--no-progress"], capsys)
    assert code == 1
    assert one_line(err) == f"{frames / 'f0.png'}: frame 0 is 1x1 pixels; at least 2x2 are needed"
    assert not (tmp_path / "o").exists()


def test_an_image_over_8192_pixels_a_side_is_refused_from_its_header(tmp_path, capsys, monkeypatch):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"f{k}.png"), np.zeros((2, 9000, 3), np.uint8))
    decoded = []
    real = cv2.imdecode
    monkeypatch.setattr(cv2, "imdecode", lambda *a: decoded.append(1) or real(*a))
    code, err = run(["segment", frames, "-o", tmp_path / "m", "--no-progress"], capsys)
    assert code == 1
    assert one_line(err) == (f"{frames / 'f0.png'}: the image is 9000x2 pixels; at most 8192 pixels a side are "
                             "supported (scale it down first)")
    assert decoded == []  # refused from the PNG header, not after decoding


def test_a_large_jpeg_is_refused_from_its_header_too(tmp_path):
    from kms2pin.errors import InputDataError
    from kms2pin.video.io import read_image

    path = tmp_path / "wide.jpg"
    cv2.imwrite(str(path), np.zeros((8, 8200, 3), np.uint8))
    with pytest.raises(InputDataError, match=r"wide.jpg: the image is 8200x8 pixels; at most 8192"):
        read_image(path)


# ----------------------------------------------------------------------------- trajectories and poses


@pytest.fixture(scope="module")
def truth_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth")
    assert main(["synth", str(SPECS / "lowerbody.kms"), "--frames", "2", "-o", str(d)]) == 0
    return d / "truth.csv"


@pytest.mark.parametrize("cells, message", [
    (dict(root_qx="0", root_qy="0", root_qz="0", root_qw="0"),
     "the root quaternion (root_qx, root_qy, root_qz, root_qw) is zero"),
    (dict(root_x="1e308"), "root position (root_x, root_y, root_z) must be within +-1e+06, got [1e+308, "),
])
def test_a_trajectory_with_an_unusable_root_is_refused_with_its_line(truth_csv, tmp_path, cells, message):
    from conftest import set_csv_cell

    from kms2pin.ecm import Trajectory
    from kms2pin.errors import InputDataError
    from kms2pin.robot import load

    path = tmp_path / "t.csv"
    path.write_text(truth_csv.read_text())
    for column, value in cells.items():
        set_csv_cell(path, 3, column, value)
    with pytest.raises(InputDataError) as err:
        Trajectory.from_csv(load(SPECS / "lowerbody.kms", root="free"), path)
    assert str(err.value).startswith(f"{path}:3: {message}")


def test_a_trajectory_quaternion_of_any_size_is_normalized(truth_csv, tmp_path):
    from conftest import set_csv_cell

    from kms2pin.ecm import Trajectory
    from kms2pin.robot import load

    robot = load(SPECS / "lowerbody.kms", root="free")
    path = tmp_path / "t.csv"
    path.write_text(truth_csv.read_text())
    for column, value in dict(root_qx="0", root_qy="3e300", root_qz="0", root_qw="4e300").items():
        set_csv_cell(path, 2, column, value)
    q = Trajectory.from_csv(robot, path).q[0]
    np.testing.assert_allclose(q[3:7], [0, 0.6, 0, 0.8])


@pytest.mark.parametrize("root, message", [
    ({"rotation": [[1.3e154, 0, 0], [0, 1, 0], [0, 0, 1]]}, "root rotation is not a rotation matrix"),
    ({"rotation": [None, [0, 1, 0], [0, 0, 1]]}, "root rotation must be a 3x3 matrix"),
    ({"position": [0, 0, 1e308]}, "root position must be within +-1e+06"),
    ({"quaternion_xyzw": [0, 0, 0, 2**70]}, None),
    ({"quaternion_xyzw": [0, 0, 0, 10**400]}, "quaternion_xyzw must be [x, y, z, w]"),
])
def test_pose_files_with_absurd_roots(tmp_path, root, message):
    from kms2pin.errors import InputDataError
    from kms2pin.robot import load
    from kms2pin.video.init import read_pose_json

    robot = load(SPECS / "lowerbody.kms", root="free")
    path = tmp_path / "pose.json"
    path.write_text(json.dumps({"root": root}).replace("Infinity", "1e400"))
    if message is None:
        np.testing.assert_allclose(read_pose_json(robot, path)[3:7], [0, 0, 0, 1])
        return
    with pytest.raises(InputDataError) as err:
        read_pose_json(robot, path)
    assert str(err.value).startswith(f"{path}: {message}")


def test_a_fifo_among_the_masks_is_refused_at_once(tmp_path):
    masks = tmp_path / "masks"
    masks.mkdir()
    (masks / "cameras.json").write_text(json.dumps([CAMERA]))
    cv2.imwrite(str(masks / "frame_00000.png"), np.zeros((48, 64), np.uint8))
    os.mkfifo(masks / "frame_00001.png")  # reading its header would block forever
    r = run_process(["track", SPECS / "lowerbody.kms", "--masks", masks, "-o", tmp_path / "out", "--no-progress"])
    assert r.returncode == 1
    assert r.stderr.strip().splitlines()[-1] == f"{masks / 'frame_00001.png'}: not a regular file"


def test_a_closed_pipe_on_stdout_ends_quietly(monkeypatch):
    class ClosedPipe:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")  # `kms2pin check x | head` once head has exited

        def flush(self):
            pass

    import io

    err = io.StringIO()
    err.close = lambda: None  # the handler closes stderr (no "Exception ignored" at exit); keep it readable
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["check", str(SPECS / "fullbody.kms")]) == 0
    assert err.getvalue() == ""  # not "error: Broken pipe" (it is an OSError, caught before those)
