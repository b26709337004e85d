"""synth -> track -> evaluate end to end, and bad input to the ECM commands."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import PNG, set_csv_cell, video_frames

from kms2pin.cli import main
from kms2pin.ecm.bothways import MARGIN, SWEEPS, SWITCH, TOLERANCE, parts
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.sizes import SCALE_MAX, SCALE_MIN
from kms2pin.robot import load
from kms2pin.video.synthetic import walking_video

SPECS = Path(__file__).resolve().parents[1] / "specs"
LOWER = str(SPECS / "lowerbody.kms")


@pytest.fixture(scope="module")
def cams2(tmp_path_factory) -> str:
    robot = load(LOWER, root="free")
    path = tmp_path_factory.mktemp("cams") / "cams.json"
    Camera.list_to_json([Camera.default(), Camera.look_at(position=[8, 0, 8], target=robot.q_rest[:3])], path)
    return str(path)


def _synth(tmp_path, cams=None, frames=4, noise=0.0, extra=()):
    """Synthetic masks in ``tmp_path/masks``: two cameras from ``cams``, else synth's one."""
    d = tmp_path / "masks"
    cameras = ["--cameras", cams] if cams else []
    assert main(["synth", LOWER, "--frames", str(frames), *cameras, "--noise", str(noise),
                 "--seed", "1", "-o", str(d), *extra]) == 0
    return d


@pytest.mark.slow
def test_synth_track_evaluate(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=20, noise=0.02)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "-o", str(out)]) == 0
    for name in ("trajectory.csv", "poses.npz", "overlay.mp4", "model.kms", "meta.json"):
        assert (out / name).is_file(), name
    with np.load(out / "poses.npz") as z:  # body sizes measured on frame 0: synth used the model's
        assert z["body_scales"].shape == (z["body_poses"].shape[1], 3)
        assert np.median(np.abs(z["body_scales"] - 1.0)) < 0.03
    capsys.readouterr()
    assert main(["evaluate", str(out), str(masks / "truth.csv"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["frames"] == 20
    assert rep["mean_centre_error_pct"] < 2.0
    assert rep["revolute_rmse_deg"] < 5.0


def test_one_camera_options_reach_the_tracker(tmp_path, capsys):
    """One camera: the mirror and swap hypotheses and the limb search are on by default;
    --no-mirror-hypothesis, --no-swap-hypothesis, --no-limb-search and --no-size-calibration turn them
    off (meta.json records what ran), and the body sizes then stay the spec's;
    --binned-hypotheses tracks the hypotheses on binned masks; --size-every sets how often
    the sizes are refined (default 5, 0: never), and a bad count is a usage error;
    --limb-search-drop sets the search's fall in fit (default 0.015 with --masks), and
    --no-limb-hypothesis turns off the limb-search hypothesis (on with the limb search);
    --tol-px sets the outlines' test of convergence (0: the joints' test alone); --ground and
    --ground-height set the ground contact prior.  Without
    the priors a one-camera run points at the upright prior (the model has joint limits)."""
    d = tmp_path / "m"
    anatomical = str(SPECS / "anatomical" / "lowerbody.kms")  # joint limits: both hypotheses
    assert main(["synth", anatomical, "--frames", "3", "--size-mismatch", "0.1", "-o", str(d)]) == 0
    runs = {
        "default": [],
        "off": ["--no-mirror-hypothesis", "--no-swap-hypothesis", "--no-limb-search", "--no-size-calibration",
                "--depth-prior", "0.02", "--tol-px", "0.5",
                "--upright", "0.1", "--up", "0", "0", "2", "--rest-prior", "0.01", "--ground", "0.5",
                "--ground-height", "-1.5"],
        "binned": ["--binned-hypotheses", "--size-every", "0", "--limb-search-drop", "0.03", "--no-limb-hypothesis",
                   "--tol-px", "0"],
    }
    for name, flags in runs.items():
        out = tmp_path / name
        capsys.readouterr()
        assert main(["track", anatomical, "--masks", str(d), "--no-progress", "--no-video", *flags, "-o", str(out)]) == 0
        err = capsys.readouterr().err
        # the model has joint limits: the note names the upright prior alone
        assert ("--upright 0.1 holds" in err) == (name != "off") and "--rest-prior" not in err
        options = json.loads((out / "meta.json").read_text())["options"]
        meta = {name: value for group in options.values() for name, value in group.items()}
        meta["size_calibration"] = meta["calibrate_sizes"]
        with np.load(out / "poses.npz") as z:
            scales = z["body_scales"]
        assert meta["binned_hypotheses"] == (name == "binned")
        assert meta["size_every"] == (0 if name == "binned" else 5)
        assert meta["limb_search_drop"] == (0.03 if name == "binned" else 0.015)
        assert meta["limb_hypothesis"] == (name == "default")
        assert meta["tol_px"] == {"default": 0.25, "off": 0.5, "binned": None}[name]
        if name == "binned":
            assert meta["mirror_hypothesis"] and meta["swap_hypothesis"]
        elif name == "default":
            assert meta["mirror_hypothesis"] and meta["swap_hypothesis"] and meta["size_calibration"]
            assert meta["limb_search"] and meta["limb_search_drop"] == 0.015
            assert meta["depth_prior"] == 0.0 and meta["upright"] == 0.0 and meta["up"] == [0.0, 1.0, 0.0]
            assert meta["rest_prior"] == 0.0 and meta["ground"] == 0.0 and meta["ground_height"] is None
            assert np.abs(scales - 1.0).max() > 0.01  # measured: synth's sizes differ by 10 %
        else:
            assert not (meta["mirror_hypothesis"] or meta["swap_hypothesis"] or meta["size_calibration"])
            assert not meta["limb_search"]
            assert meta["depth_prior"] == 0.02 and meta["upright"] == 0.1 and meta["up"] == [0.0, 0.0, 1.0]
            assert meta["rest_prior"] == 0.01 and meta["ground"] == 0.5 and meta["ground_height"] == -1.5
            np.testing.assert_array_equal(scales, 1.0)
    for bad in ("-1", "2.5"):
        with pytest.raises(SystemExit) as exc:
            main(["track", anatomical, "--masks", str(d), "--size-every", bad, "-o", str(tmp_path / "bad")])
        assert exc.value.code == 2
    assert not (tmp_path / "bad").exists()


def test_one_camera_note_names_both_priors_for_a_model_without_limits(tmp_path, capsys):
    """The thesis's lower body has no joint limits: a one-camera run without priors is
    pointed at both (with the upright prior alone the benchmark lost seeds)."""
    d = tmp_path / "m"
    spec = str(SPECS / "lowerbody.kms")
    assert main(["synth", spec, "--frames", "2", "-o", str(d)]) == 0
    capsys.readouterr()
    assert main(["track", spec, "--masks", str(d), "--no-progress", "--no-video", "-o", str(tmp_path / "o")]) == 0
    assert "--upright 0.1 --rest-prior 0.01 hold" in capsys.readouterr().err


def test_evaluate_splits_off_the_depth_error_with_one_camera(tmp_path, cams2, capsys):
    """With one camera, evaluate also splits the centre error into its parts along and
    across the camera's viewing rays; with two it does not."""
    for name, cams in (("one", []), ("two", ["--cameras", cams2])):
        masks = tmp_path / f"m{name}"
        assert main(["synth", LOWER, "--frames", "3", "--noise", "0.02", "--seed", "1", *cams, "-o", str(masks)]) == 0
        out = tmp_path / name
        assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
        capsys.readouterr()
        assert main(["evaluate", str(out), str(masks / "truth.csv"), "--json"]) == 0
        rep = json.loads(capsys.readouterr().out)
        if name == "two":
            assert "depth_error_pct" not in rep
            continue
        total, depth, across = (rep[k] for k in ("mean_centre_error_pct", "depth_error_pct",
                                                 "centre_error_across_rays_pct"))
        assert 0.0 < depth <= total and 0.0 < across <= total <= depth + across  # orthogonal parts
        assert main(["evaluate", str(out), str(masks / "truth.csv")]) == 0
        assert "one camera: along its viewing rays (depth)" in capsys.readouterr().out


def test_synth_layout_one_camera(tmp_path):
    d = tmp_path / "m"
    assert main(["synth", LOWER, "--frames", "2", "--noise", "0.05", "--size-mismatch", "0.1", "-o", str(d)]) == 0
    assert sorted(p.name for p in (d / "cam0").iterdir()) == ["frame_00000.png", "frame_00001.png"]
    assert len(Camera.list_from_json(d / "cameras.json")) == 1
    img = cv2.imread(str(d / "cam0" / "frame_00000.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (240, 320) and set(np.unique(img)) <= {0, 255}


def test_track_wrong_size_names_file_and_frame(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=3)
    bad = masks / "cam1" / "frame_00001.png"
    cv2.imwrite(str(bad), np.zeros((100, 120), np.uint8))
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "frame_00001.png" in err and "frame 1" in err and "120x100" in err
    # every mask's size is checked (from its PNG header) before anything is written
    assert not (tmp_path / "o").exists()


def test_track_missing_frame_and_unreadable(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=4)
    (masks / "cam0" / "frame_00002.png").unlink()
    (masks / "cam1" / "frame_00002.png").unlink()
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "-o", str(tmp_path / "o")]) == 1
    assert "missing frame(s) 2" in capsys.readouterr().err
    (masks / "cam0" / "frame_00002.png").write_bytes(b"not a png")
    cv2.imwrite(str(masks / "cam1" / "frame_00002.png"), np.zeros((240, 320), np.uint8))
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "frame_00002.png: frame 2: not a readable image" in err


def test_track_non_binary_and_empty(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=3)
    for k in (0, 1):
        p = masks / "cam0" / f"frame_{k:05d}.png"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(p), (img // 255 * 200).astype(np.uint8) + 10)
    for c in (0, 1):
        cv2.imwrite(str(masks / f"cam{c}" / "frame_00002.png"), np.zeros((240, 320), np.uint8))
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "frame_00001.png: frame 1: not a binary mask; thresholded at 127" in err
    # frame 0 is read twice (the first frame that shows the subject, then tracked): one note
    assert err.count("frame_00000.png: frame 0: not a binary mask; thresholded at 127") == 1
    assert "frame 2: empty mask" in err
    last = (out / "trajectory.csv").read_text().splitlines()[-1]
    assert last.endswith("empty mask")


def test_evaluate_bad_folder(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    assert main(["evaluate", str(tmp_path / "x"), str(tmp_path / "t.csv")]) == 1
    assert "not a kms2pin track output" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "nope"), str(tmp_path / "t.csv")]) == 2


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """A 6-frame one-camera synth and its track: (track output folder, truth.csv)."""
    d = tmp_path_factory.mktemp("evaluate")
    masks = _synth(d, frames=6)
    out = d / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
    return out, masks / "truth.csv"


def _copy_track(out, dest, rows=None):
    """A copy of the track output ``out`` keeping the header and the first ``rows`` frames."""
    dest.mkdir()
    for f in out.iterdir():
        if f.is_file():
            (dest / f.name).write_bytes(f.read_bytes())
    if rows is not None:
        lines = (out / "trajectory.csv").read_text().splitlines(keepends=True)
        (dest / "trajectory.csv").write_text("".join(lines[: rows + 1]))
    return dest


def test_evaluate_warns_of_a_frame_count_mismatch_and_evaluates_the_common_frames(tracked, tmp_path, capsys):
    out, truth = tracked
    lines = truth.read_text().splitlines(keepends=True)
    short = tmp_path / "truth4.csv"
    short.write_text("".join(lines[:5]))  # header and 4 frames
    capsys.readouterr()
    assert main(["evaluate", str(out), str(short), "--json"]) == 0
    cap = capsys.readouterr()
    assert f"warning: {out} has 6 frames, {short} 4: evaluating the first 4" in cap.err
    assert json.loads(cap.out)["frames"] == 4
    out4 = _copy_track(out, tmp_path / "out4", rows=4)
    assert main(["evaluate", str(out4), str(truth)]) == 0
    cap = capsys.readouterr()
    assert f"warning: {out4} has 4 frames, {truth} 6: evaluating the first 4" in cap.err
    assert cap.out.startswith("4 frames;")
    assert main(["evaluate", str(out), str(truth)]) == 0
    assert "warning" not in capsys.readouterr().err


def test_evaluate_rejects_a_truth_with_a_non_finite_cell_naming_its_line_and_column(tracked, tmp_path, capsys):
    out, truth = tracked
    bad = tmp_path / "t_nan.csv"
    bad.write_text(truth.read_text())
    set_csv_cell(bad, 3, "leftShin_knee", "nan")
    capsys.readouterr()
    assert main(["evaluate", str(out), str(bad)]) == 1
    cap = capsys.readouterr()
    assert cap.err == f"{bad}:3: column 'leftShin_knee': 'nan' is not a finite number\n"
    assert cap.out == ""


def test_evaluate_reports_binary_files_without_a_traceback(tracked, tmp_path, capsys):
    out, truth = tracked
    png = tmp_path / "frame_00000.png"
    png.write_bytes(PNG)
    capsys.readouterr()
    assert main(["evaluate", str(out), str(png)]) == 1
    assert capsys.readouterr().err == f"{png}: not a text (CSV) file\n"
    for name, kind in (("trajectory.csv", "CSV"), ("meta.json", "JSON"), ("cameras.json", "JSON")):
        bad = _copy_track(out, tmp_path / name.replace(".", "_"))
        (bad / name).write_bytes(PNG)
        assert main(["evaluate", str(bad), str(truth)]) == 1
        assert capsys.readouterr().err == f"{bad / name}: not a text ({kind}) file\n"


def test_evaluate_names_a_header_only_file_and_a_directory_given_as_truth(tracked, tmp_path, capsys):
    out, truth = tracked
    header = tmp_path / "header.csv"
    header.write_text(truth.read_text().splitlines(keepends=True)[0])
    capsys.readouterr()
    assert main(["evaluate", str(out), str(header)]) == 1
    assert capsys.readouterr().err == f"{header}: no frames to evaluate (only a header)\n"
    assert main(["evaluate", str(out), str(tmp_path)]) == 2
    assert f"{tmp_path}: is a directory, not a trajectory CSV file" in capsys.readouterr().err
    assert main(["evaluate", str(truth), str(truth)]) == 2
    assert f"{truth}: not a folder" in capsys.readouterr().err


def test_synth_reports_a_binary_camera_file_without_a_traceback(tmp_path, capsys):
    cams = tmp_path / "cams.json"
    cams.write_bytes(PNG)
    assert main(["synth", LOWER, "--frames", "2", "--cameras", str(cams), "-o", str(tmp_path / "m")]) == 1
    assert capsys.readouterr().err == f"{cams}: not a text (JSON) file\n"


def test_track_reports_frames_it_cannot_fit(tmp_path, cams2, capsys):
    """Masks that no pose of the model explains (a thin diagonal line): the frames are
    flagged 'poor fit' in the CSV and the command says where the track is probably lost."""
    masks = _synth(tmp_path, cams2, frames=2)
    for f in sorted(masks.glob("cam*/frame_*.png")):
        cv2.imwrite(str(f), np.eye(240, 320, dtype=np.uint8) * 255)
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "fit the masks poorly" in err and "first at frame 0" in err
    rows = (out / "trajectory.csv").read_text().splitlines()
    assert all("poor fit" in row for row in rows[1:])


@pytest.mark.parametrize("value", ["-0.1", "nan", "strong"])
def test_a_bad_depth_prior_is_a_usage_error_before_anything_is_written(tmp_path, capsys, value):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["track", str(SPECS / "lowerbody.kms"), "--masks", str(tmp_path), "--depth-prior", value, "-o", str(out)])
    assert exc.value.code == 2
    assert "--depth-prior" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    "flags", [["--upright", "-1"], ["--up", "0", "0", "0"], ["--up", "0", "nan", "1"], ["--rest-prior", "-0.01"],
              ["--limb-search-drop", "-0.01"], ["--tol-px", "-0.1"], ["--ground", "-1"], ["--ground-height", "nan"]]
)
def test_a_bad_upright_prior_is_a_usage_error_before_anything_is_written(tmp_path, capsys, flags):
    out = tmp_path / "out"
    argv = ["track", str(SPECS / "lowerbody.kms"), "--masks", str(tmp_path), *flags, "-o", str(out)]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own type check
        code = exc.code
    assert code == 2
    assert flags[0] in capsys.readouterr().err
    assert not out.exists()


def test_upright_with_a_fixed_root_says_it_does_nothing(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=2, extra=("--root", "spec"))
    out = tmp_path / "out"
    argv = ["track", LOWER, "--masks", str(masks), "--root", "spec", "--no-progress", "--no-video", "--upright", "0.1"]
    assert main([*argv, "-o", str(out)]) == 0
    assert "with --root spec they do nothing" in capsys.readouterr().err
    assert json.loads((out / "meta.json").read_text())["root"] == "spec"


def test_a_damaged_mask_is_refused_before_anything_is_written(tmp_path, capsys):
    """A mask that is a PNG by its header but cut short (its size is right): every mask is
    decoded before the track starts, so the error names it and its frame, no output folder
    is made, and OpenCV's own warning does not reach stderr."""
    masks = _synth(tmp_path, frames=6)
    bad = masks / "cam0" / "frame_00004.png"
    bad.write_bytes(bad.read_bytes()[:40])
    out = tmp_path / "o"
    capsys.readouterr()
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == f"{bad}: frame 4: not a readable image (empty, truncated or unknown format)"
    assert "WARN" not in err
    assert not out.exists()


def test_a_mask_that_fails_mid_track_stops_it_with_its_outputs_complete_up_to_there(tmp_path, capsys, monkeypatch):
    """A mask that cannot be read once the track runs (replaced on a shared disk, say) stops
    the run at its frame: trajectory.csv and poses.npz hold the frames before it, meta.json
    says the track is not complete, and evaluate warns of both."""
    from kms2pin.commands import track as track_command
    from kms2pin.errors import InputDataError

    masks = _synth(tmp_path, frames=6)
    read = track_command.read_mask

    def flaky(path, frame, *a, **k):
        if frame == 4:
            raise InputDataError(f"{path}: frame {frame}: not a readable image (empty, truncated or unknown format)")
        return read(path, frame, *a, **k)

    monkeypatch.setattr(track_command, "read_mask", flaky)
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "frame_00004.png: frame 4: not a readable image (empty, truncated or unknown format)" in err
    assert f"stopped at frame 4; outputs in {out} are up to frame 3" in err
    assert len((out / "trajectory.csv").read_text().splitlines()) == 1 + 4
    with np.load(out / "poses.npz") as z:
        assert z["body_poses"].shape[0] == 4
    assert json.loads((out / "meta.json").read_text())["complete"] is False
    assert main(["evaluate", str(out), str(masks / "truth.csv")]) == 0
    err = capsys.readouterr().err
    assert "the track stopped before its last frame" in err and "has 4 frames" in err and "truth.csv 6" in err


def test_a_finished_track_is_complete_and_a_rerun_replaces_the_earlier_outputs(tmp_path, capsys):
    """A run that tracks every frame says so in meta.json; a second run into the same
    folder removes the first one's outputs that it does not write itself (here
    overlay.mp4, with --no-video), and says so."""
    masks = _synth(tmp_path, frames=3)
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "-o", str(out)]) == 0
    assert (out / "overlay.mp4").is_file()
    assert json.loads((out / "meta.json").read_text())["complete"] is True
    capsys.readouterr()
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
    # trajectory.csv, poses.npz, overlay.mp4, animation.html and motion.bvh
    assert f"note: {out}: removed 5 file(s) of an earlier run" in capsys.readouterr().err
    assert not (out / "overlay.mp4").exists()
    assert len((out / "trajectory.csv").read_text().splitlines()) == 1 + 3


def test_every_mask_empty_is_an_error_before_anything_is_written(tmp_path, capsys):
    masks = _synth(tmp_path, frames=3)
    for p in (masks / "cam0").iterdir():
        cv2.imwrite(str(p), np.zeros((240, 320), np.uint8))
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "-o", str(out)]) == 1
    assert "every mask is empty: nothing to track" in capsys.readouterr().err
    assert not out.exists()


def test_an_empty_first_frame_keeps_the_initial_pose(tmp_path, capsys):
    masks = _synth(tmp_path, frames=3)
    cv2.imwrite(str(masks / "cam0" / "frame_00000.png"), np.zeros((240, 320), np.uint8))
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(tmp_path / "o")]) == 0
    assert "frame 0: empty mask" in (err := capsys.readouterr().err) and "the initial pose kept" in err


def test_a_camera_file_may_hold_a_list(tmp_path, cams2, capsys):
    """--camera takes synth's own cameras.json (a list) as well as one-camera files."""
    masks = _synth(tmp_path, cams2, frames=2)
    out = tmp_path / "o"
    argv = ["track", LOWER, "--masks", str(masks), "--camera", str(masks / "cameras.json"), "--no-progress",
            "--no-video", "-o", str(out)]
    assert main(argv) == 0
    assert json.loads((out / "meta.json").read_text())["cameras"] == 2


def test_synth_into_a_used_folder_removes_the_longer_runs_frames(tmp_path, capsys):
    d = tmp_path / "m"
    assert main(["synth", LOWER, "--frames", "5", "-o", str(d)]) == 0
    assert main(["synth", LOWER, "--frames", "2", "--motion", "sweep", "-o", str(d)]) == 0
    assert "removed 3 older mask(s)" in capsys.readouterr().out
    assert sorted(p.name for p in (d / "cam0").iterdir()) == ["frame_00000.png", "frame_00001.png"]


@pytest.mark.parametrize(
    "argv, option",
    [
        (["synth", LOWER, "--seed", "-1"], "--seed"),
        (["synth", LOWER, "--frames", "0"], "--frames"),
        (["synth", LOWER, "--noise", "2"], "--noise"),
        (["synth", LOWER, "--size-mismatch", "1"], "--size-mismatch"),
        (["track", LOWER, "--masks", "m", "--fps", "0"], "--fps"),
        (["track", LOWER, "--masks", "m", "--fps", "-5"], "--fps"),
        (["segment", "v.avi", "--learn-frames", "-1"], "--learn-frames"),
        (["segment", "v.avi", "--history", "0"], "--history"),
        (["segment", "v.avi", "--shadow-threshold", "1"], "--shadow-threshold"),
        (["camera", "make", "--width", "0", "--height", "240", "--fov", "50"], "--width"),
        (["camera", "make", "--width", "320", "--height", "240", "--fov", "180"], "--fov"),
    ],
)
def test_out_of_range_options_are_usage_errors_naming_the_option(tmp_path, capsys, argv, option):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main([*argv, "-o", str(out)])
    assert exc.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err
    assert not out.exists()


def test_options_that_do_nothing_say_so(tmp_path, capsys):
    masks = _synth(tmp_path, frames=2)
    argv = ["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(tmp_path / "o")]
    assert main([*argv, "--shadow-threshold", "0.3", "--no-size-calibration", "--size-every", "3"]) == 0
    err = capsys.readouterr().err
    assert "with --masks they do nothing" in err and "with --no-size-calibration none are measured" in err


def test_shadow_threshold_with_no_shadows_says_it_does_nothing_with_video(tmp_path, capsys):
    """`track --video` shares segment's lighting options and its note: --shadow-threshold
    with --no-shadows does nothing (a tiny 4-frame video, found by the automatic
    initialization)."""
    cam = Camera.default()
    video = tmp_path / "frames"
    video.mkdir()
    for i, f in enumerate(walking_video(load(LOWER, root="free"), cam, frames=4, seed=2).frames):
        cv2.imwrite(str(video / f"f{i:02d}.png"), f)
    cam.to_json(tmp_path / "cam.json")
    argv = ["track", LOWER, "--video", str(video), "--camera", str(tmp_path / "cam.json"), "--no-shadows",
            "--shadow-threshold", "0.3", "--no-progress", "--no-video", "-o", str(tmp_path / "o")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert err.count("note: --shadow-threshold sets the shadow test; with --no-shadows it does nothing\n") == 1
    assert "with --masks they do nothing" not in err


def test_a_missing_camera_file_is_a_usage_error_like_a_missing_spec(tmp_path, capsys):
    masks = _synth(tmp_path, frames=2)
    nothere = str(tmp_path / "nothere.json")
    assert main(["track", LOWER, "--masks", str(masks), "--camera", nothere, "-o", str(tmp_path / "o")]) == 2
    assert f"{nothere}: no such file" in capsys.readouterr().err
    assert main(["synth", LOWER, "--cameras", nothere, "-o", str(tmp_path / "s")]) == 2
    assert f"{nothere}: no such file" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "s").exists()


def test_an_option_given_twice_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["track", LOWER, "--masks", "a", "--masks", "b", "-o", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "argument --masks: given twice ('a' and 'b')" in capsys.readouterr().err


def test_preset_people_one_camera_is_changed_by_the_other_flags(tmp_path, capsys):
    """--preset starts from a preset; a flag given beside it changes that option only; the
    one-camera note is not printed once a preset is chosen."""
    d = tmp_path / "m"
    spec = str(SPECS / "lowerbody.kms")
    assert main(["synth", spec, "--frames", "2", "-o", str(d)]) == 0
    capsys.readouterr()
    out = tmp_path / "o"
    assert main(["track", spec, "--masks", str(d), "--no-progress", "--no-video", "--preset", "people-one-camera",
                 "--upright", "0.2", "-o", str(out)]) == 0
    assert "note: one camera" not in capsys.readouterr().err
    groups = json.loads((out / "meta.json").read_text())["options"]
    meta = {name: value for group in groups.values() for name, value in group.items()}
    assert meta["prediction"] == "learnt" and meta["reach_search"] is True  # the preset
    assert meta["rest_prior"] == 0.01 and meta["upright"] == 0.2  # the preset, and the flag over it


@pytest.mark.parametrize("name", ["people", "people-tracks", "people-one-camera", "segmented-masks"])
def test_the_flags_the_help_gives_for_a_preset_make_its_options(name):
    """`track --help` spells each preset as flags; those flags, split as a shell would, give the
    preset's options."""
    import argparse
    import shlex

    from kms2pin.commands._tracking import PRESETS, add_tracker_arguments, preset_flags, tracker_options

    p = argparse.ArgumentParser()
    add_tracker_arguments(p)
    assert name in p.format_help()
    by_flags = tracker_options(p.parse_args(shlex.split(preset_flags(PRESETS[name]))))
    by_preset = tracker_options(p.parse_args(["--preset", name]))
    assert by_flags == by_preset != tracker_options(p.parse_args([]))


def test_smooth_writes_the_low_passed_track_and_evaluate_scores_it(tmp_path, cams2, capsys):
    """``--smooth HZ``: smoothed.csv beside trajectory.csv (the same frames, numbered alike),
    the cutoff in meta.json, motion.bvh of the smoothed motion; ``evaluate --smoothed``
    scores it.  The synthetic walk is smooth: with noisy masks the low-pass is closer to
    the truth than the per-frame track (checked on real motion capture in
    benchmarks/realmotion.py)."""
    masks = _synth(tmp_path, cams2, frames=24, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--smooth", "6",
                 "-o", str(out)]) == 0
    raw, smoothed = ((out / f).read_text().splitlines() for f in ("trajectory.csv", "smoothed.csv"))
    assert len(smoothed) == len(raw) == 1 + 24
    assert [r.split(",")[0] for r in smoothed] == [r.split(",")[0] for r in raw]
    assert json.loads((out / "meta.json").read_text())["smooth_hz"] == 6.0
    from kms2pin.bvh import to_bvh
    from kms2pin.ecm import Trajectory

    def numbers(text: str) -> np.ndarray:  # the MOTION section's channels
        return np.array(text.split("Frame Time:")[1].split()[1:], dtype=float)

    robot = load(LOWER, root="free")
    written = numbers((out / "motion.bvh").read_text())
    for name, same in (("smoothed.csv", True), ("trajectory.csv", False)):  # motion.bvh is of the smoothed track
        motion = numbers(to_bvh(robot, Trajectory.from_csv(robot, out / name).q, 30.0))
        assert np.allclose(written, motion, atol=1e-6) == same
    capsys.readouterr()
    reports = []
    for extra in ([], ["--smoothed"]):
        assert main(["evaluate", str(out), str(masks / "truth.csv"), "--json", *extra]) == 0
        reports.append(json.loads(capsys.readouterr().out))
    assert reports[0] != reports[1]
    assert reports[1]["revolute_rmse_deg"] < reports[0]["revolute_rmse_deg"]


def test_a_cutoff_at_or_above_half_the_frame_rate_is_a_usage_error_before_anything_is_written(tmp_path, capsys):
    masks = _synth(tmp_path, frames=2)
    out = tmp_path / "out"
    code = main(["track", LOWER, "--masks", str(masks), "--smooth", "15", "-o", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "--smooth 15" in err and "below 15 Hz" in err
    assert not out.exists()


def test_evaluate_smoothed_without_a_smoothed_track_says_how_to_make_one(tracked, capsys):
    out, truth = tracked
    assert main(["evaluate", str(out), str(truth), "--smoothed"]) == 1
    assert "no smoothed.csv (written by kms2pin track --smooth HZ)" in capsys.readouterr().err


def _smoothed_and_scored(robot, out, masks, kept, flag: str, capsys) -> None:
    """smoothed.csv is ``kept`` (the track ``flag`` wrote) smoothed at 6 Hz, and
    ``evaluate flag`` scores that track's 10 frames."""
    from kms2pin.ecm import Trajectory

    smoothed = Trajectory.from_csv(robot, out / "smoothed.csv").q
    assert np.allclose(smoothed, Trajectory(robot, kept).smoothed(30.0, 6.0).q, atol=1e-6)
    assert main(["evaluate", str(out), str(masks / "truth.csv"), flag, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 10


def test_both_ways_writes_the_kept_poses_and_smooth_uses_them(tmp_path, cams2, capsys):
    """``--both-ways``: both_ways.csv (every frame, numbered as trajectory.csv, each row the
    forward or the backward track's pose, the latter flagged, a limb's part taken from the
    other track or from the frames beside flagged with its name, every row's fit its own pose's), which ``--smooth`` then
    smooths; ``evaluate --both-ways`` scores it."""
    masks = _synth(tmp_path, cams2, frames=10, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--both-ways",
                 "--smooth", "6", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "--both-ways: the backward track's pose kept on" in err and "a limb's part taken from the other track on" in err
    took = re.search(r"taken from the other track on (\d+) and from the frames beside on (\d+)", err)
    assert took
    meta = json.loads((out / "meta.json").read_text())
    assert meta["both_ways"] is True and meta["both_ways_switch"] == SWITCH and meta["both_ways_margin"] == MARGIN
    assert meta["both_ways_tolerance"] == TOLERANCE and meta["both_ways_parts"] == list(parts(load(LOWER, root="free")))
    assert meta["both_ways_sweeps"] == SWEEPS
    from kms2pin.ecm import Trajectory

    robot = load(LOWER, root="free")
    raw, kept = (Trajectory.from_csv(robot, out / f).q for f in ("trajectory.csv", "both_ways.csv"))
    rows = (out / "both_ways.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == [str(k) for k in range(10)]
    # the note counts the rows flagged
    assert int(took[1]) == sum("' taken from the forward track" in r or "' taken from the backward track" in r for r in rows)
    assert int(took[2]) == sum("' taken from the frames beside it" in r for r in rows)
    for row, a, b in zip(rows, raw, kept):  # a frame not flagged is the forward track's pose
        assert ("kept from the backward track" in row) or ("' taken from the backward track" in row) \
            or ("' taken from the frames beside it" in row) or np.allclose(a, b, atol=1e-8)
    _smoothed_and_scored(robot, out, masks, kept, "--both-ways", capsys)


def test_beside_writes_the_track_with_parts_from_the_frames_beside_and_smooth_uses_it(tmp_path, cams2, capsys):
    """``--beside``: beside.csv (every frame, numbered as trajectory.csv, a part taken from the
    frames beside flagged with its name, every other row the forward track's pose), no
    backward pass; ``--smooth`` then smooths it; ``evaluate --beside`` scores it."""
    masks = _synth(tmp_path, cams2, frames=10, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--beside",
                 "--smooth", "6", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    took = re.search(r"--beside: a limb's part taken from the frames beside on (\d+) of 10 frames", err)
    assert took and "backward" not in err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["beside"] is True and meta["beside_sweeps"] == SWEEPS and "both_ways" not in meta
    assert meta["beside_parts"] == list(parts(load(LOWER, root="free")))
    assert not (out / "both_ways.csv").exists()
    from kms2pin.ecm import Trajectory

    robot = load(LOWER, root="free")
    raw, kept = (Trajectory.from_csv(robot, out / f).q for f in ("trajectory.csv", "beside.csv"))
    rows = (out / "beside.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == [str(k) for k in range(10)]
    assert int(took[1]) == sum("' taken from the frames beside it" in r for r in rows)
    for row, a, b in zip(rows, raw, kept):  # a frame not flagged is the forward track's pose
        assert ("' taken from the frames beside it" in row) or np.allclose(a, b, atol=1e-8)
    _smoothed_and_scored(robot, out, masks, kept, "--beside", capsys)


def test_stretches_writes_each_stretch_from_the_track_that_fits_it_and_smooth_uses_it(tmp_path, cams2, capsys):
    """``--stretches`` with a track beside (a first track held near its starting pose by a
    stiff rest prior, a second without it, which the masks follow): stretches.csv (every
    frame, numbered as trajectory.csv), each row one track's pose (the second's flagged) or
    with parts taken from a track or the frames beside (flagged with their names); the note
    counts them; ``--smooth`` then smooths it; ``evaluate --stretches`` scores it."""
    masks = _synth(tmp_path, cams2, frames=10, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--stretches",
                 "--rest-prior", "10", "--second-track", "rest_prior=0", "--smooth", "6", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    note = re.search(r"--stretches: the poses of 10 frames: (\d+) from the first track, (\d+) from the second track "
                     r"\((\d+) changes of track\); a limb's part taken from another track on (\d+) frames "
                     r"and from the frames beside on (\d+)", err)
    assert note, err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["stretches"] is True and meta["stretches_tracks"] == 2 and meta["stretches_switch"] == SWITCH
    assert meta["stretches_tolerance"] == TOLERANCE and meta["stretches_sweeps"] == SWEEPS and "beside" not in meta
    from kms2pin.ecm import Trajectory

    robot = load(LOWER, root="free")
    kept = Trajectory.from_csv(robot, out / "stretches.csv").q
    rows = (out / "stretches.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == [str(k) for k in range(10)]
    assert int(note[1]) + int(note[2]) == 10 and int(note[2]) >= 5  # the track that follows the masks, mostly
    assert int(note[2]) == sum("from the second track" in r.split("' taken")[0] for r in rows)
    assert int(note[4]) == sum("' taken from the first track" in r or "' taken from the second track" in r for r in rows)
    assert int(note[5]) == sum("' taken from the frames beside it" in r for r in rows)
    _smoothed_and_scored(robot, out, masks, kept, "--stretches", capsys)


def test_temporal_refits_the_finished_track_and_smooth_and_evaluate_use_it(tmp_path, cams2, capsys):
    """``--temporal`` after ``--beside``: temporal.csv (every frame, numbered as
    trajectory.csv, no flag of where a pose came from), the weight and sweeps in meta.json
    and the note; ``--smooth`` then smooths it, motion.bvh shows that, ``evaluate
    --temporal`` scores it, and the refit is nearer the truth than the track it refit."""
    masks = _synth(tmp_path, cams2, frames=10, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--beside", "--temporal",
                 "--temporal-sweeps", "3", "--temporal-weight", "0.05", "--temporal-starts", "neighbours,pose",
                 "--temporal-spans", "2", "--jobs", "2", "--smooth", "6", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    note = re.search(r"note: --temporal: 10 frames refit over 3 sweeps from neighbours and pose \(2 processes, "
                     r"the body sizes measured again every 2 sweeps\); mean fit \(IoU\) (\d\.\d+)", err)
    assert note, err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["temporal"] is True and meta["temporal_weight"] == 0.05 and meta["temporal_sweeps"] == 3
    assert meta["temporal_starts"] == ["neighbours", "pose"] and meta["temporal_sizes_every"] == 2
    assert meta["temporal_searches"] == [4, 8]  # past the 3 sweeps, and no reach search: none in the note
    assert meta["temporal_spans"] == [2]
    from kms2pin.ecm import Trajectory

    robot = load(LOWER, root="free")
    kept = Trajectory.from_csv(robot, out / "temporal.csv").q
    rows = (out / "temporal.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == [str(k) for k in range(10)]
    assert "taken from" not in "".join(rows)
    fits = [float(r.split(",")[rows[0].split(",").index("fit")]) for r in rows[1:]]
    assert float(note[1]) == pytest.approx(np.mean(fits), abs=6e-4)
    assert not np.allclose(kept, Trajectory.from_csv(robot, out / "beside.csv").q, atol=1e-6)
    reports = []
    for extra in (["--beside"], ["--temporal"]):
        assert main(["evaluate", str(out), str(masks / "truth.csv"), "--json", *extra]) == 0
        reports.append(json.loads(capsys.readouterr().out))
    assert reports[1]["revolute_rmse_deg"] < 0.9 * reports[0]["revolute_rmse_deg"]  # (2.36 -> 1.79 deg)
    # animation.html draws the refit at the sizes it measured again, not the track's (poses.npz)
    drawn = _drawn_scales(robot, out)
    online = np.load(out / "poses.npz")["body_scales"]
    assert np.all((drawn >= SCALE_MIN) & (drawn <= SCALE_MAX))
    assert np.abs(drawn - online).max() > 1e-3 and np.abs(drawn - 1.0).max() > 1e-3  # nor the spec's
    saved = Trajectory.from_npz(robot, out / "temporal.npz")  # the refit with those sizes, as poses.npz the track
    np.testing.assert_allclose(saved.scales, drawn, rtol=1e-12)
    np.testing.assert_allclose(saved.q, kept, atol=1e-6)
    np.testing.assert_allclose([r.fit for r in saved.results], fits, rtol=0, atol=5.1e-5)  # the rows' own fits (4 places)
    _smoothed_and_scored(robot, out, masks, kept, "--temporal", capsys)


def test_after_an_offline_pass_the_overlay_shows_its_poses_at_its_sizes(tmp_path, cams2, capsys):
    """overlay.mp4 after ``--temporal``: each frame drawn again at temporal.npz's poses and
    sizes (the refit), nearer that drawing than the online track's (poses.npz), frame by frame."""
    from kms2pin.ecm import Trajectory
    from kms2pin.video.io import read_mask
    from kms2pin.viewer.overlay import overlay_image

    masks = _synth(tmp_path, cams2, frames=5, noise=0.05)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--temporal", "--temporal-sweeps", "3",
                 "--temporal-weight", "0.05", "--jobs", "1", "-o", str(out)]) == 0
    capsys.readouterr()
    robot = load(LOWER, root="free")
    cameras = Camera.list_from_json(masks / "cameras.json")
    refit, online = Trajectory.from_npz(robot, out / "temporal.npz"), Trajectory.from_npz(robot, out / "poses.npz")
    shown = [img.astype(float) for img in video_frames(out / "overlay.mp4")]
    assert len(shown) == 5
    gaps = []
    for k, img in enumerate(shown):
        views = [read_mask(masks / f"cam{c}" / f"frame_{k:05d}.png", k, cam.shape, "", set())
                 for c, cam in enumerate(cameras)]
        a = overlay_image(robot, cameras, views, refit.q[k], refit.scales).astype(float)
        b = overlay_image(robot, cameras, views, online.q[k], online.scales).astype(float)
        differ = np.abs(a - b).sum(axis=2) > 60  # where the two drawings' ellipses part
        assert differ.sum() > 100
        gaps.append((np.abs(img - a)[differ].mean(), np.abs(img - b)[differ].mean()))
    # (about 22 against 36 grey levels; the online track's overlay gives the reverse)
    assert all(to_refit < 0.75 * to_online for to_refit, to_online in gaps), gaps


def test_an_overlay_redraw_interrupted_leaves_the_online_tracks_and_no_temporary_file(tmp_path, cams2, monkeypatch,
                                                                                         capsys):
    """Ctrl-C while overlay.mp4 is drawn again after ``--beside``: the online track's
    overlay.mp4 stays whole (every frame), no temporary file is left, meta.json says
    the run is not complete, and the exit status is 130."""
    import kms2pin.commands.track as track_command

    masks = _synth(tmp_path, cams2, frames=4)
    out = tmp_path / "out"
    drawn, real = [], track_command._overlay_frame

    def interrupted(*args):
        drawn.append(1)
        if len(drawn) == 4 + 2:  # the redraw's second frame
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(track_command, "_overlay_frame", interrupted)
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--beside", "-o", str(out)]) == 130
    capsys.readouterr()
    assert len(drawn) == 6 and (out / "beside.csv").is_file()
    assert len(video_frames(out / "overlay.mp4")) == 4
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []
    assert json.loads((out / "meta.json").read_text())["complete"] is False


def _drawn_scales(robot, out: Path) -> np.ndarray:
    """(n_bodies, 3): the sizes animation.html draws each body at, relative to the spec's."""
    from conftest import drawn_semi_axes

    html = (out / "animation.html").read_text()
    inner, outer = drawn_semi_axes(html, "inner"), drawn_semi_axes(html, "outer")
    scales = np.array([inner[b] / robot.inner(b) for b in robot.bodies])
    np.testing.assert_allclose([outer[b] / robot.outer(b) for b in robot.bodies], scales, rtol=1e-12)
    return scales


def test_temporal_runs_with_the_refits_defaults_and_its_settings_alone_are_noted(tmp_path, capsys):
    from kms2pin.ecm.temporal import SEARCHES as T_SEARCHES
    from kms2pin.ecm.temporal import SIZES_EVERY as T_SIZES_EVERY
    from kms2pin.ecm.temporal import SPANS as T_SPANS
    from kms2pin.ecm.temporal import STARTS as T_STARTS
    from kms2pin.ecm.temporal import SWEEPS as T_SWEEPS
    from kms2pin.ecm.temporal import WEIGHT as T_WEIGHT

    masks = _synth(tmp_path, frames=3)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--temporal", "-o", str(out)]) == 0
    assert re.search(rf"note: --temporal: 3 frames refit over {T_SWEEPS} sweeps from pose and target \(\d "
                     rf"process(es)?, the body sizes measured again every {T_SIZES_EVERY} sweeps\)",
                     capsys.readouterr().err)
    meta = json.loads((out / "meta.json").read_text())
    assert (meta["temporal_weight"], meta["temporal_sweeps"]) == (T_WEIGHT, T_SWEEPS) == (0.01, 20)
    assert meta["temporal_searches"] == list(T_SEARCHES) == [4, 8]
    assert meta["temporal_spans"] == list(T_SPANS) == [4, 4, 4, 4, 2, 2, 2, 2]
    assert meta["temporal_starts"] == list(T_STARTS) == ["pose", "target"]
    assert meta["temporal_sizes_every"] == T_SIZES_EVERY == 2
    other = tmp_path / "other"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--temporal-sweeps", "2",
                 "-o", str(other)]) == 0
    err = capsys.readouterr().err
    assert ("note: --temporal-weight, --temporal-sweeps, --temporal-starts, --temporal-sizes-every, "
            "--temporal-searches and --temporal-spans set the refit of --temporal; without it they do nothing") in err
    assert not (other / "temporal.csv").exists() and "temporal" not in json.loads((other / "meta.json").read_text())
    scales = np.load(other / "poses.npz")["body_scales"]  # the track's measured sizes, drawn in animation.html
    assert np.abs(scales - 1.0).max() > 1e-3
    np.testing.assert_allclose(_drawn_scales(load(LOWER, root="free"), other), scales, rtol=1e-12)
    for bad in (["--temporal-weight", "-1"], ["--temporal-sweeps", "0"], ["--temporal-weight", "nan"],
                ["--temporal-starts", "pose,truth"], ["--temporal-starts", "pose,pose"], ["--temporal-starts", ""],
                ["--temporal-sizes-every", "-1"], ["--temporal-sizes-every", "1.5"], ["--temporal-searches", "-1"],
                ["--temporal-searches", "4,x"], ["--temporal-searches", ""], ["--temporal-spans", "0"],
                ["--temporal-spans", "2,x"], ["--temporal-spans", ""]):
        with pytest.raises(SystemExit) as exc:  # argparse's own type check
            main(["track", LOWER, "--masks", str(masks), "--temporal", *bad, "-o", str(tmp_path / "bad")])
        assert exc.value.code == 2 and bad[0] in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_evaluate_temporal_without_that_track_says_how_to_make_it(tracked, capsys):
    out, truth = tracked
    assert main(["evaluate", str(out), str(truth), "--temporal"]) == 1
    assert "no temporal.csv (written by kms2pin track --temporal)" in capsys.readouterr().err


def test_the_people_tracks_preset_runs_the_guides_offline_command(tmp_path, cams2, capsys):
    """The tracking guide's choice for a finished recording, ``--preset people-tracks
    --stretches --jobs 2``: four tracks (the first and the preset's three beside it), the
    stretches chosen among the four, the options recorded as the preset's."""
    from kms2pin.ecm.options import PEOPLE_TRACKS

    masks = _synth(tmp_path, cams2, frames=4)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--preset", "people-tracks",
                 "--stretches", "--jobs", "2", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "--stretches: the poses of 4 frames:" in err, err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["stretches_tracks"] == 4
    flat = {name: value for group in meta["options"].values() for name, value in group.items()}
    assert flat["second_track"] == PEOPLE_TRACKS["second_track"] and flat["reach_rest"] == 0
    assert len((out / "stretches.csv").read_text().splitlines()) == 1 + 4


def test_stretches_without_a_track_beside_or_with_both_ways_is_refused(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=3)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--stretches",
                 "-o", str(out)]) == 2
    assert "--stretches chooses among tracks beside the first, and there are none: give --second-track" \
        in capsys.readouterr().err
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--stretches", "--both-ways",
                 "--second-track", "max_iterations=4", "-o", str(out)]) == 2
    assert "--stretches with --both-ways: choose one" in capsys.readouterr().err
    assert not out.exists()  # refused before anything is written


def test_beside_with_both_ways_notes_that_both_ways_takes_the_frames_beside(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=4)
    out = tmp_path / "out"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--beside", "--both-ways",
                 "-o", str(out)]) == 0
    assert "note: --beside with --both-ways: both_ways.csv already takes the frames beside" in capsys.readouterr().err
    assert (out / "both_ways.csv").is_file() and not (out / "beside.csv").exists()
    assert "beside" not in json.loads((out / "meta.json").read_text())


def test_evaluate_beside_without_that_track_says_how_to_make_it(tracked, capsys):
    out, truth = tracked
    assert main(["evaluate", str(out), str(truth), "--beside"]) == 1
    assert "no beside.csv (written by kms2pin track --beside)" in capsys.readouterr().err


def test_evaluate_both_ways_without_that_track_says_how_to_make_it(tracked, capsys):
    out, truth = tracked
    assert main(["evaluate", str(out), str(truth), "--both-ways"]) == 1
    assert "no both_ways.csv (written by kms2pin track --both-ways)" in capsys.readouterr().err


def test_stretches_with_one_camera_notes_that_the_fit_does_not_see_depth(tmp_path, capsys):
    masks = _synth(tmp_path, frames=3)
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--stretches",
                 "--second-track", "rest_prior=0.01", "-o", str(tmp_path / "out")]) == 0
    assert "note: --stretches with one camera: the fit that chooses among the tracks does not see depth" \
        in capsys.readouterr().err
    assert (tmp_path / "out" / "stretches.csv").is_file()


def test_both_ways_with_one_camera_notes_that_the_fit_does_not_see_depth(tmp_path, capsys):
    masks = _synth(tmp_path, frames=3)
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "--both-ways",
                 "-o", str(tmp_path / "out")]) == 0
    assert "note: --both-ways with one camera: the fit that chooses between the two tracks does not see depth" \
        in capsys.readouterr().err
    assert (tmp_path / "out" / "both_ways.csv").is_file()


def test_jobs_track_the_tracks_beside_in_several_processes_to_the_same_outputs(tmp_path, cams2, capsys):
    """``--jobs N``: the tracks beside (``--second-track``) tracked in N processes write the
    outputs one process writes, byte for byte (trajectory.csv, stretches.csv; both_ways.csv,
    whose backward tracks are tracked so too); by default one process a track, at most one a
    core; meta.json says how many ran."""
    from kms2pin.ecm.workers import FORK, usable_cores

    masks = _synth(tmp_path, cams2, frames=6, noise=0.05)
    tracks = ["--rest-prior", "10", "--second-track", "rest_prior=0; rest_prior=0,max_iterations=4"]
    written = {}
    for jobs in ("1", "3", None):
        for extra, name in ((["--stretches"], "stretches.csv"), (["--both-ways"], "both_ways.csv")):
            out = tmp_path / f"out-{jobs}-{name}"
            given = ["--jobs", jobs] if jobs else []
            assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", *tracks, *extra,
                         *given, "-o", str(out)]) == 0
            meta = json.loads((out / "meta.json").read_text())
            assert meta["jobs"] == ((min(int(jobs), 3) if jobs else min(3, usable_cores())) if FORK else 1)
            written[jobs, name] = [(out / f).read_bytes() for f in ("trajectory.csv", name)]
    for key, files in written.items():
        assert files == written["1", key[1]], key
    capsys.readouterr()
    with pytest.raises(SystemExit) as err:
        main(["track", LOWER, "--masks", str(masks), "--jobs", "0", "-o", str(tmp_path / "x")])
    assert err.value.code == 2
    assert "--jobs: expected a whole number >= 1, got '0'" in capsys.readouterr().err


def test_mask_folders_beyond_the_cameras_are_named_in_a_note(tmp_path, cams2, capsys):
    """Masks of two cameras tracked with one camera's file: cam1/ is not tracked, and the
    note says so instead of leaving it out silently."""
    masks = _synth(tmp_path, cams2, frames=2)
    one = tmp_path / "one.json"
    cams = json.loads((masks / "cameras.json").read_text())
    one.write_text(json.dumps(cams[0]))
    capsys.readouterr()
    assert main(["track", LOWER, "--masks", str(masks), "--camera", str(one), "--no-progress", "--no-video",
                 "-o", str(tmp_path / "out")]) == 0
    assert f"note: {masks}: cam1 not tracked: the cameras give 1 camera(s)" in capsys.readouterr().err
