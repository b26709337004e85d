"""`kms2pin track --video`: synthetic colour videos of the lowerbody model walking,
seen by a front and a raised side camera, tracked without a hand-made initial
pose; initialization alone; pose files; bad and awkward input."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pinocchio as pin
import pytest

from kms2pin.cli import main
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.evaluate import evaluate
from kms2pin.ecm.tracker import Trajectory
from kms2pin.errors import InputDataError
from kms2pin.robot import load
from kms2pin.video.init import initial_pose_details, read_pose_json
from kms2pin.video.synthetic import diagonal_walk, walking_video, write_video

from ._scene import LOWER, cast_shadow, pale_walk, read_masks, render_video

N = 40


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    robot = load(str(LOWER), root="free")
    truth = diagonal_walk(robot, N)
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    d = tmp_path_factory.mktemp("walk")
    videos, cam_files, true_masks, all_frames = [], [], [], []
    for k, cam in enumerate(cams):
        frames, masks = render_video(robot, truth, cam, seed=k)
        videos.append(d / f"cam{k}.avi")
        write_video(videos[-1], frames)
        cam_files.append(d / f"cam{k}.json")
        cam.to_json(cam_files[-1])
        true_masks.append(masks)
        all_frames.append(frames)
    Trajectory(robot, truth).to_csv(d / "truth.csv")
    return {"robot": robot, "truth": truth, "cams": cams, "videos": [str(v) for v in videos],
            "cam_files": [str(c) for c in cam_files], "masks": true_masks, "frames": all_frames, "dir": d}


@pytest.fixture(scope="module")
def clip16():
    """A 16-frame clip of the lower body walking, seen by the default camera: (camera, video)."""
    robot = load(str(LOWER), root="free")
    cam = Camera.default()
    return cam, walking_video(robot, cam, frames=16, seed=2)


def _write_clip(folder, frames, cam) -> list[str]:
    """``frames`` as ``folder``/fNN.png and ``cam`` as cam.json beside it; the `track`
    arguments that read them (without ``-o``)."""
    folder.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i:02d}.png"), f)
    cam_file = folder.parent / "cam.json"
    cam.to_json(cam_file)
    return ["track", str(LOWER), "--video", str(folder), "--camera", str(cam_file), "--no-progress", "--no-video"]


def _args(scene, videos=None, cams=None):
    out = []
    for v in videos or scene["videos"]:
        out += ["--video", str(v)]
    for c in cams or scene["cam_files"]:
        out += ["--camera", str(c)]
    return out


def _pose_json(scene, path, q=None):
    robot = scene["robot"]
    q = scene["truth"][0] if q is None else q
    m = robot.model
    joints = {m.names[j]: float(np.degrees(q[m.joints[j].idx_q])) for j in range(1, m.njoints) if m.joints[j].nq == 1}
    path.write_text(json.dumps({"joints": joints, "root": {"position": q[:3].tolist(), "quaternion_xyzw": q[3:7].tolist()}}))
    return path


@pytest.mark.slow
def test_track_two_videos_without_init(scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["track", str(LOWER), *_args(scene), "--no-progress", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "initial pose from frame 0" in err
    for name in ("trajectory.csv", "poses.npz", "overlay.mp4", "model.kms", "meta.json", "joint_angles.png"):
        assert (out / name).is_file(), name
    for c in (0, 1):
        assert len(list((out / "masks" / f"cam{c}").glob("frame_*.png"))) == N
    png = (out / "joint_angles.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imread(str(out / "joint_angles.png"))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    robot = scene["robot"]
    rep = evaluate(robot, Trajectory.from_csv(robot, out / "trajectory.csv"), Trajectory(robot, scene["truth"]))
    with capsys.disabled():
        print(f"\ntrack --video (2 cameras, {N} frames, no --init): centre error "
              f"{rep['mean_centre_error_pct']:.2f} % of height (worst {rep['worst_frame_error_pct']:.2f}), "
              f"revolute RMSE {rep['revolute_rmse_deg']:.2f} deg")
    assert rep["frames"] == N
    assert rep["mean_centre_error_pct"] < 3.0
    assert rep["revolute_rmse_deg"] < 7.5
    # `kms2pin evaluate` reads the same output
    capsys.readouterr()
    assert main(["evaluate", str(out), str(scene["dir"] / "truth.csv"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == N


def test_initial_pose_alone(scene, capsys):
    robot, truth = scene["robot"], scene["truth"]
    masks = [m[0] for m in scene["masks"]]
    res = initial_pose_details(robot, scene["cams"], masks)
    rep = evaluate(robot, Trajectory(robot, res.q[None]), Trajectory(robot, truth[:1]))
    with capsys.disabled():
        print(f"\ninitial_pose: centre error {rep['mean_centre_error_pct']:.2f} % of height, "
              f"fit {res.fit:.3f}, yaw {res.yaw_deg:.0f} deg")
    assert rep["mean_centre_error_pct"] < 5.0
    assert res.fit > 0.8
    assert len(res.coarse) == 12 * 3


def test_initial_pose_off_centre_and_turned(scene):
    """Root moved sideways, away and turned by 120°: placement and the yaw search find it."""
    robot = scene["robot"]
    q = robot.q_rest.copy()
    T = pin.XYZQUATToSE3(q[:7])
    q[:7] = pin.SE3ToXYZQUAT(pin.SE3(pin.exp3(np.array([0, np.radians(120), 0])) @ T.rotation,
                                     T.translation + [1.0, 0.0, 1.5]))
    from kms2pin.ecm.synth import render

    masks = render(robot, q, scene["cams"])
    res = initial_pose_details(robot, scene["cams"], masks, refine_steps=2)
    rep = evaluate(robot, Trajectory(robot, res.q[None]), Trajectory(robot, q[None]))
    assert rep["mean_centre_error_pct"] < 5.0, rep["mean_centre_error_pct"]


def test_size_mismatch_names_video_and_camera(scene, tmp_path, capsys):
    small = tmp_path / "small.json"
    Camera.default(160, 120).to_json(small)
    code = main(["track", str(LOWER), *_args(scene, cams=[scene["cam_files"][0], small]), "--no-progress",
                 "-o", str(tmp_path / "o")])
    assert code == 1
    err = capsys.readouterr().err
    assert scene["videos"][1] in err and str(small) in err and "320x240" in err and "160x120" in err


def test_pose_json(scene, tmp_path):
    robot = scene["robot"]
    truth0 = scene["truth"][0]
    turned = truth0.copy()  # the walk's root is not turned: also a turned one, so the rotation counts
    turned[:7] = pin.SE3ToXYZQUAT(pin.SE3(pin.exp3(np.array([0.3, 2.0, -0.5])), truth0[:3] + [0.2, -0.1, 0.4]))
    for k, truth in enumerate((truth0, turned)):
        q = read_pose_json(robot, _pose_json(scene, tmp_path / f"p{k}.json", truth))
        np.testing.assert_allclose(q[7:], truth[7:], atol=1e-9)
        # the root pose, not its quaternion: q[3:7] and -q[3:7] are the same rotation
        np.testing.assert_allclose(pin.XYZQUATToSE3(q[:7]).homogeneous, pin.XYZQUATToSE3(truth[:7]).homogeneous,
                                   atol=1e-9)
    R = pin.XYZQUATToSE3(turned[:7]).rotation
    (tmp_path / "r.json").write_text(json.dumps({"root": {"position": [0, 1, 9], "rotation": R.tolist()}}))
    q2 = read_pose_json(robot, tmp_path / "r.json")
    assert np.allclose(q2[:3], [0, 1, 9]) and np.allclose(pin.XYZQUATToSE3(q2[:7]).rotation, R)
    assert np.allclose(q2[7:], robot.q_rest[7:])
    for bad, msg in (({"joints": {"leftKnee": 3}}, "no joint coordinate 'leftKnee'"),
                     ({"root": {"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}}, "not a rotation"),
                     ({"joints": {"leftShin_knee": "x"}}, "must be a number"),
                     ({"pose": 1}, "unknown key")):
        (tmp_path / "b.json").write_text(json.dumps(bad))
        with pytest.raises(InputDataError, match=msg):
            read_pose_json(robot, tmp_path / "b.json")


@pytest.mark.slow
def test_videos_of_different_lengths_and_json_init(scene, tmp_path, capsys):
    """Videos of different lengths stop at the shortest; --init pose.json skips the search."""
    videos = []
    for k, n in enumerate((N - 4, N)):
        videos.append(tmp_path / f"v{k}.avi")
        write_video(videos[-1], scene["frames"][k][:n])
    out = tmp_path / "o"
    code = main(["track", str(LOWER), *_args(scene, videos=videos), "--init", str(_pose_json(scene, tmp_path / "p.json")),
                 "--no-progress", "--no-video", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "stopping at the shortest" in err and str(videos[0]) in err and f"frames 0-{N - 5}" in err
    assert "initial pose from frame" not in err
    rows = (out / "trajectory.csv").read_text().splitlines()
    assert len(rows) == N - 4 + 1
    robot = scene["robot"]
    rep = evaluate(robot, Trajectory.from_csv(robot, out / "trajectory.csv"), Trajectory(robot, scene["truth"]))
    assert rep["mean_centre_error_pct"] < 3.0


def test_truncated_video_tracks_what_it_can(scene, tmp_path, capsys):
    data = open(scene["videos"][0], "rb").read()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 4])
    code = main(["track", str(LOWER), *_args(scene, videos=[cut], cams=[scene["cam_files"][0]]),
                 "--init", str(_pose_json(scene, tmp_path / "p.json")), "--no-progress", "--no-video",
                 "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 0, err
    rows = (tmp_path / "o" / "trajectory.csv").read_text().splitlines()
    assert 1 < len(rows) - 1 < N
    assert f"stopped at frame {len(rows) - 1}" in err and str(cut) in err


def test_no_shadows_reaches_the_segmentation(tmp_path, capsys):
    """A light grey trunk before a white wall is a "shadow" unless --no-shadows; the
    masks `track --video --no-shadows` saves keep it."""
    robot = load(str(LOWER), root="free")
    cam = Camera.default()
    frames, _, light, q = pale_walk(robot, cam, frames=16, stride=15)
    video = tmp_path / "frames"
    video.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(video / f"f{i:02d}.png"), f)
    cam.to_json(tmp_path / "cam.json")
    Trajectory(robot, q[:1]).to_csv(tmp_path / "start.csv")
    out = tmp_path / "o"
    code = main(["track", str(LOWER), "--video", str(video), "--camera", str(tmp_path / "cam.json"), "--no-shadows",
                 "--init", str(tmp_path / "start.csv"), "--no-progress", "--no-video", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["shadow_detection"] is False
    opts = meta["options"]
    assert opts["sizes"]["calibrate_sizes"] and opts["sizes"]["size_every"] == 5  # --init POSE: measured, then refined
    assert opts["limbs"]["limb_search"] and opts["limbs"]["limb_search_drop"] == 0.03  # segmented masks: a noisy fit
    masks = read_masks(out / "masks" / "cam0", len(frames))
    assert min((m & t).sum() / t.sum() for m, t in zip(masks, light)) >= 0.98


def test_shadow_threshold_reaches_the_segmentation(clip16, tmp_path, capsys):
    """`track --video --shadow-threshold 0.3`: a cast shadow at 0.4 of the floor's
    brightness is not in the masks it saves; a threshold outside (0, 1) is refused
    before anything is written."""
    cam, v = clip16
    frames, shadows = cast_shadow(v.frames, v.masks, 0.4)
    args = _write_clip(tmp_path / "frames", frames, cam)
    bad = tmp_path / "bad"
    with pytest.raises(SystemExit) as exc:
        main([*args, "--shadow-threshold", "1", "-o", str(bad)])
    assert exc.value.code == 2
    assert "argument --shadow-threshold: expected a number in (0, 1)" in capsys.readouterr().err
    assert not (bad / "trajectory.csv").exists()
    out = tmp_path / "o"
    assert main([*args, "--shadow-threshold", "0.3", "-o", str(out)]) == 0, capsys.readouterr().err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["shadow_threshold"] == 0.3 and meta["gain_compensation"] is True
    masks = read_masks(out / "masks" / "cam0", len(v.frames))
    # the shadow is not in the masks (16 frames are too few for the rest of the masks to be good)
    assert sum(int((m & s).sum()) for m, s in zip(masks, shadows)) < 0.02 * sum(int(s.sum()) for s in shadows)


def test_gain_compensation_reaches_the_segmentation(clip16, tmp_path, capsys):
    """`track --video` divides out an exposure step (the whole image 25 % brighter from
    frame 8 on, as a camera's automatic exposure does) and `--no-gain-compensation`
    does not: the masks it saves then hold most of the background."""
    cam, v = clip16
    stepped = [np.clip(f * (1.25 if i >= 8 else 1.0), 0, 255).astype(np.uint8) for i, f in enumerate(v.frames)]
    args = _write_clip(tmp_path / "frames", stepped, cam)
    false = {}
    for extra in ([], ["--no-gain-compensation"]):
        out = tmp_path / f"o{len(extra)}"
        assert main([*args, *extra, "-o", str(out)]) == 0, capsys.readouterr().err
        assert json.loads((out / "meta.json").read_text())["gain_compensation"] == (not extra)
        masks = read_masks(out / "masks" / "cam0", len(v.frames))
        false[bool(extra)] = max((m & ~t).sum() / t.sum() for m, t in zip(masks[8:], v.masks[8:]))
    assert false[False] < 0.25 < 5.0 < false[True], false  # false pixels in units of the true area


def test_video_needs_cameras_and_exclusive_with_masks(scene, tmp_path, capsys):
    assert main(["track", str(LOWER), "--video", scene["videos"][0], "--no-progress", "-o", str(tmp_path / "o")]) == 1
    assert "--camera" in capsys.readouterr().err
    code = main(["track", str(LOWER), *_args(scene), "--camera", scene["cam_files"][0], "--no-progress",
                 "-o", str(tmp_path / "o")])
    assert code == 1
    assert "2 video(s) but 3 camera(s)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["track", str(LOWER), "--video", "a.avi", "--masks", "m", "-o", str(tmp_path / "o")])
    assert e.value.code == 2


@pytest.mark.slow
def test_one_camera_video_waits_for_the_running_fit_before_searching_or_switching(tmp_path, capsys):
    """`track --video` with one camera, automatic initialization, no priors: the full
    body's diagonal walk (``benchmarks/video.py``'s clip 0).  The running fit is mostly
    frame 0's for the first five frames; the search on a falling fit fired there (frame
    3, the trunk's limbs put back at rest) and the mirror hypothesis took over on frame
    3 (23 % of the height off).  Now neither happens before frame 5."""
    robot = load(str(LOWER.parent / "fullbody.kms"), root="free")
    cam = Camera.default()
    truth = diagonal_walk(robot, 60, stride=2)
    write_video(tmp_path / "cam0.avi", walking_video(robot, cam, seed=0, q=truth).frames)
    cam.to_json(tmp_path / "cam0.json")
    out = tmp_path / "o"
    code = main(["track", str(LOWER.parent / "fullbody.kms"), "--video", str(tmp_path / "cam0.avi"), "--camera",
                 str(tmp_path / "cam0.json"), "--no-progress", "--no-video", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    with open(out / "trajectory.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    early = ";".join(r["flags"] for r in rows[:5])  # twins' exchange after a crossing does not wait
    assert not any(w in early for w in ("switched to", "the other way", "back at rest")), early
    rep = evaluate(robot, Trajectory.from_csv(robot, out / "trajectory.csv"), Trajectory(robot, truth))
    assert rep["mean_centre_error_pct"] < 3.0 and rep["worst_frame_error_pct"] < 10.0


def test_a_shorter_video_into_the_same_folder_leaves_only_its_own_masks(clip16, tmp_path, capsys):
    cam, v = clip16
    out = tmp_path / "o"
    for args in (_write_clip(tmp_path / "long", v.frames, cam), _write_clip(tmp_path / "short", v.frames[:12], cam)):
        assert main([*args, "-o", str(out)]) == 0, capsys.readouterr().err
    # frames 12-15's masks, trajectory.csv, poses.npz, animation.html, joint_angles.png and motion.bvh
    assert f"note: {out}: removed 9 file(s) of an earlier run" in capsys.readouterr().err
    assert sorted(p.name for p in (out / "masks" / "cam0").iterdir()) == [f"frame_{k:05d}.png" for k in range(12)]
    assert len((out / "trajectory.csv").read_text().splitlines()) == 1 + 12


def test_a_video_tracked_both_ways_and_smoothed(tmp_path, clip16):
    """``--video`` with ``--both-ways --smooth 6``: the backward pass reads the masks the
    segmentation saved; both_ways.csv and smoothed.csv number the video's 16 frames."""
    cam, video = clip16
    out = tmp_path / "out"
    assert main([*_write_clip(tmp_path / "clip", video.frames, cam), "--both-ways", "--smooth", "6",
                 "-o", str(out)]) == 0
    for name in ("trajectory.csv", "both_ways.csv", "smoothed.csv"):
        rows = (out / name).read_text().splitlines()
        assert [r.split(",")[0] for r in rows[1:]] == [str(k) for k in range(16)], name
    meta = json.loads((out / "meta.json").read_text())
    assert meta["both_ways"] is True and meta["smooth_hz"] == 6.0 and meta["complete"] is True


@pytest.mark.slow
def test_tracks_beside_in_processes_from_videos_write_what_one_process_writes(scene, tmp_path, capsys):
    """``--video`` with tracks beside in two processes (``--jobs 2``; the decoders run in
    children of their own): the outputs of one process, byte for byte, and every child ended."""
    written = []
    for jobs in ("1", "2"):
        out = tmp_path / f"out{jobs}"
        assert main(["track", str(LOWER), *_args(scene), "--second-track", "max_iterations=4", "--jobs", jobs,
                     "--no-progress", "--no-video", "-o", str(out)]) == 0
        assert json.loads((out / "meta.json").read_text())["jobs"] == int(jobs)
        written.append([(out / f).read_bytes() for f in ("trajectory.csv", "poses.npz")])
    assert written[0] == written[1]
    import multiprocessing

    assert not multiprocessing.active_children()
