"""``kms2pin import``: a BVH file's skeleton as a model and its motion as that model's
trajectory, checked against an independent BVH forward kinematics (tests/_bvh.py)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from _bvh import Bvh
from scipy.spatial.transform import Rotation

import kms2pin
from kms2pin.cli import main
from kms2pin.ecm import Trajectory

DATA = Path(__file__).resolve().parent / "data"
CMU = DATA / "cmu_131_01_walk.bvh"  # 240 frames of CMU subject 131's walk (tests/data/README.md)
CMU_SCALE = 0.05644  # metres per file unit
CMU_HINGES = ("LeftKnee", "RightKnee", "LeftElbow", "RightElbow")


def _import(tmp_path: Path, bvh: Path, *options: str, name: str | None = None):
    """Run ``kms2pin import``; the model (free root), its trajectory and the spec."""
    out = tmp_path / "out"
    assert main(["import", str(bvh), "-o", str(out), *options]) == 0
    kms = out / f"{name or bvh.stem}.kms"
    robot = kms2pin.load(kms, root="free")
    return robot, Trajectory.from_csv(robot, out / "motion.csv").q, kms.read_text()


def _model_points(robot, q):
    """Every named bound vector's world point at ``q``: (body, bvec) -> point."""
    out = {}
    for body, pose in zip(robot.bodies, robot.body_poses(q)):
        for name, bvec in robot.system.body(body).bvecs.items():
            out[body, name] = pose.act(np.asarray(bvec.pos))
    return out


def _bone_end_errors(robot, q, bvh: Bvh, scale: float, turn=None, renamed=None) -> np.ndarray:
    """For every frame, the largest distance between a BVH joint or End Site (the test's
    own forward kinematics) and the model's bound vector that stands for it: a body's
    'joint' (its BVH joint), a bound vector named after a BVH joint (that joint's point:
    a bone's end), 'end', 'end_2', ... (its End Sites).  ``renamed``: model names of BVH
    joints whose names are not names of the language."""
    errors = []
    renamed = renamed or {}
    for k in range(len(q)):
        points, _, ends = bvh.world(k, scale, turn)
        worst, seen = 0.0, set()
        for (body, name), x in _model_points(robot, q[k]).items():
            body = renamed.get(body, body)
            if name == "joint":
                ref, key = points[body], body
            elif name not in renamed and re.fullmatch(r"end(_\d+)?", name):  # End Sites: end, end_2, ...
                n = int(name[4:]) if name != "end" else 1
                ref, key = ends[body][n - 1], (body, n)
            else:
                ref, key = points[renamed.get(name, name)], renamed.get(name, name)
            worst = max(worst, float(np.linalg.norm(x - ref)))
            seen.add(key)
        assert set(points) <= seen, f"BVH joints without a point in the model: {set(points) - seen}"
        assert {(b, n + 1) for b, es in ends.items() for n in range(len(es))} <= seen | _zero_ends(bvh)
        errors.append(worst)
    return np.array(errors)


def _zero_ends(bvh: Bvh) -> set:
    return {(b, n + 1) for b, es in bvh.ends.items() for n, e in enumerate(es) if not np.any(e)}


def test_every_bone_end_of_the_cmu_walk_is_where_the_bvh_puts_it(tmp_path, capsys):
    robot, q, text = _import(tmp_path, CMU, "--scale", str(CMU_SCALE))
    bvh = Bvh.read(CMU)
    height = bvh.rest_height(CMU_SCALE)
    assert len(q) == 240 == len(bvh.frames)
    errors = _bone_end_errors(robot, q, bvh, CMU_SCALE)
    assert errors.max() < 1e-6 * height, errors.max() / height
    assert {j.kind for j in robot.system.joints} == {"spherical"}
    # one body per bone: the 31 joints less the three whose children all start at their point
    assert len(robot.bodies) == 28
    assert not {"Chest2", "LeftWrist", "RightWrist"} & set(robot.bodies)
    out = capsys.readouterr().out
    assert "zero-length bones merged: Chest2, LeftWrist, RightWrist; 240 frames at 120 fps; Y-up" in out
    assert "Metres (0.05644 m per file unit); +y up (the file is Y-up" in text


def test_the_rest_pose_is_the_offsets_pose_with_every_joint_coordinate_zero(tmp_path):
    """A motion whose every rotation is zero is the rest pose: its coordinates are 0 and the
    model's q_rest puts every BVH joint where the offsets do."""
    text = CMU.read_text().splitlines()
    motion = text.index("MOTION")
    n = len(text[motion + 3].split())
    still = tmp_path / "still.bvh"
    still.write_text("\n".join(text[: motion + 1] + ["Frames: 2", "Frame Time: 0.5"]
                               + [" ".join(["1", "2", "3"] + ["0"] * (n - 3))] * 2) + "\n")
    robot, q, _ = _import(tmp_path, still, "--scale", str(CMU_SCALE))
    coordinates = robot.coordinates(q)
    np.testing.assert_array_equal(coordinates[:, 7:], 0.0)
    np.testing.assert_allclose(coordinates[:, :7], [[1 * CMU_SCALE, 2 * CMU_SCALE, 3 * CMU_SCALE, 0, 0, 0, 1]] * 2)
    np.testing.assert_array_equal(robot.coordinates(robot.q_rest)[7:], 0.0)
    bvh = Bvh.read(still)
    rest = robot.q_rest.copy()
    rest[:3] = bvh.world(0, CMU_SCALE)[0]["Hips"]
    assert _bone_end_errors(robot, rest[None], bvh, CMU_SCALE).max() < 1e-9


def test_hinged_knees_and_elbows_are_revolute_about_the_axis_they_turn_about(tmp_path):
    """CMU's knees and elbows turn about one axis (the ASF skeleton's): hinged, they keep
    every bone end in place, and flex one way (positive)."""
    robot, q, text = _import(tmp_path, CMU, "--scale", str(CMU_SCALE), "--hinge", ",".join(CMU_HINGES))
    kinds = {j.child: j.kind for j in robot.system.joints}
    assert {b for b, kind in kinds.items() if kind == "revolute"} == set(CMU_HINGES)
    assert set(kinds.values()) == {"revolute", "spherical"}
    assert text.count("// --hinge") == 4
    bvh = Bvh.read(CMU)
    assert _bone_end_errors(robot, q, bvh, CMU_SCALE).max() < 1e-5 * bvh.rest_height(CMU_SCALE)
    coordinates = robot.coordinates(q)
    for name in ("LeftKnee", "RightKnee"):
        angle = coordinates[:, list(robot.coordinate_names).index(f"{name}_joint")]
        assert angle.mean() > 0 and angle.max() > 40 and angle.min() > -5, (name, angle.min(), angle.max())


def _write(path: Path, hierarchy: str, rows: np.ndarray, frame_time: float = 0.04) -> Path:
    motion = "\n".join(" ".join(f"{x:.12g}" for x in r) for r in rows)
    path.write_text(f"HIERARCHY\n{hierarchy.strip()}\nMOTION\nFrames: {len(rows)}\nFrame Time: {frame_time}\n{motion}\n")
    return path


# every channel order, six channels on the root with the positions last, a joint below the
# root with constant position channels (another place than its OFFSET), one- and no-channel
# joints, names with spaces, several End Sites, bones of zero length with children (merged:
# hub into lever and stub, stub into tip) and one without (left out: nub)
ODD = """
ROOT Root Bone
{
    OFFSET 0.5 1 0.2
    CHANNELS 6 Yrotation Xrotation Zrotation Xposition Zposition Yposition
    JOINT spine {
        OFFSET 0 1 0
        CHANNELS 3 Xrotation Zrotation Yrotation
        JOINT neck
        {
            OFFSET 0.1 0.9 0.1
            CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
            End Site
            {
                OFFSET 0 0.5 0
            }
        }
        JOINT hub
        {
            OFFSET 0.6 0.5 0
            CHANNELS 2 Zrotation Yrotation
            JOINT lever
            {
                OFFSET 0 0 0
                CHANNELS 1 Xrotation
                End Site { OFFSET 0.8 0 0 }
                End Site { OFFSET 0.7 0.2 0 }
            }
            JOINT stub
            {
                OFFSET 0 0 0
                CHANNELS 0
                JOINT tip
                {
                    OFFSET 0 0 0
                    CHANNELS 3 Yrotation Zrotation Xrotation
                    End Site { OFFSET 0 -0.4 0.1 }
                }
            }
        }
        JOINT nub
        {
            OFFSET -0.4 0.6 0
            CHANNELS 3 Zrotation Xrotation Yrotation
        }
    }
}
"""
ODD_CHANNELS = (6, 3, 6, 2, 1, 0, 3, 3)


def _odd_motion(rng: np.random.Generator, frames: int = 25) -> np.ndarray:
    rows = rng.uniform(-170, 170, (frames, sum(ODD_CHANNELS)))
    rows[:, 3:6] = rng.uniform(-2, 2, (frames, 3))  # the root's position
    rows[:, 9:12] = [0.3, 0.8, -0.2]  # neck's positions: constant, not its OFFSET
    return rows


def test_channel_orders_six_channel_joints_and_end_sites_are_honoured(tmp_path, capsys):
    bvh_path = _write(tmp_path / "odd.bvh", ODD, _odd_motion(np.random.default_rng(4)))
    robot, q, text = _import(tmp_path, bvh_path, "--up", "y")
    bvh = Bvh.read(bvh_path)
    assert _bone_end_errors(robot, q, bvh, 1.0, renamed={"Root_Bone": "Root Bone"}).max() < 1e-6 * bvh.rest_height()
    kinds = {j.child: j.kind for j in robot.system.joints}
    # hub (2 channels) is merged into lever (1) and the stub (0, no bone) into tip (3): spherical
    assert kinds == {"Root_Bone": "spherical", "spine": "spherical", "neck": "spherical", "lever": "spherical",
                     "tip": "spherical"}
    assert "merged into their children: hub, stub; left out: nub" in text
    # a name the anthropometric table does not know: 0.15 of the bone across (lever's bone: its End Sites' mean)
    bone = np.linalg.norm([0.75, 0.1, 0.0])
    np.testing.assert_allclose(sorted(robot.inner("lever")), [0.15 * bone, 0.15 * bone, 0.55 * bone], atol=5e-5)
    assert "zero-length bones merged: hub, stub; left out: nub" in capsys.readouterr().out


def test_a_one_channel_joint_is_revolute_about_its_axis_exactly(tmp_path):
    hierarchy = """
ROOT base
{
    OFFSET 0 0 0
    CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
    JOINT arm
    {
        OFFSET 0 1 0
        CHANNELS 1 Zrotation
        End Site { OFFSET 0.3 1 0.2 }
    }
}
"""
    rows = np.zeros((9, 7))
    rows[:, 3:6] = np.random.default_rng(1).uniform(-90, 90, (9, 3))
    rows[:, 6] = np.linspace(-150, 170, 9)
    bvh_path = _write(tmp_path / "one.bvh", hierarchy, rows)
    robot, q, _ = _import(tmp_path, bvh_path)
    assert robot.system.joint_of("arm").kind == "revolute"
    assert _bone_end_errors(robot, q, Bvh.read(bvh_path), 1.0).max() < 1e-9
    # the angle is the channel's; the parent body's axes are the file's (a root without a bone)
    np.testing.assert_allclose(robot.coordinates(q)[:, -1], rows[:, 6], atol=1e-7)


def test_a_hinge_finds_the_oblique_axis_a_joint_turns_about(tmp_path):
    """A knee turning about an oblique axis u (written as Z-Y-X Euler angles): hinged, it is
    a revolute joint about u, its angle each frame's, every bone end in place."""
    hierarchy = """
ROOT hips
{
    OFFSET 0 0 0
    CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
    JOINT thigh
    {
        OFFSET 0.1 -0.05 0
        CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT knee
        {
            OFFSET 0.05 -0.45 0.02
            CHANNELS 3 Zrotation Yrotation Xrotation
            End Site { OFFSET 0 -0.42 -0.03 }
        }
    }
}
"""
    rng = np.random.default_rng(7)
    u = np.array([0.9, 0.2, -0.3]) / np.linalg.norm([0.9, 0.2, -0.3])
    angles = np.radians(np.concatenate([np.linspace(0, 110, 12), np.linspace(100, -10, 8)]))
    knee = Rotation.from_rotvec(angles[:, None] * u).as_euler("ZYX", degrees=True)
    rows = np.hstack([rng.uniform(-1, 1, (20, 3)), rng.uniform(-60, 60, (20, 6)), knee])
    bvh_path = _write(tmp_path / "leg.bvh", hierarchy, rows)
    robot, q, _ = _import(tmp_path, bvh_path, "--hinge", "knee")
    joint = robot.system.joint_of("knee")
    assert joint.kind == "revolute"
    assert _bone_end_errors(robot, q, Bvh.read(bvh_path), 1.0).max() < 1e-6
    # the axis: the parent end's orient, in the thigh body's frame, is u in the world at rest
    world = robot.body_pose(robot.q_rest, "thigh").rotation @ np.asarray(joint.parent_bvec.orient)
    np.testing.assert_allclose(world, u, atol=1e-9)
    np.testing.assert_allclose(robot.coordinates(q)[:, -1], np.degrees(angles), atol=1e-7)


@pytest.mark.parametrize(("names", "words"), [
    ("LeftKnea", "--hinge: tests/data/cmu_131_01_walk.bvh has no joint 'LeftKnea' (did you mean 'LeftKnee'?)"),
    ("Hips", "--hinge: 'Hips' is the root, whose joint is free"),
    ("LeftKnee,LeftWrist", "--hinge: 'LeftWrist' has a bone of zero length and is merged into lhand, LThumb; "
                           "hinge one of them"),
])
def test_a_hinge_that_cannot_be_is_a_usage_error_before_anything_is_written(tmp_path, capsys, monkeypatch,
                                                                           names, words):
    monkeypatch.chdir(DATA.parent.parent)
    out = tmp_path / "out"
    assert main(["import", "tests/data/cmu_131_01_walk.bvh", "--hinge", names, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert not out.exists()


def test_a_z_up_file_gives_the_model_and_motion_of_the_same_y_up_one(tmp_path, capsys):
    """The CMU walk written Z-up (y -> -z... : file = W^T model) imports to the same model
    and the same motion, the up axis found and stated."""
    text = CMU.read_text()
    z_up = tmp_path / "zup" / "cmu_131_01_walk.bvh"
    z_up.parent.mkdir()
    z_up.write_text(_y_up_to_z_up(text))
    robot, q, kms = _import(tmp_path / "y", CMU, "--scale", str(CMU_SCALE))
    robot_z, q_z, kms_z = _import(tmp_path / "z", z_up, "--scale", str(CMU_SCALE))
    assert "the file is Z-up: the rest pose spans" in kms_z
    assert "Z-up (the rest pose spans" in capsys.readouterr().out
    assert kms_z.split("rigidBodySystem")[1] == kms.split("rigidBodySystem")[1]
    np.testing.assert_allclose(robot_z.coordinates(q_z), robot.coordinates(q), atol=1e-7)
    turn = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # the Z-up file's coordinates -> the model's
    bvh = Bvh.read(z_up)
    assert _bone_end_errors(robot_z, q_z, bvh, CMU_SCALE, turn).max() < 1e-6 * bvh.rest_height(CMU_SCALE, up=2)


def _y_up_to_z_up(text: str) -> str:
    """A Y-up BVH's text written Z-up: a point (x, y, z) becomes (x, -z, y); a rotation about y
    one about the file's z, one about z one about -y (its angle negated)."""
    lines, out, motion = text.splitlines(), [], None
    columns: list[tuple[int, int]] = []  # (source channel, sign) per written channel
    for line in lines:
        words = line.split()
        if motion is None and words and words[0] == "OFFSET":
            x, y, z = (float(v) for v in words[1:4])
            out.append(f"OFFSET {x!r} {-z!r} {y!r}")
        elif motion is None and words and words[0] == "CHANNELS":
            names = words[2:]
            base = len(columns)
            new = [{"X": "X", "Y": "Z", "Z": "Y"}[n[0]] + n[1:] for n in names]
            out.append(f"CHANNELS {len(names)} {' '.join(new)}")
            columns += [(base + i, -1 if n[0] == "Z" else 1) for i, n in enumerate(names)]
        elif motion is None and words and words[0] == "MOTION":
            motion = len(out)
            out.append(line)
        elif motion is not None and len(out) > motion + 2 and words:
            values = [float(v) for v in words]
            out.append(" ".join(repr(s * values[c]) for c, s in columns))
        else:
            out.append(line)
    return "\n".join(out) + "\n"


def test_resampling_keeps_whole_frames_and_slerps_between_them(tmp_path):
    robot, q, _ = _import(tmp_path / "a", CMU, "--scale", str(CMU_SCALE))
    _, q60, _ = _import(tmp_path / "b", CMU, "--scale", str(CMU_SCALE), "--fps", "60")
    _, q240, _ = _import(tmp_path / "c", CMU, "--scale", str(CMU_SCALE), "--fps", "240")
    assert len(q60) == 120 and len(q240) == 479
    np.testing.assert_allclose(robot.coordinates(q60), robot.coordinates(q[::2]), atol=1e-7)
    np.testing.assert_allclose(robot.coordinates(q240[::2]), robot.coordinates(q), atol=1e-7)
    # between frames: the root's position half way, every BVH joint's rotation half way along
    # the shorter arc (a joint with a merged one above it turns by the product of two: not checked)
    mid, before, after = q240[1::2], q[:-1], q[1:]
    np.testing.assert_allclose(mid[:, :3], (before[:, :3] + after[:, :3]) / 2, atol=1e-9)
    below_merged = {"lowerneck", "LeftCollar", "RightCollar", "lhand", "LThumb", "rhand", "RThumb"}
    for j in robot.joints:
        if j.kind == "free" or (j.kind == "spherical" and j.spec.child not in below_merged):
            a = 3 if j.kind == "free" else j.idx_q
            R0, R1, Rm = (Rotation.from_quat(x[:, a : a + 4]) for x in (before, after, mid))
            half = (R0.inv() * R1).magnitude() / 2
            np.testing.assert_allclose((R0.inv() * Rm).magnitude(), half, atol=1e-8)
            np.testing.assert_allclose((Rm.inv() * R1).magnitude(), half, atol=1e-8)


def test_body_sizes_follow_the_bones_and_the_anthropometric_table(tmp_path):
    robot, _, _ = _import(tmp_path, CMU, "--scale", str(CMU_SCALE))
    bvh = Bvh.read(CMU)
    height = bvh.rest_height(CMU_SCALE)
    for body, child, across in (("LeftHip", "LeftKnee", 0.045), ("RightKnee", "RightAnkle", 0.032),
                                ("LeftShoulder", "LeftElbow", 0.03)):
        bone = CMU_SCALE * np.asarray(bvh.joints[child][1])  # rest offset: the bone, file axes = world at rest
        inner = robot.inner(body)
        k = int(np.argmax(inner))
        assert math.isclose(inner[k], 0.55 * np.linalg.norm(bone), abs_tol=5e-5)  # written to 0.1 mm
        np.testing.assert_allclose(np.delete(inner, k), across * height, atol=5e-5)
        np.testing.assert_allclose(robot.outer(body), 1.2 * inner, atol=1e-4)
        R = robot.body_pose(robot.q_rest, body).rotation  # the long axis lies along the bone
        assert abs(R[:, k] @ bone) / np.linalg.norm(bone) > 1 - 1e-9


def test_joint_names_that_are_not_names_of_the_language_are_made_so(tmp_path):
    """Spaces and dashes become '_' (a clash takes '_2'), a keyword, 'world' or a leading
    digit is escaped, and 'joint', 'end' and 'root' (whose joint would be a free root's
    root_joint) are renamed: the model compiles and every bone end is in place."""
    hierarchy = """
ROOT root
{
    OFFSET 0 0 0
    CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
    JOINT a b
    {
        OFFSET 0 1 0
        CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT a-b { OFFSET 0 1 0 CHANNELS 3 Zrotation Yrotation Xrotation End Site { OFFSET 0 1 0 } }
    }
    JOINT double { OFFSET 1 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT 1st { OFFSET 1 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
            JOINT world { OFFSET 1 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
                JOINT joint { OFFSET 0 -1 0 CHANNELS 3 Zrotation Yrotation Xrotation
                    JOINT end { OFFSET 0 -1 0 CHANNELS 3 Zrotation Yrotation Xrotation End Site { OFFSET 0 -1 0 } } } } } }
}
"""
    rows = np.random.default_rng(2).uniform(-90, 90, (5, 27))  # the root and 7 joints
    bvh_path = _write(tmp_path / "names.bvh", hierarchy, rows)
    robot, q, _ = _import(tmp_path, bvh_path, "--up", "y")
    renamed = {"root_": "root", "a_b": "a b", "a_b_2": "a-b", "double_": "double", "_1st": "1st", "world_": "world",
               "joint_2": "joint", "end_2": "end"}
    assert set(robot.bodies) == set(renamed)
    bvh = Bvh.read(bvh_path)
    assert _bone_end_errors(robot, q, bvh, 1.0, renamed=renamed).max() < 1e-6 * bvh.rest_height()
