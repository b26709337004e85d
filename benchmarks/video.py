"""Video speed: `python benchmarks/video.py [--frames N] [--track-frames M | --no-track]`.

1. **Segmentation at 640x480.**  A synthetic static-camera video (lowerbody
   model walking over a textured, flickering, noisy background; ray-cast at
   320x240 and enlarged, which only affects the test material) is decoded into
   memory first; the timed part is :class:`kms2pin.video.segmentation.Segmenter`
   (background model + luminance edge refinement + clean-up), per frame, with
   one OpenCV thread and with OpenCV's default thread count, and once more
   without the edge refinement.  The learning (temporal mode + training) is timed
   separately.  Target: >= 100 frames/s on one core.
2. **End to end: `kms2pin track --video` on the full-body model.**  Two
   synchronized 320x240 MJPG videos (15 frames/s) of the full-body model
   walking diagonally across the scene (:func:`kms2pin.video.synthetic.diagonal_walk`;
   the front camera and a raised side camera) are written to a temporary folder;
   the timed part is the whole command (reading and segmenting both videos,
   automatic initialization, ECM tracking, trajectory.csv / poses.npz /
   joint_angles.png / animation.html; no overlay.mp4).  The segmentation and
   the initialization are also timed on their own, and the run's accuracy
   against the true motion is printed.  Then the same with the front camera
   alone, tracked with ``--upright 0.1 --rest-prior 0.01``.
3. **Size refinement on segmented video** (``--size-clips K``, off by default):
   K clips of that scene (60 frames, the videos' noise seeds 10k and 10k + 1),
   tracked with ``--init`` at the true first pose, so the body sizes are measured
   on the first frame; each with ``--size-every 5`` and ``0``.  The accuracy of
   both is printed (``track --video`` refines them, since the segmentation's
   temporal mode; before it, with a false blob beside the subject, it did not).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from kms2pin.cli import main as cli
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.evaluate import evaluate
from kms2pin.ecm.tracker import Trajectory
from kms2pin.robot import load
from kms2pin.video.init import initial_pose_details
from kms2pin.video.segmentation import Segmenter, SegmentParams, sample_evenly
from kms2pin.video.synthetic import diagonal_walk, walking_video, write_video
from kms2pin.video.track_video import segment_videos

SPECS = Path(__file__).resolve().parents[1] / "specs"


def time_method(frames, method: str, refine_edges: bool = True) -> tuple[float, np.ndarray]:
    params = SegmentParams(method=method, refine_edges=refine_edges)
    seg = Segmenter(params)
    t0 = time.perf_counter()
    sample = sample_evenly(frames, params.learn_frames)
    seg._check_shape(sample[0], 0)
    seg.learn(sample)
    learn = time.perf_counter() - t0
    per = []
    for f in frames:
        t = time.perf_counter()
        seg.segment(f)
        per.append(time.perf_counter() - t)
    return learn, np.array(per)


def segmentation(n_frames: int) -> None:
    robot = load(str(SPECS / "lowerbody.kms"), root="free")
    video = walking_video(robot, Camera.default(640, 480), frames=n_frames, seed=0, render_scale=2, stride=2)
    frames = video.frames
    default_threads = cv2.getNumThreads()
    print(f"segmentation: {len(frames)} frames 640x480, OpenCV {cv2.__version__}")
    for threads, label in ((1, "1 thread"), (default_threads, f"default ({default_threads} threads)")):
        cv2.setNumThreads(threads)
        for method in ("mog2", "knn"):
            for refine in (True, False):
                time_method(frames[:10], method, refine)  # warm-up
                learn, per = time_method(frames, method, refine)
                med = float(np.median(per))
                name = f"{method}{'' if refine else ' (no edge refinement)'}"
                print(f"  {name:27s} {label:22s} median {med * 1e3:6.2f} ms/frame = {1 / med:6.1f} frames/s "
                      f"(mean {len(per) / per.sum():6.1f} frames/s; learning {learn:.2f} s once)")
    cv2.setNumThreads(default_threads)


def _scene(n_frames: int):
    """The full-body scene of sections 2 and 3: spec, robot, the two cameras, the true motion."""
    spec = SPECS / "fullbody.kms"
    robot = load(str(spec), root="free")
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    return spec, robot, cams, diagonal_walk(robot, n_frames, stride=2)  # 15 frames/s


def _write_videos(d: Path, robot, cams, truth, seed: int) -> list[str]:
    """One video and camera file per camera in ``d`` (noise seeds ``seed + k``); the
    ``track`` arguments that read them."""
    args = []
    for k, cam in enumerate(cams):
        write_video(d / f"cam{k}.avi", walking_video(robot, cam, seed=seed + k, q=truth).frames)
        cam.to_json(d / f"cam{k}.json")
        args += ["--video", str(d / f"cam{k}.avi"), "--camera", str(d / f"cam{k}.json")]
    return args


def end_to_end(n_frames: int, n_cameras: int = 2) -> None:
    """Section 2 of the module docstring; with one camera (the front one) ``track`` gets
    ``--upright 0.1 --rest-prior 0.01``, the README's advice for a person and one camera."""
    spec, robot, cams, truth = _scene(n_frames)
    cams = cams[:n_cameras]
    priors = ["--upright", "0.1", "--rest-prior", "0.01"] if n_cameras == 1 else []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        args = _write_videos(d, robot, cams, truth, 0)
        t0 = time.perf_counter()
        masks, _ = segment_videos([d / f"cam{k}.avi" for k in range(n_cameras)], cams)
        t_seg = time.perf_counter() - t0
        t0 = time.perf_counter()
        initial_pose_details(robot, cams, [m[0] for m in masks])
        t_init = time.perf_counter() - t0
        err = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stderr(err):
            code = cli(["track", str(spec), *args, *priors, "--no-progress", "--no-video", "-o", str(d / "out")])
        t_all = time.perf_counter() - t0
        if code != 0:
            raise SystemExit(f"track --video failed:\n{err.getvalue()}")
        rep = evaluate(robot, Trajectory.from_csv(robot, d / "out" / "trajectory.csv"), Trajectory(robot, truth))
    track = t_all - t_seg - t_init
    rig = "2 cameras" if n_cameras == 2 else "1 camera (" + " ".join(priors) + ")"
    print(f"track --video, full body ({len(robot.bodies)} bodies), {rig} 320x240, {n_frames} frames:")
    print(f"  whole command {t_all:6.1f} s = {n_frames / t_all:5.2f} frames/s")
    print(f"  of which segmentation {t_seg:5.1f} s ({n_cameras * n_frames / t_seg:5.0f} camera-frames/s), "
          f"initialization {t_init:4.1f} s, tracking and outputs {track:5.1f} s ({n_frames / track:4.2f} frames/s)")
    print(f"  accuracy: body-centre error {rep['mean_centre_error_pct']:.2f} % of height "
          f"(worst frame {rep['worst_frame_error_pct']:.2f}), revolute RMSE {rep['revolute_rmse_deg']:.2f} deg")


def size_refinement(clips: int, n_frames: int = 60) -> None:
    """Section 3 of the module docstring."""
    print(f"size refinement on segmented video: full body, 2 cameras, {n_frames} frames, --init at the true pose")
    spec, robot, cams, truth = _scene(n_frames)
    for clip in range(clips):
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            args = _write_videos(d, robot, cams, truth, 10 * clip)
            Trajectory(robot, truth[:1]).to_csv(d / "init.csv")
            row = []
            for every in (5, 0):
                err = io.StringIO()
                with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                    code = cli(["track", str(spec), *args, "--init", str(d / "init.csv"), "--size-every", str(every),
                                "--no-progress", "--no-video", "-o", str(d / "out")])
                if code != 0:
                    raise SystemExit(f"track --video failed:\n{err.getvalue()}")
                rep = evaluate(robot, Trajectory.from_csv(robot, d / "out" / "trajectory.csv"), Trajectory(robot, truth))
                row.append(f"--size-every {every}: {rep['mean_centre_error_pct']:.2f} % "
                           f"(worst frame {rep['worst_frame_error_pct']:.2f}), {rep['revolute_rmse_deg']:.1f} deg")
        print(f"  clip {clip}: " + " | ".join(row))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=120, help="frames of the segmentation benchmark")
    ap.add_argument("--track-frames", type=int, default=40, help="frames of the end-to-end run")
    ap.add_argument("--no-track", action="store_true", help="segmentation only")
    ap.add_argument("--size-clips", type=int, default=0, metavar="K",
                    help="also track K segmented clips from the true pose with and without the size refinement")
    args = ap.parse_args()
    segmentation(args.frames)
    if not args.no_track:
        end_to_end(args.track_frames)
        end_to_end(args.track_frames, n_cameras=1)
    if args.size_clips > 0:
        size_refinement(args.size_clips)


if __name__ == "__main__":
    main()
