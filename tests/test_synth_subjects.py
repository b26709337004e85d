"""``kms2pin synth`` of subjects that are not the model's rest motions: ``--motion FILE.csv``
renders a given trajectory, ``--shape capsule`` renders capsules in place of the ellipsoids."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from kms2pin.cli import main
from kms2pin.ecm import Trajectory
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.synth import render
from kms2pin.robot import load

SPECS = Path(__file__).resolve().parents[1] / "specs"
LOWER = str(SPECS / "lowerbody.kms")


def _masks(folder: Path) -> list[np.ndarray]:
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "cam0").glob("frame_*.png"))]


def _rewrite_like_track(truth: Path, path: Path) -> None:
    """``truth`` with its columns in reverse order and track's fit and flags columns added."""
    with open(truth, newline="") as f:
        rows = list(csv.reader(f))
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*reversed(rows[0]), "fit", "flags"])
        w.writerows([*reversed(r), "0.9", "poor fit (0.9)"] for r in rows[1:])


def test_synth_of_a_truth_csv_reproduces_the_same_masks(tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    noise = ["--noise", "0.05", "--size-mismatch", "0.1", "--seed", "3"]
    assert main(["synth", LOWER, "--motion", "walk", "--frames", "6", *noise, "-o", str(a)]) == 0
    assert main(["synth", LOWER, "--motion", str(a / "truth.csv"), *noise, "-o", str(b)]) == 0
    _rewrite_like_track(a / "truth.csv", tmp_path / "tracked.csv")
    assert main(["synth", LOWER, "--motion", str(tmp_path / "tracked.csv"), "--frames", "4", *noise, "-o", str(c)]) == 0
    first, again, four = _masks(a), _masks(b), _masks(c)
    assert len(first) == len(again) == 6 and len(four) == 4
    for k in range(6):
        np.testing.assert_array_equal(again[k], first[k], err_msg=f"frame {k}")
        if k < 4:
            np.testing.assert_array_equal(four[k], first[k], err_msg=f"frame {k}")
    robot = load(LOWER, root="free")
    np.testing.assert_allclose(Trajectory.from_csv(robot, b / "truth.csv").q,
                               Trajectory.from_csv(robot, a / "truth.csv").q, atol=1e-9)
    assert capsys.readouterr().out.splitlines()[-1] == f"{c}: 4 frames x 1 camera(s)"


@pytest.mark.parametrize(
    ("motion", "extra", "status", "words"),
    [
        ("wlak", [], 2, "--motion: 'wlak' is neither a motion (sweep, walk, random) nor a file"),
        ("{dir}", [], 2, "is a directory, not a trajectory CSV file"),
        ("{truth}", ["--frames", "7"], 2, "--frames 7: {truth} has 3 frames"),
        ("{truth}", ["--root", "spec"], 1, "missing columns pelvis_inertialAnchor for 'lowerBodyBipedal' (root='spec')"),
        ("{header}", [], 1, "{header}: the trajectory has no frames"),
    ],
)
def test_a_motion_file_that_cannot_be_rendered_is_refused_before_anything_is_written(
        tmp_path, capsys, motion, extra, status, words):
    truth_dir = tmp_path / "t"
    assert main(["synth", LOWER, "--frames", "3", "-o", str(truth_dir)]) == 0
    truth = truth_dir / "truth.csv"
    header = tmp_path / "header.csv"
    header.write_text(truth.read_text().splitlines()[0] + "\n")
    names = {"dir": str(truth_dir), "truth": str(truth), "header": str(header)}
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["synth", LOWER, "--motion", motion.format(**names), *extra, "-o", str(out)]) == status
    err = capsys.readouterr().err
    assert words.format(**names) in err and "Traceback" not in err
    assert not out.exists()


def test_synth_shape_capsule_renders_capsules_in_place_of_the_ellipsoids(tmp_path, capsys):
    ell, cap = tmp_path / "e", tmp_path / "c"
    assert main(["synth", LOWER, "--frames", "3", "-o", str(ell)]) == 0
    assert main(["synth", LOWER, "--frames", "3", "--shape", "capsule", "-o", str(cap)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"{cap}: 3 frames x 1 camera(s) (capsules)"
    robot = load(LOWER, root="free")
    truth = Trajectory.from_csv(robot, cap / "truth.csv").q
    (camera,) = Camera.list_from_json(cap / "cameras.json")
    for k, (e, c) in enumerate(zip(_masks(ell), _masks(cap))):
        np.testing.assert_array_equal(c > 0, render(robot, truth[k], [camera], shape="capsule")[0])
        differ = (c > 0) != (e > 0)
        assert 0.02 < differ.sum() / (e > 0).sum() < 0.5  # the same subject, another outline
    with pytest.raises(SystemExit) as exit_:
        main(["synth", LOWER, "--shape", "cube", "-o", str(tmp_path / "x")])
    assert exit_.value.code == 2 and "invalid choice: 'cube'" in capsys.readouterr().err
