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
is available), model.kms, meta.json and cameras.json (for `kms2pin evaluate`).

A frame whose masks are all empty (the subject has left every image) keeps the
last pose and is flagged "empty mask" in trajectory.csv; with the automatic
initialization the subject is searched for again once it is back
(:mod:`kms2pin.video.reacquire`, flag "reinitialized").
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

from ..cli import UsageError
from ..ecm.camera import Camera
from ..ecm.projection import ProjectionError, ellipse_parameters, ellipsoid_conic
from ..ecm.tracker import SEGMENTED_MASKS, Tracker, Trajectory, TrajectoryCsvWriter
from ..errors import InputDataError, Kms2pinError
from ..robot import Robot
from ..video.io import decode_image, remove_masks_from, write_mask
from ..video.segmentation import DEFAULT_METHOD, METHODS
from ._common import Once, add_spec_argument, count, existing_file, lighting_notes, non_negative, positive, read_model
from ._outputs import interrupts_deferred, owns_output, replaced, write_files_atomically
from .segment import add_lighting_arguments

NAME = "track"
HELP = "track a model through silhouette masks (ECM); writes trajectory.csv, poses.npz, overlay.mp4, animation.html"

_NUM = re.compile(r"(\d+)(?=\.png$)", re.IGNORECASE)


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
    p.add_argument("--no-size-calibration", action="store_true",
                   help="keep the spec's body sizes (default: measure them on the first frame, whose "
                        "pose is taken to be the rest pose or --init POSE, and refine them as the "
                        "subject turns; not with --init auto)")
    p.add_argument("--size-every", type=count, default=None, metavar="N",
                   help="refine the measured body sizes on every N-th frame (default 5; 0: keep the first "
                        "frame's, e.g. when the masks have systematic errors, such as deep shadows, that the "
                        "sizes would take up)")
    p.add_argument("--no-mirror-hypothesis", action="store_true",
                   help="with one camera, do not also track the mirror image of the pose (it tells "
                        "which way a turn goes; one more ECM a frame)")
    p.add_argument("--no-swap-hypothesis", action="store_true",
                   help="with one camera and a model with joint limits, do not also track the pose with "
                        "left and right swapped (it tells the legs apart after a side-on view; one more "
                        "ECM a frame)")
    p.add_argument("--no-limb-search", action="store_true",
                   help="do not swing a limb the other way, or put it back at rest below its first joint, "
                        "when a frame's fit falls behind the running fit (an arm stuck on the wrong side of "
                        "the trunk, a finger folded the wrong way), nor, with one camera, try twin limbs "
                        "exchanged after they cross")
    p.add_argument("--limb-search-drop", type=non_negative, default=None, metavar="D",
                   help="run the limb search on a frame whose fit (IoU) falls more than D below the "
                        "running fit (default 0.015 with --masks, 0.03 with --video: on segmented masks "
                        "the fit is noisy, and 0.03 tracked as well at 1.5-2.5x the frames/s; use 0.03 "
                        "for --masks from 'kms2pin segment' too)")
    p.add_argument("--no-limb-hypothesis", action="store_true",
                   help="with one camera, do not track the limb search's best candidate beside the pose "
                        "when the fit falls a little (by 0.005; it becomes the pose once it fits better "
                        "over the frames that follow)")
    p.add_argument("--tol-px", type=non_negative, default=None, metavar="PX",
                   help="end a frame's iterations once no body's outline moves more than PX pixels "
                        "(default 0.25; 0: only once the joints stop moving: on the one-camera hand, "
                        "fifteen of twenty seeds ended within 1.5x of their start against twelve, at "
                        "0.77x the frames/s)")
    p.add_argument("--binned-hypotheses", action="store_true",
                   help="track the one-camera alternative hypotheses (mirror, swapped, limb search) on the masks binned 2x2 (about 1.3x "
                        "the frames/s with one camera, at some cost in accuracy)")
    p.add_argument("--depth-prior", type=non_negative, default=0.0, metavar="K",
                   help="a spring holding the root's distance along each camera's ray at each frame's "
                        "prediction, K times the root's stiffness (default 0: off; with one camera 0.02 "
                        "keeps a lost track from sliding towards the camera)")
    p.add_argument("--upright", type=non_negative, default=0.0, metavar="K",
                   help="a spring holding the root's tilt from the vertical (--up) at the first frame's, "
                        "K times the root's rotational stiffness; it turns freely about the vertical "
                        "(default 0: off; 0.1 for people walking, seen by one camera)")
    p.add_argument("--up", type=float, nargs=3, default=(0.0, 1.0, 0.0), metavar=("X", "Y", "Z"),
                   help="the world's vertical for --upright (default 0 1 0)")
    p.add_argument("--rest-prior", type=non_negative, default=0.0, metavar="K",
                   help="a spring pulling every joint angle towards the spec's rest pose, K times the "
                        "joints' mean stiffness (default 0: off; 0.01 for people walking, seen by one "
                        "camera: it holds the joints the images do not fix, e.g. a hidden arm's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("-o", "--output", action=Once, required=True, metavar="OUT", help="output folder")


def _up_vector(xyz) -> np.ndarray:
    up = np.asarray(xyz, dtype=float)
    if not (np.all(np.isfinite(up)) and np.linalg.norm(up) > 0.0):
        raise UsageError(f"--up: expected a finite, non-zero vector, got {' '.join(map(str, xyz))}")
    return up


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


_OUTPUTS = ("trajectory.csv", "poses.npz", "overlay.mp4", "animation.html", "joint_angles.png")
OVERLAY_TMP = ".overlay.tmp.mp4"


def _remove_earlier_outputs(out: Path, cameras: int, frames: int | None = None) -> int:
    """Delete what an earlier run left in ``out`` that this one writes or would not
    overwrite (so that the folder never mixes two runs' files); returns how many files.
    ``frames``: with --video, the masks this run writes to OUT/masks/camK."""
    removed = 0
    for name in _OUTPUTS:
        if (out / name).is_file():
            (out / name).unlink()
            removed += 1
    if frames is not None:
        for d in sorted((out / "masks").glob("cam*")):
            k = d.name[3:]
            removed += remove_masks_from(d, frames if k.isdigit() and int(k) < cameras else 0)
    return removed


_PNG = b"\x89PNG\r\n\x1a\n"


def check_masks(per_cam: list[dict[int, Path]], numbers: list[int], cameras: list[Camera]) -> None:
    """Before anything is written: every mask's size against its camera, from its PNG
    header (a file that is not a PNG is decoded instead)."""
    for pc, cam in zip(per_cam, cameras):
        for f in numbers:
            path = pc[f]
            try:
                with open(path, "rb") as fh:
                    head = fh.read(24)
            except OSError as err:
                raise InputDataError(f"{path}: frame {f}: cannot read: {err.strerror or err}") from None
            if head[:8] == _PNG and head[12:16] == b"IHDR":
                w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
                if (h, w) != cam.shape:
                    raise _size_error(path, f, w, h, cam)
            else:
                read_mask(path, f, cam)


def _frames_in(folder: Path) -> dict[int, Path]:
    frames: dict[int, Path] = {}
    for path in sorted(folder.glob("*.png")) + sorted(folder.glob("*.PNG")):
        if not path.is_file():  # a FIFO would block the header check, a device never end
            raise InputDataError(f"{path}: not a regular file")
        m = _NUM.search(path.name)
        if m is None:
            raise InputDataError(f"{path}: cannot tell the frame number from the name (expected frame_NNNNN.png)")
        k = int(m.group(1))
        if k in frames and frames[k] != path:
            raise InputDataError(f"{path}: frame {k} appears twice (also {frames[k].name})")
        frames[k] = path
    return frames


def find_frames(masks: Path, n_cameras: int) -> tuple[list[int], list[dict[int, Path]]]:
    """Frame numbers and, per camera, frame -> file; errors name gaps and missing files."""
    if not masks.exists():
        raise FileNotFoundError(2, "no such folder", str(masks))
    if not masks.is_dir():
        raise InputDataError(f"{masks}: --masks must be a folder")
    cam_dirs = [masks / f"cam{c}" for c in range(n_cameras)]
    if all(d.is_dir() for d in cam_dirs):
        per_cam = [_frames_in(d) for d in cam_dirs]
    elif n_cameras == 1:
        per_cam = [_frames_in(masks)]
    else:
        missing = [str(d) for d in cam_dirs if not d.is_dir()]
        raise InputDataError(f"{masks}: {n_cameras} cameras but no mask folder {', '.join(missing)}")
    where = cam_dirs if len(per_cam) > 1 or cam_dirs[0].is_dir() else [masks]
    for d, frames in zip(where, per_cam):
        if not frames:
            raise InputDataError(f"{d}: no PNG masks found")
    numbers = sorted(per_cam[0])
    for d, frames in zip(where, per_cam):
        nums = sorted(frames)
        gaps = sorted(set(range(nums[0], nums[-1] + 1)) - set(nums))
        if gaps:
            shown = ", ".join(map(str, gaps[:10])) + (" ..." if len(gaps) > 10 else "")
            raise InputDataError(f"{d}: missing frame(s) {shown} (frames {nums[0]}..{nums[-1]})")
        if nums != numbers:
            other = sorted(set(nums) ^ set(numbers))
            raise InputDataError(f"{d}: frames differ from {where[0]}: frame(s) {', '.join(map(str, other[:10]))}")
    return numbers, per_cam


def _size_error(path: Path, frame: int, width: int, height: int, camera: Camera) -> InputDataError:
    name = f" {camera.name}" if camera.name else ""
    return InputDataError(f"{path}: frame {frame}: mask is {width}x{height} but camera{name} is "
                          f"{camera.width}x{camera.height}")


def read_mask(path: Path, frame: int, camera: Camera) -> np.ndarray:
    img = decode_image(path, where=f"{path}: frame {frame}")  # refuses over 8192 pixels a side before decoding
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.shape != camera.shape:
        raise _size_error(path, frame, img.shape[1], img.shape[0], camera)
    scale = 255 if img.dtype == np.uint8 else np.iinfo(img.dtype).max if img.dtype.kind in "ui" else 1
    vals = np.unique(img)
    if not np.all(np.isin(vals, (0, scale))) and not np.all(np.isin(vals, (0, 1))):
        print(f"note: {path}: frame {frame}: not a binary mask; thresholded at 127", file=sys.stderr)
        return img > 127 * scale / 255
    return img > 0


def _overlay(robot: Robot, cameras, masks, q, scales=None) -> np.ndarray:
    """The masks with the projected outer (orange) and inner (green) ellipses at ``q``,
    the body sizes times ``scales`` (the tracker's calibrated sizes)."""
    poses = robot.body_poses(q)
    scales = np.ones((len(robot.bodies), 3)) if scales is None else scales
    tiles = []
    for cam, m in zip(cameras, masks):
        img = cv2.cvtColor(m.astype(np.uint8) * 160, cv2.COLOR_GRAY2BGR)
        for P, b, f in zip(poses, robot.bodies, scales):
            for axes, colour in ((robot.outer(b) * f, (0, 200, 255)), (robot.inner(b) * f, (0, 255, 0))):
                try:
                    e = ellipse_parameters(ellipsoid_conic(cam, P, axes))
                except (ProjectionError, np.linalg.LinAlgError):
                    continue
                if not np.all(np.isfinite(e.centre)) or np.max(e.semi_axes) > 1e4:
                    continue
                cv2.ellipse(img, (tuple(map(float, e.centre)), tuple(map(float, 2 * e.semi_axes)), e.angle_deg),
                            colour, 1, cv2.LINE_AA)
        tiles.append(img)
    h = max(t.shape[0] for t in tiles)
    tiles = [cv2.copyMakeBorder(t, 0, h - t.shape[0], 0, 0, cv2.BORDER_CONSTANT) for t in tiles]
    return np.hstack(tiles)


def _initial_q(args, robot: Robot):
    """q0 from --init POSE.csv / POSE.json, or None (rest pose or "auto")."""
    if not args.init or args.init == "auto":
        return None
    existing_file(args.init)
    if args.init.lower().endswith(".json"):
        from ..video.init import read_pose_json

        return read_pose_json(robot, args.init)
    init = Trajectory.from_csv(robot, args.init)
    if len(init) == 0:
        raise InputDataError(f"{args.init}: no pose rows")
    return init.q[0]


def _first_non_empty(load, frames: int, masks_dir: Path) -> tuple[int, list[np.ndarray]]:
    """The first frame with a non-empty mask and its masks; InputDataError if there is none."""
    for k in range(frames):
        masks = load(k)
        if any(m.any() for m in masks):
            return k, masks
    raise InputDataError(f"{masks_dir}: every mask is empty: nothing to track")


def _auto_init(robot: Robot, cameras, masks, frame: int) -> tuple[np.ndarray, float]:
    """Initial pose and its fit (IoU), found on ``masks`` (those of ``frame``)."""
    from ..video.init import initial_pose_details

    res = initial_pose_details(robot, cameras, masks)
    print(f"initial pose from frame {frame}: root yaw {res.yaw_deg:.0f} deg, pitch {res.pitch_deg:.0f} deg, "
          f"fit (IoU) {res.fit:.3f}", file=sys.stderr)
    if res.fit < 0.5:
        print(f"warning: the initial pose fits the first frame poorly (IoU {res.fit:.2f}); "
              "consider --init POSE.json", file=sys.stderr)
    return res.q, res.fit


@owns_output
def run(args: argparse.Namespace) -> int:
    up = _up_vector(args.up)
    spec = read_model(args.spec)
    robot = Robot(spec, spec.system(args.system), args.root)
    if robot.root != "free" and (args.upright > 0 or args.depth_prior > 0):
        print("note: --upright and --depth-prior act on a free root; with --root spec they do nothing",
              file=sys.stderr)
    out = Path(args.output)
    video_mode = bool(args.video)
    for note in lighting_notes(args, segmenting=video_mode):
        print(f"note: {note}", file=sys.stderr)
    if video_mode:
        if not args.camera:
            raise InputDataError("--video needs the cameras: give one --camera CAM.json per --video, in order")
        cameras, camera_names = _load_cameras(args.camera)
        for v in args.video:
            existing_file(v)
        from ..video.track_video import segment_videos

        per_cam_masks, notes = segment_videos(args.video, cameras, camera_names, method=args.method,
                                              detect_shadows=not args.no_shadows,
                                              shadow_threshold=args.shadow_threshold,
                                              compensate_gain=not args.no_gain_compensation)
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
        numbers = list(range(len(per_cam_masks[0])))
        masks_dir = out / "masks"
        removed = _remove_earlier_outputs(out, len(cameras), len(numbers))
        try:
            for c, ms in enumerate(per_cam_masks):
                d = masks_dir / f"cam{c}"
                d.mkdir(parents=True, exist_ok=True)
                for k, m in enumerate(ms):
                    write_mask(d, k, m)
        except OSError as err:
            raise Kms2pinError(f"cannot write to {masks_dir}: {err.strerror or err}") from None
        frame_names = [", ".join(f"{v}" for v in args.video)] * len(numbers)

        def load(k: int, _pc=per_cam_masks):
            return [pc[k] for pc in _pc]
    else:
        masks_dir = Path(args.masks)
        if not masks_dir.is_dir():
            raise FileNotFoundError(2, "no such folder", str(masks_dir))
        if args.camera:
            cameras = _load_cameras(args.camera)[0]
        elif (masks_dir / "cameras.json").is_file():
            cameras = Camera.list_from_json(masks_dir / "cameras.json")
        else:
            raise InputDataError(f"{masks_dir}: no cameras.json; give the cameras with --camera CAM.json")
        numbers, per_cam = find_frames(masks_dir, len(cameras))
        check_masks(per_cam, numbers, cameras)
        frame_names = [", ".join(str(pc[f]) for pc in per_cam) for f in numbers]

        def load(k: int, _pc=per_cam):
            f = numbers[k]
            return [read_mask(pc[f], f, cam) for pc, cam in zip(_pc, cameras)]

    if len(cameras) == 1 and robot.root == "free" and args.upright == 0 and args.rest_prior == 0:
        # with joint limits the upright prior alone tracked the walk benchmark best; without
        # them it lost seeds that the rest prior keeps (README, 'Which options')
        priors = "--upright 0.1 holds" if robot.has_limits else "--upright 0.1 --rest-prior 0.01 hold"
        print(f"note: one camera: for a person walking or standing, {priors} what one view does not fix "
              "(not for a hand; the README's 'Which options')", file=sys.stderr)
    q0 = _initial_q(args, robot)
    auto = args.init == "auto" or (video_mode and not args.init)
    init_fit = None
    first, first_masks = _first_non_empty(load, len(numbers), masks_dir)
    if auto:
        q0, init_fit = _auto_init(robot, cameras, first_masks, first)
    if not video_mode:
        removed = _remove_earlier_outputs(out, len(cameras))
    if removed:
        print(f"note: {out}: removed {removed} file(s) of an earlier run", file=sys.stderr)
    if (args.no_size_calibration or auto) and args.size_every is not None:
        why = "--no-size-calibration" if args.no_size_calibration else "the automatic initialization (no --init POSE)"
        print(f"note: --size-every refines the measured sizes; with {why} none are measured, so it does nothing",
              file=sys.stderr)
    options = dict(SEGMENTED_MASKS) if video_mode else {}  # else Tracker's own defaults
    if args.size_every is not None:
        options["size_every"] = args.size_every
    if args.limb_search_drop is not None:
        options["limb_search_drop"] = args.limb_search_drop
    if args.tol_px is not None:
        options["tol_px"] = args.tol_px or None  # 0: the joints' test alone
    # body sizes are measured on the first frame only where its pose is known (the rest pose
    # or --init POSE): at a pose found by the search they would absorb its errors
    tracker = Tracker(
        robot, cameras, q0=q0, calibrate_sizes=not (args.no_size_calibration or auto),
        mirror_hypothesis=False if args.no_mirror_hypothesis else None,
        swap_hypothesis=False if args.no_swap_hypothesis else None, binned_hypotheses=args.binned_hypotheses,
        depth_prior=args.depth_prior, upright=args.upright, up=up, rest_prior=args.rest_prior,
        limb_search=False if args.no_limb_search else None,
        limb_hypothesis=False if args.no_limb_hypothesis else None, **options,
    )
    try:
        out.mkdir(parents=True, exist_ok=True)
        with replaced(out / "model.kms") as tmp:
            shutil.copyfile(args.spec, tmp)
        meta = {
            "model": "model.kms", "system": robot.system.name, "root": robot.root, "cameras": len(cameras),
            "masks": str(masks_dir), "first_frame": numbers[0], "frames": len(numbers),
            "size_calibration": tracker.calibrate_sizes, "size_every": tracker.size_every,
            "mirror_hypothesis": tracker.mirror_hypothesis,
            "swap_hypothesis": tracker.swap_hypothesis, "limb_search": tracker.limb_search,
            "limb_search_drop": tracker.limb_search_drop, "limb_hypothesis": tracker.limb_hypothesis,
            "tol_px": tracker.tol_px,
            "binned_hypotheses": tracker.binned_hypotheses,
            "depth_prior": tracker.depth_prior,
            "upright": tracker.upright, "up": tracker.up.tolist(), "rest_prior": tracker.rest_prior,
            "complete": False,  # set once every frame is tracked (kms2pin evaluate warns otherwise)
        }
        if video_mode:
            meta["videos"] = [str(v) for v in args.video]
            meta["segmentation"] = args.method
            meta["shadow_detection"] = not args.no_shadows
            meta["shadow_threshold"] = args.shadow_threshold
            meta["gain_compensation"] = not args.no_gain_compensation
        write_files_atomically({out / "meta.json": json.dumps(meta, indent=2) + "\n"})
        with replaced(out / "cameras.json") as tmp:
            Camera.list_to_json(cameras, tmp)
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None

    video = None
    qs, results = [], []
    iterator = range(len(numbers))
    if not args.no_progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, unit="frame", desc="tracking")
    interrupted = False
    reacquire = None
    if auto and robot.root == "free":
        from ..video.reacquire import Reacquisition

        reacquire = Reacquisition(robot, cameras, q0, reference_fit=init_fit)
    try:
        with TrajectoryCsvWriter(robot, out / "trajectory.csv") as csv_out:
            for k in iterator:
                frame = numbers[k]
                masks = load(k)
                names = frame_names[k]
                r = tracker.step(masks, source=f"{names}: frame {frame}")
                if "empty mask" in r.flags:
                    kept = "the previous frame's pose kept" if k else "the initial pose kept"
                    print(f"note: frame {frame}: empty mask ({names}); {kept}", file=sys.stderr)
                if reacquire is not None:
                    tracker, r, note = reacquire.update(tracker, r, masks, source=f"{names}: frame {frame}")
                    if note:
                        print(f"note: frame {frame}: {note}", file=sys.stderr)
                with interrupts_deferred():  # a frame is in every output or in none
                    csv_out.write(frame, r)
                    qs.append(r.q)
                    results.append(r)
                    if not args.no_video:
                        img = _overlay(robot, cameras, masks, r.q, tracker.scales)
                        if video is None:  # written to a temporary name, renamed once released
                            video = cv2.VideoWriter(str(out / OVERLAY_TMP), cv2.VideoWriter_fourcc(*"mp4v"),
                                                    args.fps, (img.shape[1], img.shape[0]))
                        video.write(img)
    except KeyboardInterrupt as stop:  # Ctrl-C, or SIGTERM (Terminated)
        interrupted = stop
    except Kms2pinError:
        done = f"up to frame {numbers[len(qs) - 1]}" if qs else "empty (no frame tracked)"
        print(f"kms2pin track: stopped at frame {numbers[len(qs)]}; outputs in {out} are {done}", file=sys.stderr)
        raise
    finally:
        if video is not None:
            video.release()
            if (out / OVERLAY_TMP).exists():
                os.replace(out / OVERLAY_TMP, out / "overlay.mp4")
        if qs:
            with replaced(out / "poses.npz") as tmp:
                Trajectory(robot, np.array(qs), results, scales=tracker.scales).to_npz(tmp)
    if interrupted:
        print(f"interrupted after {len(qs)} frame(s); outputs in {out} are complete up to there", file=sys.stderr)
        raise interrupted
    if video_mode:
        from ..video.track_video import plot_joint_angles

        try:
            with replaced(out / "joint_angles.png") as tmp:
                plot_joint_angles(robot, np.array(qs), tmp, frames=numbers[: len(qs)])
        except Exception as err:  # noqa: BLE001 - the plot is a convenience
            print(f"note: joint_angles.png skipped ({err})", file=sys.stderr)
    try:
        from ..viewer import write_animation_html
    except Exception as err:  # noqa: BLE001 - the viewer is optional
        print(f"note: animation.html skipped (viewer unavailable: {err})", file=sys.stderr)
    else:
        try:
            with replaced(out / "animation.html") as tmp:
                write_animation_html(robot, np.array(qs), args.fps, tmp)
        except Exception as err:  # noqa: BLE001
            print(f"note: animation.html skipped ({err})", file=sys.stderr)
    meta["complete"] = True
    try:
        write_files_atomically({out / "meta.json": json.dumps(meta, indent=2) + "\n"})
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None
    fits = np.array([r.fit for r in results])
    poor = [numbers[k] for k, r in enumerate(results) if any(f.startswith("poor fit") for f in r.flags)]
    if poor:
        print(f"note: {len(poor)} frame(s) fit the masks poorly (IoU < {tracker.poor_fit:g}), the first at frame "
              f"{poor[0]}: the track is probably lost there (flag 'poor fit' in trajectory.csv)", file=sys.stderr)
        if video_mode:
            print(f"note: if the masks in {masks_dir} miss parts of the subject, the background model learnt them "
                  "(a subject that stands still while most of the video is taken); `kms2pin segment` with "
                  "--learn-frames / --learn-from, then track --masks, can do better", file=sys.stderr)
    print(f"{out}: {len(qs)} frames tracked; mean fit (IoU) {fits.mean():.3f}, worst {fits.min():.3f} "
          f"(frame {numbers[int(fits.argmin())]})")
    return 0
