"""Track a model through silhouette masks with the ECM algorithm (thesis §2.1.2).

Reads DIR/camK/frame_NNNNN.png (or DIR/frame_*.png / DIR/*.png for one camera)
and the cameras from --camera files or DIR/cameras.json; or, with --video
(once per camera, synchronized, with one --camera each), segments the videos
into masks (saved under OUT/masks/camK/), finds the first frame's pose itself
(placement, coarse root-rotation search, ECM refinement; or --init) and also
writes OUT/joint_angles.png.  Writes to OUT:
trajectory.csv (joint angles in degrees, one row per frame, appended as it
goes), poses.npz (body poses; also written on interruption), overlay.mp4
(projected inner/outer ellipses over the masks), animation.html (if the viewer
is available), motion.bvh (the trajectory on the model's skeleton, docs/bvh.md; unless
the model cannot be written as BVH), model.kms, meta.json and cameras.json (for
`kms2pin evaluate`).  With --both-ways the frames are also tracked backwards from the
last pose and both_ways.csv keeps the better-fitting stretches of the two tracks, changing
track where they agree, and each frame's better-fitting parts of the two (every joint with
the joints below it: hips, knees, spine, collars, shoulders, elbows, ...), then of the
frames beside it (kms2pin.ecm.bothways); with --beside alone, beside.csv takes the frames
beside on the forward track, without the backward pass; with --stretches and tracks
beside (--second-track), stretches.csv keeps each stretch of frames from the track that
fits it best, changing track where the tracks agree, then each part from the other tracks
and from the frames beside (kms2pin.ecm.stretches); with --temporal, temporal.csv
is the finished track (the last of those) refit frame by frame by ECM with a spring
towards the frames beside it, over several sweeps (kms2pin.ecm.temporal), and
temporal.npz the same poses with the body sizes the refit measured;
with --smooth HZ smoothed.csv is the finished track low-pass filtered
(kms2pin.ecm.smoothing).  motion.bvh and animation.html show the last of these
(animation.html with the body sizes its poses were fit at); after an offline pass
overlay.mp4 is drawn again at that pass's poses and sizes (not smoothed).

A frame whose masks are all empty (the subject has left every image) keeps the
last pose and is flagged "empty mask" in trajectory.csv; with the automatic
initialization the subject is searched for again once it is back
(:mod:`kms2pin.ecm.reacquisition`, flag "reinitialized").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..bvh import to_bvh
from ..ecm.camera import Camera
from ..ecm.options import SEGMENTED_MASKS, track_changes
from ..ecm.stretches import track_poses
from ..ecm.tracker import Tracker, Trajectory, TrajectoryCsvWriter
from ..ecm.trajectory import POOR_FIT
from ..ecm.workers import usable_cores
from ..errors import BvhError, InputDataError, Kms2pinError, OutputError, UsageError
from ..robot import Robot
from ..video.io import check_masks, find_mask_frames, read_mask, remove_masks_from, write_mask
from ..video.segmentation import DEFAULT_METHOD, METHODS
from ._common import (
    Once,
    add_spec_argument,
    existing_file,
    lighting_notes,
    positive,
    positive_count,
    read_model,
)
from ._offline import add_offline_arguments, offline_meta, offline_notes, offline_passes, run_offline
from ._outputs import interrupts_deferred, owns_output, replaced, write_files_atomically
from ._tracking import add_tracker_arguments, tracker_options
from .segment import add_lighting_arguments

NAME = "track"
HELP = ("track a model through silhouette masks (ECM); writes trajectory.csv, poses.npz, overlay.mp4, animation.html, "
        "motion.bvh")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--masks", action=Once, metavar="DIR", help="mask folder (camK/ sub-folders or PNGs)")
    src.add_argument("--video", action="append", metavar="VIDEO",
                     help="video file or image folder, once per camera (synchronized); segmented into masks")
    p.add_argument("--camera", action="append", metavar="CAM.json",
                   help="camera file, once per camera in order (default: DIR/cameras.json)")
    p.add_argument("--root", choices=("spec", "free"), default="free", help="root joint (default: free)")
    p.add_argument("--init", action=Once, metavar="POSE",
                   help="initial pose: POSE.csv (first row of a trajectory CSV), POSE.json "
                        '({"joints": {name: degrees}, "root": {"position": [...], "rotation": 3x3 | '
                        '"quaternion_xyzw": [...]}}) or "auto" (found from the first frame; the default with '
                        "--video; with --masks the default is the rest pose)")
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help="segmentation of --video (default mog2)")
    add_lighting_arguments(p, prefix="segmentation of --video: ")
    p.add_argument("--system", help="rigidBodySystem to use (if the spec has several)")
    p.add_argument("--fps", type=positive, default=30.0, help="frame rate of overlay and animation (default 30)")
    p.add_argument("--no-video", action="store_true", help="skip overlay.mp4")
    add_offline_arguments(p)
    p.add_argument("--smooth", type=positive, metavar="HZ",
                   help="also write smoothed.csv, the track low-pass filtered at HZ forwards and backwards, "
                        "joint by joint (6 is usual for walking at 30 frames/s; below half of --fps), and "
                        "make motion.bvh and animation.html of it")
    add_tracker_arguments(p)
    p.add_argument("--jobs", type=positive_count, metavar="N",
                   help="with tracks beside (--second-track), the processes that track at once: each track in one "
                        "of N, the same results (default: one per track, at most one per core this process may use; "
                        "1: every track in this process); with --temporal, the processes that refit its frames "
                        "(default: one per core this process may use)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("-o", "--output", action=Once, required=True, metavar="OUT", help="output folder")


def _load_cameras(paths: list[str]) -> tuple[list[Camera], list[str]]:
    """The cameras of ``--camera`` files, in order (a file may hold one camera or a list,
    as ``synth`` and ``camera`` write them), and a name for each in messages."""
    cameras: list[Camera] = []
    names: list[str] = []
    for path in paths:
        existing_file(path)  # a usage error, as for the spec and the videos
        cams = Camera.list_from_json(path)
        cameras += cams
        names += [path] if len(cams) == 1 else [f"{path}[{i}]" for i in range(len(cams))]
    return cameras, names


_OUTPUTS = ("trajectory.csv", "poses.npz", "overlay.mp4", "animation.html", "joint_angles.png", "motion.bvh",
            "smoothed.csv", "both_ways.csv", "beside.csv", "stretches.csv", "temporal.csv", "temporal.npz")
OVERLAY_TMP = ".overlay.tmp.mp4"


def _remove_earlier_outputs(out: Path, cameras: int, frames: int | None = None) -> int:
    """Delete what an earlier run left in ``out`` that this one writes or would not
    overwrite (so that the folder never mixes two runs' files); returns how many files.
    ``frames``: with --video, the masks this run writes to OUT/masks/camK."""
    found = [name for name in _OUTPUTS if (out / name).is_file()]
    masks = frames is not None and any((out / "masks").glob("cam*/frame_*.png"))
    if (found or masks) and not _earlier_track(out):
        what = ", ".join(found + ["masks/cam*/frame_*.png"] * masks)
        raise OutputError(
            f"{out}: holds {what} but no meta.json of a kms2pin track run, so they are not an earlier "
            "run's outputs and track will not replace them; choose an empty or new output folder (or move them)")
    removed = 0
    for name in found:
        (out / name).unlink()
        removed += 1
    if frames is not None:
        for d in sorted((out / "masks").glob("cam*")):
            k = d.name[3:]
            removed += remove_masks_from(d, frames if k.isdigit() and int(k) < cameras else 0)
    return removed


def _earlier_track(out: Path) -> bool:
    """Whether ``out`` holds the meta.json a ``kms2pin track`` run writes first (its options
    and its ``complete`` flag): what else is in it is that run's."""
    try:
        meta = json.loads((out / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and {"options", "complete", "cameras"} <= meta.keys()


@dataclass
class _Frames:
    """The input frames: cameras, frame numbers, a loader per frame index, names for messages."""

    cameras: list[Camera]
    numbers: list[int]
    load: Callable[[int], list[np.ndarray]]
    names: list[str]
    masks_dir: Path
    removed: int = 0


def _video_frames(args, out: Path) -> _Frames:
    """Segment the videos into OUT/masks/camK (an earlier run's outputs removed first)."""
    if not args.camera:
        raise InputDataError("--video needs the cameras: give one --camera CAM.json per --video, in order")
    cameras, camera_names = _load_cameras(args.camera)
    for v in args.video:
        existing_file(v)
    from ..video.track_video import segment_videos

    per_cam, notes = segment_videos(args.video, cameras, camera_names, method=args.method,
                                    detect_shadows=not args.no_shadows, shadow_threshold=args.shadow_threshold,
                                    compensate_gain=not args.no_gain_compensation)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    numbers = list(range(len(per_cam[0])))
    masks_dir = out / "masks"
    removed = _remove_earlier_outputs(out, len(cameras), len(numbers))
    try:
        for c, ms in enumerate(per_cam):
            d = masks_dir / f"cam{c}"
            d.mkdir(parents=True, exist_ok=True)
            for k, m in enumerate(ms):
                write_mask(d, k, m)
    except OSError as err:
        raise Kms2pinError(f"cannot write to {masks_dir}: {err.strerror or err}") from None
    names = [", ".join(f"{v}" for v in args.video)] * len(numbers)
    return _Frames(cameras, numbers, lambda k: [pc[k] for pc in per_cam], names, masks_dir, removed)


def _mask_frames(args) -> _Frames:
    """The mask folder's frames, every mask's size checked against its camera first."""
    masks_dir = Path(args.masks)
    if not masks_dir.is_dir():
        raise FileNotFoundError(2, "no such folder", str(masks_dir))
    if args.camera:
        cameras = _load_cameras(args.camera)[0]
    elif (masks_dir / "cameras.json").is_file():
        cameras = Camera.list_from_json(masks_dir / "cameras.json")
    else:
        raise InputDataError(f"{masks_dir}: no cameras.json; give the cameras with --camera CAM.json")
    numbers, per_cam = find_mask_frames(masks_dir, len(cameras))
    unused = sorted((d.name for d in masks_dir.glob("cam*") if d.is_dir() and d.name[3:].isdigit()
                     and int(d.name[3:]) >= len(cameras)), key=lambda n: int(n[3:]))
    if unused:
        print(f"note: {masks_dir}: {', '.join(unused)} not tracked: the cameras give {len(cameras)} camera(s) "
              "(one per camK folder, in order)", file=sys.stderr)
    shapes, cam_names = [c.shape for c in cameras], [c.name or "" for c in cameras]
    check_masks(per_cam, numbers, shapes, cam_names)  # every mask decodes, before anything is written
    names = [", ".join(str(pc[f]) for pc in per_cam) for f in numbers]

    noted: set = set()  # the masks whose thresholding was noted: the first frames are read twice

    def load(k: int) -> list[np.ndarray]:
        f = numbers[k]
        return [read_mask(pc[f], f, s, n, noted) for pc, s, n in zip(per_cam, shapes, cam_names)]

    return _Frames(cameras, numbers, load, names, masks_dir)


def _initial_q(args, robot: Robot):
    """q0 from --init POSE.csv / POSE.json, or None (rest pose or "auto")."""
    if not args.init or args.init == "auto":
        return None
    existing_file(args.init)
    if args.init.lower().endswith(".json"):
        from ..video.posefile import read_pose_json

        return read_pose_json(robot, args.init)
    init = Trajectory.from_csv(robot, args.init)
    if len(init) == 0:
        raise InputDataError(f"{args.init}: no pose rows")
    return init.q[0]


def _first_non_empty(frames: _Frames) -> tuple[int, list[np.ndarray]]:
    """The first frame with a non-empty mask and its masks; InputDataError if there is none."""
    for k in range(len(frames.numbers)):
        masks = frames.load(k)
        if any(m.any() for m in masks):
            return k, masks
    raise InputDataError(f"{frames.masks_dir}: every mask is empty: nothing to track")


def _auto_init(robot: Robot, cameras, masks, frame: int) -> tuple[np.ndarray, float]:
    """Initial pose and its fit (IoU), found on ``masks`` (those of ``frame``)."""
    from ..ecm.initialization import initial_pose_details

    res = initial_pose_details(robot, cameras, masks)
    print(f"initial pose from frame {frame}: root yaw {res.yaw_deg:.0f} deg, pitch {res.pitch_deg:.0f} deg, "
          f"fit (IoU) {res.fit:.3f}", file=sys.stderr)
    if res.fit < 0.5:
        print(f"warning: the initial pose fits the first frame poorly (IoU {res.fit:.2f}); "
              "consider --init POSE.json", file=sys.stderr)
    return res.q, res.fit


def _notes(args, robot: Robot, n_cameras: int, auto: bool) -> None:
    """Notes on options that do nothing as given, and on one-camera tracking."""
    if robot.root != "free" and (args.upright or args.depth_prior or args.ground):
        print("note: --upright, --depth-prior and --ground act on a free root; with --root spec they do nothing",
              file=sys.stderr)
    if n_cameras == 1 and robot.root == "free" and not args.upright and not args.rest_prior and args.preset is None:
        # with joint limits the upright prior alone tracked the walk benchmark best; without
        # them it lost seeds that the rest prior keeps (docs/design/tracking-history.md)
        priors = "--upright 0.1 holds" if robot.has_limits else "--upright 0.1 --rest-prior 0.01 hold"
        print(f"note: one camera: for a person walking or standing, {priors} what one view does not fix "
              "(not for a hand; docs/tracking.md); for a real person, --preset people-one-camera", file=sys.stderr)
    offline_notes(args, n_cameras)
    if (args.calibrate_sizes is False or auto) and args.size_every is not None:
        why = "--no-size-calibration" if args.calibrate_sizes is False else "the automatic initialization (no --init POSE)"
        print(f"note: --size-every refines the measured sizes; with {why} none are measured, so it does nothing",
              file=sys.stderr)


def _write_start(out: Path, args, robot: Robot, tracker: Tracker, frames: _Frames) -> dict:
    """model.kms, cameras.json and meta.json (``complete`` false until the last frame)."""
    meta = {
        "model": "model.kms", "system": robot.system.name, "root": robot.root, "cameras": len(frames.cameras),
        "masks": str(frames.masks_dir), "first_frame": frames.numbers[0], "frames": len(frames.numbers),
        "options": dataclasses.asdict(tracker.options), "jobs": tracker.jobs,
        "complete": False,  # set once every frame is tracked (kms2pin evaluate warns otherwise)
    }
    if args.smooth is not None:
        meta |= {"smooth_hz": args.smooth, "fps": args.fps}
    meta |= offline_meta(args, robot, tracker)
    if args.video:
        meta |= {"videos": [str(v) for v in args.video], "segmentation": args.method,
                 "shadow_detection": not args.no_shadows, "shadow_threshold": args.shadow_threshold,
                 "gain_compensation": not args.no_gain_compensation}
    try:
        out.mkdir(parents=True, exist_ok=True)
        with replaced(out / "model.kms") as tmp:
            shutil.copyfile(args.spec, tmp)
        write_files_atomically({out / "meta.json": json.dumps(meta, indent=2) + "\n"})
        with replaced(out / "cameras.json") as tmp:
            Camera.list_to_json(frames.cameras, tmp)
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None
    return meta


def _track_frames(args, out: Path, robot: Robot, tracker: Tracker, frames: _Frames,
                  reacquire) -> tuple[list, Tracker, list]:
    """Track every frame, appending trajectory.csv rows and overlay frames as they
    finish; poses.npz is written also when interrupted.  Returns the results, the
    tracker of the last frame (a re-acquisition starts a new one) and, with --stretches,
    each frame's :func:`~kms2pin.ecm.stretches.track_poses`."""
    video, results, tracks = None, [], []
    iterator = range(len(frames.numbers))
    if not args.no_progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, unit="frame", desc="tracking")
    try:
        with TrajectoryCsvWriter(robot, out / "trajectory.csv") as csv_out:
            for k in iterator:
                frame, masks, names = frames.numbers[k], frames.load(k), frames.names[k]
                r = tracker.step(masks, source=f"{names}: frame {frame}")
                for what in ("empty mask", "mask nearly full"):
                    if what in r.flags:
                        kept = "the previous frame's pose kept" if k else "the initial pose kept"
                        print(f"note: frame {frame}: {what} ({names}); {kept}", file=sys.stderr)
                if reacquire is not None:
                    tracker, r, note = reacquire.update(tracker, r, masks, source=f"{names}: frame {frame}")
                    if note:
                        print(f"note: frame {frame}: {note}", file=sys.stderr)
                with interrupts_deferred():  # a frame is in every output or in none
                    csv_out.write(frame, r)
                    results.append(r)
                    if args.stretches:
                        tracks.append(track_poses(tracker))
                    if not args.no_video:
                        video = _overlay_frame(video, out, args.fps, robot, frames.cameras, masks, r.q,
                                               tracker.scales)
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (Terminated)
        print(f"interrupted after {len(results)} frame(s); outputs in {out} are complete up to there",
              file=sys.stderr)
        raise
    except Kms2pinError:
        done = f"up to frame {frames.numbers[len(results) - 1]}" if results else "empty (no frame tracked)"
        print(f"kms2pin track: stopped at frame {frames.numbers[len(results)]}; outputs in {out} are {done}",
              file=sys.stderr)
        raise
    finally:
        _finish_overlay(video, out)
        if results:
            with replaced(out / "poses.npz") as tmp:
                Trajectory(robot, np.array([r.q for r in results]), results, scales=tracker.scales).to_npz(tmp)
    return results, tracker, tracks


def _overlay_frame(video, out: Path, fps: float, robot, cameras, masks, q, scales):
    """Append one frame to the overlay video (opened on the first, under a temporary name
    that becomes OUT/overlay.mp4 once it is released)."""
    from ..viewer.overlay import overlay_image

    img = overlay_image(robot, cameras, masks, q, scales)
    if video is None:
        video = cv2.VideoWriter(str(out / OVERLAY_TMP), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                (img.shape[1], img.shape[0]))
    video.write(img)
    return video


def _rewrite_overlay(out: Path, fps: float, robot: Robot, frames: _Frames, qs: np.ndarray, scales: np.ndarray) -> None:
    """overlay.mp4 drawn again at the offline passes' poses ``qs`` and sizes ``scales``
    (the online track's, written while tracking, replaced once this one is complete)."""
    video = None
    try:
        for k, q in enumerate(qs):
            video = _overlay_frame(video, out, fps, robot, frames.cameras, frames.load(k), q, scales)
    except BaseException:
        if video is not None:
            video.release()
        (out / OVERLAY_TMP).unlink(missing_ok=True)  # the online track's overlay.mp4 stays
        raise
    _finish_overlay(video, out)


def _finish_overlay(video, out: Path) -> None:
    """Release the overlay video (if one was opened) and give it its name, OUT/overlay.mp4."""
    if video is not None:
        video.release()
        if (out / OVERLAY_TMP).exists():
            os.replace(out / OVERLAY_TMP, out / "overlay.mp4")


def _write_end(out: Path, args, robot: Robot, qs: np.ndarray, scales: np.ndarray, frames: _Frames,
               meta: dict) -> None:
    """smoothed.csv (``--smooth``), joint_angles.png (video), animation.html (its bodies at
    ``scales``, the sizes ``qs`` were fit at), motion.bvh (if the model can be written as
    BVH; the last two of ``qs``, smoothed with ``--smooth``), overlay.mp4 again after an
    offline pass (at the last pass's poses and sizes, not smoothed) and meta.json complete."""
    if not args.no_video and offline_passes(args):
        _rewrite_overlay(out, args.fps, robot, frames, qs, scales)
    if args.smooth is not None:  # checked against --fps before tracking (run)
        qs = Trajectory(robot, qs).smoothed(args.fps, args.smooth).q
        with replaced(out / "smoothed.csv") as tmp:
            Trajectory(robot, qs).to_csv(tmp, frames=frames.numbers[: len(qs)])
    if args.video:
        from ..video.track_video import plot_joint_angles

        try:
            with replaced(out / "joint_angles.png") as tmp:
                plot_joint_angles(robot, qs, tmp, frames=frames.numbers[: len(qs)])
        except Exception as err:  # noqa: BLE001 - the plot is a convenience
            print(f"note: joint_angles.png skipped ({err})", file=sys.stderr)
    try:
        from ..viewer import write_animation_html
    except Exception as err:  # noqa: BLE001 - the viewer is optional
        print(f"note: animation.html skipped (viewer unavailable: {err})", file=sys.stderr)
    else:
        try:
            with replaced(out / "animation.html") as tmp:
                write_animation_html(robot, qs, args.fps, tmp, scales=scales)
        except Exception as err:  # noqa: BLE001
            print(f"note: animation.html skipped ({err})", file=sys.stderr)
    try:
        text = to_bvh(robot, qs, args.fps)
    except BvhError as err:
        print(f"note: motion.bvh skipped ({err})", file=sys.stderr)
    else:
        try:
            with replaced(out / "motion.bvh") as tmp:
                tmp.write_text(text)
        except OSError as err:
            raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None
    meta["complete"] = True
    try:
        write_files_atomically({out / "meta.json": json.dumps(meta, indent=2) + "\n"})
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None


def _summary(out: Path, results: list, frames: _Frames, poor_fit: float, video: bool) -> None:
    fits = np.array([r.fit for r in results])
    poor = [frames.numbers[k] for k, r in enumerate(results) if any(f.startswith(POOR_FIT) for f in r.flags)]
    if poor:
        print(f"note: {len(poor)} frame(s) fit the masks poorly (IoU < {poor_fit:g}), the first at frame "
              f"{poor[0]}: the track is probably lost there (flag '{POOR_FIT}' in trajectory.csv)", file=sys.stderr)
        if video:
            print(f"note: if the masks in {frames.masks_dir} miss parts of the subject, the background model learnt "
                  "them (a subject that stands still while most of the video is taken); `kms2pin segment` with "
                  "--learn-frames / --learn-from, then track --masks, can do better", file=sys.stderr)
    print(f"{out}: {len(results)} frames tracked; mean fit (IoU) {fits.mean():.3f}, worst {fits.min():.3f} "
          f"(frame {frames.numbers[int(fits.argmin())]})")


@owns_output
def run(args: argparse.Namespace) -> int:
    video_mode = bool(args.video)
    auto = args.init == "auto" or (video_mode and not args.init)
    # body sizes are measured on the first frame only where its pose is known (the rest pose
    # or --init POSE): at a pose found by the search they would absorb its errors
    fixed = {"calibrate_sizes": False} if auto else {}
    if args.smooth is not None and not args.smooth < args.fps / 2:
        raise UsageError(f"--smooth {args.smooth:g}: the cutoff must be below half the frame rate "
                         f"(--fps {args.fps:g}: below {args.fps / 2:g} Hz)")
    options = tracker_options(args, SEGMENTED_MASKS if video_mode else None, **fixed)
    if args.stretches and not track_changes(options.hypotheses.second_track):
        raise UsageError("--stretches chooses among tracks beside the first, and there are none: give "
                         "--second-track NAME=VALUE,... (docs/tracking.md)")
    if args.stretches and args.both_ways:
        raise UsageError("--stretches with --both-ways: choose one (both ways would track every track "
                         "backwards too; docs/tracking.md)")
    spec = read_model(args.spec)
    robot = Robot(spec, spec.system(args.system), args.root)
    out = Path(args.output)
    for note in lighting_notes(args, segmenting=video_mode):
        print(f"note: {note}", file=sys.stderr)
    frames = _video_frames(args, out) if video_mode else _mask_frames(args)
    _notes(args, robot, len(frames.cameras), auto)
    q0 = _initial_q(args, robot)
    init_fit = None
    first, first_masks = _first_non_empty(frames)
    if auto:
        q0, init_fit = _auto_init(robot, frames.cameras, first_masks, first)
    if not video_mode:
        frames.removed = _remove_earlier_outputs(out, len(frames.cameras))
    if frames.removed:
        print(f"note: {out}: removed {frames.removed} file(s) of an earlier run", file=sys.stderr)
    tracks = 1 + len(track_changes(options.hypotheses.second_track))
    jobs = min(tracks, usable_cores()) if args.jobs is None else args.jobs
    with Tracker(robot, frames.cameras, options, q0=q0, jobs=jobs) as tracker:
        return _run_tracker(args, out, robot, options, tracker, frames, auto, init_fit, q0, video_mode)


def _run_tracker(args, out: Path, robot: Robot, options, tracker: Tracker, frames: _Frames, auto: bool, init_fit,
                 q0: np.ndarray, video_mode: bool) -> int:
    """:func:`run` from the tracker made: the frames tracked, the offline passes and the outputs."""
    meta = _write_start(out, args, robot, tracker, frames)
    reacquire = None
    if auto and robot.root == "free":
        from ..ecm.reacquisition import Reacquisition

        reacquire = Reacquisition(robot, frames.cameras, q0, reference_fit=init_fit)
    results, tracker, tracks = _track_frames(args, out, robot, tracker, frames, reacquire)
    tracker.close()  # the tracks beside's processes: the passes below do not step them
    qs, scales = run_offline(args, out, robot, options, tracker, frames, results, tracks)
    _write_end(out, args, robot, qs, scales, frames, meta)
    _summary(out, results, frames, tracker.options.silhouette.poor_fit, video_mode)
    return 0
