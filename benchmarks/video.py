"""Segmentation speed at 640x480: `python benchmarks/video.py [--frames N]`.

A synthetic static-camera video (lowerbody model walking over a textured,
flickering, noisy background; ray-cast at 320x240 and enlarged, which only
affects the test material) is decoded into memory first; the timed part is
:func:`kms2pin.video.segment_frames` (background model + clean-up), per frame,
with one OpenCV thread and with OpenCV's default thread count.  The learning
(median + training) is timed separately.  Target: >= 100 frames/s on one core.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from kms2pin.ecm.camera import Camera
from kms2pin.robot import load
from kms2pin.video.segmentation import Segmenter, SegmentParams, sample_evenly
from kms2pin.video.synthetic import walking_video

SPEC = Path(__file__).resolve().parents[1] / "specs" / "lowerbody.kms"


def time_method(frames, method: str) -> tuple[float, np.ndarray]:
    params = SegmentParams(method=method)
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=120)
    args = ap.parse_args()
    robot = load(str(SPEC), root="free")
    video = walking_video(robot, Camera.default(640, 480), frames=args.frames, seed=0, render_scale=2, stride=2)
    frames = video.frames
    default_threads = cv2.getNumThreads()
    print(f"{len(frames)} frames 640x480, OpenCV {cv2.__version__}")
    for threads, label in ((1, "1 thread"), (default_threads, f"default ({default_threads} threads)")):
        cv2.setNumThreads(threads)
        for method in ("mog2", "knn"):
            time_method(frames[:10], method)  # warm-up
            learn, per = time_method(frames, method)
            med = float(np.median(per))
            print(f"{method:5s} {label:22s} median {med * 1e3:6.2f} ms/frame = {1 / med:6.1f} frames/s "
                  f"(mean {len(per) / per.sum():6.1f} frames/s; learning {learn:.2f} s once)")
    cv2.setNumThreads(default_threads)


if __name__ == "__main__":
    main()
