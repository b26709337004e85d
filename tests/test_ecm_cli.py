"""synth -> track -> evaluate end to end, and bad input to the ECM commands."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from kms2pin.cli import main
from kms2pin.ecm.camera import Camera
from kms2pin.robot import load

SPECS = Path(__file__).resolve().parents[1] / "specs"
LOWER = str(SPECS / "lowerbody.kms")


@pytest.fixture(scope="module")
def cams2(tmp_path_factory) -> str:
    robot = load(LOWER, root="free")
    path = tmp_path_factory.mktemp("cams") / "cams.json"
    Camera.list_to_json([Camera.default(), Camera.look_at(position=[8, 0, 8], target=robot.q_rest[:3])], path)
    return str(path)


def _synth(tmp_path, cams, frames=4, noise=0.0, extra=()):
    d = tmp_path / "masks"
    assert main(["synth", LOWER, "--frames", str(frames), "--cameras", cams, "--noise", str(noise),
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
    --tol-px sets the outlines' test of convergence (0: the joints' test alone).  Without
    the priors a one-camera run points at the upright prior (the model has joint limits)."""
    d = tmp_path / "m"
    anatomical = str(SPECS / "anatomical" / "lowerbody.kms")  # joint limits: both hypotheses
    assert main(["synth", anatomical, "--frames", "3", "--size-mismatch", "0.1", "-o", str(d)]) == 0
    runs = {
        "default": [],
        "off": ["--no-mirror-hypothesis", "--no-swap-hypothesis", "--no-limb-search", "--no-size-calibration",
                "--depth-prior", "0.02", "--tol-px", "0.5",
                "--upright", "0.1", "--up", "0", "0", "2", "--rest-prior", "0.01"],
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
        meta = json.loads((out / "meta.json").read_text())
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
            assert meta["rest_prior"] == 0.0
            assert np.abs(scales - 1.0).max() > 0.01  # measured: synth's sizes differ by 10 %
        else:
            assert not (meta["mirror_hypothesis"] or meta["swap_hypothesis"] or meta["size_calibration"])
            assert not meta["limb_search"]
            assert meta["depth_prior"] == 0.02 and meta["upright"] == 0.1 and meta["up"] == [0.0, 0.0, 1.0]
            assert meta["rest_prior"] == 0.01
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
    # rows up to the bad frame were written
    assert len((tmp_path / "o" / "trajectory.csv").read_text().splitlines()) == 2


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
    assert "frame_00002.png: frame 2: cannot read" in err


def test_track_non_binary_and_empty(tmp_path, cams2, capsys):
    masks = _synth(tmp_path, cams2, frames=3)
    p = masks / "cam0" / "frame_00001.png"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), (img // 255 * 200).astype(np.uint8) + 10)
    for c in (0, 1):
        cv2.imwrite(str(masks / f"cam{c}" / "frame_00002.png"), np.zeros((240, 320), np.uint8))
    out = tmp_path / "o"
    assert main(["track", LOWER, "--masks", str(masks), "--no-progress", "--no-video", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "frame_00001.png: frame 1: not a binary mask; thresholded at 127" in err
    assert "frame 2: empty mask" in err
    last = (out / "trajectory.csv").read_text().splitlines()[-1]
    assert last.endswith("empty mask")


def test_evaluate_bad_folder(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    assert main(["evaluate", str(tmp_path / "x"), str(tmp_path / "t.csv")]) == 1
    assert "not a kms2pin track output" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "nope"), str(tmp_path / "t.csv")]) == 2


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
              ["--limb-search-drop", "-0.01"], ["--tol-px", "-0.1"]]
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
