"""BVH out: ``kms2pin convert`` and ``track``'s ``motion.bvh``, checked with an independent
BVH forward kinematics (tests/_bvh.py) and by importing what was written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from _bvh import Bvh

import kms2pin
from kms2pin.bvh import to_bvh
from kms2pin.cli import main
from kms2pin.ecm import Trajectory
from kms2pin.errors import BvhError

SPECS = Path(__file__).resolve().parents[1] / "specs"
TWO_ROOTS = """
bvec left { pos(-0.3, 0, 4); orient(1, 0, 0); }
bvec right { pos(0.3, 0, 4); orient(1, 0, 0); }
rigidBodySystem pair {
    ellipsoidBody a { innerLam(0.1, 0.3, 0.1); outerLam(0.12, 0.36, 0.12); bvec top { pos(0, 0.3, 0); orient(1, 0, 0); } }
    ellipsoidBody b { innerLam(0.1, 0.3, 0.1); outerLam(0.12, 0.36, 0.12); bvec top { pos(0, 0.3, 0); orient(1, 0, 0); } }
}
constraint revolute(left, pair.a.top, 10);
constraint revolute(right, pair.b.top, -10);
"""


def _motion(robot, frames: int, seed: int) -> np.ndarray:
    """Random configurations: every joint turned by up to 120 deg, a free root anywhere turned anyhow."""
    rng = np.random.default_rng(seed)
    q = np.array([robot.random_configuration(rng, 120.0) for _ in range(frames)])
    if robot.root == "free":
        for k in range(frames):
            axis = rng.normal(size=3)
            q[k, :7] = pin.SE3ToXYZQUAT(pin.SE3(pin.exp3(axis / np.linalg.norm(axis) * rng.uniform(0, np.pi)),
                                                rng.uniform(-2, 2, 3)))
    return q


def _joint_points(robot, q) -> dict[str, np.ndarray]:
    """Every body's joint point (its link frame's origin) at ``q``."""
    return {b: M.act(np.asarray(robot.system.joint_of(b).child_bvec.pos, dtype=float))
            for b, M in zip(robot.bodies, robot.body_poses(q))}


@pytest.mark.parametrize(("spec", "root"), [("human", "free"), ("fullbody", "free"), ("lowerbody", "free"),
                                            ("jplhand", "spec"), ("puma600", "spec")])
def test_a_trajectory_converted_to_bvh_and_imported_puts_every_joint_where_it_was(tmp_path, capsys, spec, root):
    robot = kms2pin.load(SPECS / f"{spec}.kms", root=root)
    q = _motion(robot, 8, seed=len(spec))
    Trajectory(robot, q).to_csv(tmp_path / "t.csv")
    bvh = tmp_path / "m.bvh"
    root_option = [] if root == "free" else ["--root", "spec"]
    assert main(["convert", str(tmp_path / "t.csv"), "--model", str(SPECS / f"{spec}.kms"), *root_option,
                 "--fps", "25", "-o", str(bvh)]) == 0
    assert main(["import", str(bvh), "-o", str(tmp_path / "in")]) == 0
    assert "8 frames at 25 fps" in capsys.readouterr().out
    imported = kms2pin.load(tmp_path / "in" / "m.kms", root="free")
    q_in = Trajectory.from_csv(imported, tmp_path / "in" / "motion.csv").q
    where = {b.name: (b.name, "joint") for b in imported.system.bodies}  # a merged body's point is a bvec
    where |= {n: (b.name, n) for b in imported.system.bodies for n in b.bvecs if n not in where and n != "joint"}
    worst = 0.0
    for k in range(len(q)):
        poses = dict(zip(imported.bodies, imported.body_poses(q_in[k])))
        for body, point in _joint_points(robot, q[k]).items():
            holder, bvec = where[body]
            there = poses[holder].act(np.asarray(imported.system.body(holder).bvecs[bvec].pos))
            worst = max(worst, float(np.linalg.norm(there - point)))
    assert worst < 1e-6 * robot.height, worst / robot.height


def test_the_bvh_puts_every_joint_where_the_model_does_in_the_documented_channel_order(tmp_path):
    robot = kms2pin.load(SPECS / "human.kms", root="free")
    q = _motion(robot, 6, seed=3)
    text = to_bvh(robot, q, 30.0)
    bvh = Bvh(text)
    assert list(bvh.joints) == list(robot.bodies)  # one joint per body, named after it
    assert bvh.frame_time == pytest.approx(1 / 30) and len(bvh.frames) == 6
    for name, (parent, _, channels) in bvh.joints.items():
        assert channels == (("Xposition", "Yposition", "Zposition") if parent is None else ()) + (
            "Zrotation", "Xrotation", "Yrotation")
        assert parent == robot.system.joint_of(name).parent
    assert bvh.joints["pelvis"][1].tolist() == [0, 0, 0]
    for k in range(len(q)):
        points, _, ends = bvh.world(k)
        for body, point in _joint_points(robot, q[k]).items():
            np.testing.assert_allclose(points[body], point, atol=1e-8)
        # a leaf's End Site: its joint point reflected through its ellipsoid's centre
        for leaf in ("head", "leftFoot", "rightHand"):
            centre = robot.body_pose(q[k], leaf).translation
            np.testing.assert_allclose(ends[leaf][0], 2 * centre - points[leaf], atol=1e-8)
    # the hands hang from fixed wrists: their channels stay 0
    columns = [(name, c) for name, (_, _, channels) in bvh.joints.items() for c in channels]
    for hand in ("leftHand", "rightHand"):
        np.testing.assert_allclose(bvh.frames[:, [i for i, (n, _) in enumerate(columns) if n == hand]], 0, atol=1e-9)


def test_models_bvh_cannot_express_are_refused_with_the_reason(tmp_path, capsys):
    gantry = kms2pin.load(SPECS / "gantry.kms", root="free")
    Trajectory(gantry, gantry.q_rest).to_csv(tmp_path / "g.csv")
    assert main(["convert", str(tmp_path / "g.csv"), "--model", str(SPECS / "gantry.kms"),
                 "-o", str(tmp_path / "g.bvh")]) == 1
    err = capsys.readouterr().err
    assert "has prismatic joints (" in err and "BVH joints below the root turn about a point and cannot slide" in err
    assert not (tmp_path / "g.bvh").exists()
    two = kms2pin.load(TWO_ROOTS)
    with pytest.raises(BvhError, match=r"'pair' has 2 joints to the inertial frame \(a, b\); a BVH skeleton has one"):
        to_bvh(two, two.q_rest, 30)


def test_bad_convert_calls_are_refused_before_anything_is_written(tmp_path, capsys):
    human = str(SPECS / "human.kms")
    robot = kms2pin.load(human, root="free")
    Trajectory(robot, robot.q_rest).to_csv(tmp_path / "t.csv")
    (tmp_path / "header.csv").write_text((tmp_path / "t.csv").read_text().splitlines()[0] + "\n")
    cases = [
        (["convert", str(tmp_path / "t.csv"), "--model", human, "-o", str(tmp_path / "m.txt")], 2,
         "-o " + str(tmp_path / "m.txt") + ": convert writes BVH; name a .bvh file"),
        (["convert", str(tmp_path / "nope.csv"), "--model", human, "-o", str(tmp_path / "m.bvh")], 2,
         "nope.csv: no such file"),
        (["convert", str(tmp_path / "header.csv"), "--model", human, "-o", str(tmp_path / "m.bvh")], 1,
         "header.csv: the trajectory has no frames"),
        (["convert", str(tmp_path / "t.csv"), "--model", human, "--root", "spec", "-o", str(tmp_path / "m.bvh")], 1,
         "missing columns pelvis_inertialAnchor"),
    ]
    for argv, status, words in cases:
        assert main(argv) == status, argv
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["header.csv", "t.csv"]


def test_track_writes_the_tracked_motion_as_bvh(tmp_path, capsys):
    lower = str(SPECS / "lowerbody.kms")
    assert main(["synth", lower, "--frames", "3", "-o", str(tmp_path / "masks")]) == 0
    out = tmp_path / "out"
    assert main(["track", lower, "--masks", str(tmp_path / "masks"), "--no-progress", "--no-video", "--fps", "12",
                 "-o", str(out)]) == 0
    robot = kms2pin.load(lower, root="free")
    q = Trajectory.from_csv(robot, out / "trajectory.csv").q
    bvh = Bvh.read(out / "motion.bvh")
    assert len(bvh.frames) == 3 and bvh.frame_time == pytest.approx(1 / 12)
    for k in range(3):
        points = bvh.world(k)[0]
        for body, point in _joint_points(robot, q[k]).items():
            np.testing.assert_allclose(points[body], point, atol=1e-6)  # trajectory.csv's 10 digits


def test_track_of_a_model_bvh_cannot_express_notes_it_and_finishes(tmp_path, capsys):
    spec = tmp_path / "pair.kms"
    spec.write_text(TWO_ROOTS)
    assert main(["synth", str(spec), "--root", "spec", "--frames", "2", "-o", str(tmp_path / "masks")]) == 0
    out = tmp_path / "out"
    assert main(["track", str(spec), "--root", "spec", "--masks", str(tmp_path / "masks"), "--no-progress",
                 "--no-video", "-o", str(out)]) == 0
    assert "note: motion.bvh skipped ('pair' has 2 joints to the inertial frame (a, b); a BVH skeleton has one " \
           "root)" in capsys.readouterr().err
    assert not (out / "motion.bvh").exists() and (out / "trajectory.csv").is_file()
