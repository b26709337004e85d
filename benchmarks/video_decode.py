"""What decoding videos in a child process costs (kms2pin/video/_decoder.py).

For an MPEG-4 clip and an uncompressed "DIB " AVI (each N frames of W x H), times
(medians over --repeat runs, the baseline in the same run):

- in process: ``cv2.VideoCapture`` + ``read()`` in this process, as kms2pin did before
  (not run on the DIB AVI: it crashes OpenCV's FFmpeg backend);
- probe: :func:`kms2pin.video.io.probe_video` (a child that opens the file and decodes
  the first frame: what ``open_frames`` adds once per file);
- child stream: iterating an ``open_frames`` source (a child decodes, the frames come
  over a pipe);

and prints the child stream's time over the in-process one.  Then the same for the
whole segmentation of the MPEG-4 clip (``Segmenter.masks``: learning frames spread
over the clip, so it is read twice), from in-process frames and from ``open_frames``.
Run: python benchmarks/video_decode.py [--frames 300] [--size 640x480] [--repeat 5]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "video"))
from test_decoder import dib_avi, moving_square  # noqa: E402 - the AVI writer of the tests

from kms2pin.video.io import open_frames, probe_video  # noqa: E402
from kms2pin.video.segmentation import Segmenter, SegmentParams  # noqa: E402


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def in_process(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def child_stream(path: Path) -> int:
    return sum(1 for _ in open_frames(path))


class InProcessFrames:
    """Frames decoded in this process, re-iterable (as the Segmenter's spread learning needs)."""

    def __init__(self, path: Path):
        self.path = path

    def __iter__(self):
        cap = cv2.VideoCapture(str(self.path))
        k = 0
        while True:
            ok, img = cap.read()
            if not ok:
                break
            yield k, img
            k += 1
        cap.release()


def segment(frames) -> int:
    return sum(1 for _ in Segmenter(SegmentParams()).masks(frames))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    w, h = map(int, args.size.lower().split("x"))
    frames = moving_square(args.frames, h, w)
    with tempfile.TemporaryDirectory() as tmp:
        mp4, avi = Path(tmp) / "clip.mp4", Path(tmp) / "clip.avi"
        writer = cv2.VideoWriter(str(mp4), cv2.VideoWriter_fourcc(*"mp4v"), 25, (w, h))
        for f in frames:
            writer.write(f)
        writer.release()
        avi.write_bytes(dib_avi(frames))
        print(f"{args.frames} frames of {w}x{h}, medians of {args.repeat} runs")
        print(f"{'file':22s} {'in process s':>13s} {'probe s':>8s} {'child stream s':>15s} {'ratio':>6s} "
              f"{'frames':>7s}")
        for name, path, baseline in (("MPEG-4 (mp4v)", mp4, True), ("uncompressed DIB AVI", avi, False)):
            n_child = child_stream(path)
            t_in = median_time(lambda p=path: in_process(p), args.repeat) if baseline else float("nan")
            t_probe = median_time(lambda p=path: probe_video(p), args.repeat)
            t_child = median_time(lambda p=path: child_stream(p), args.repeat)
            ratio = f"{t_child / t_in:6.2f}" if baseline else "     -"
            shown = f"{t_in:13.3f}" if baseline else f"{'(crashes)':>13s}"
            print(f"{name:22s} {shown} {t_probe:8.3f} {t_child:15.3f} {ratio} {n_child:7d}")
        t_in = median_time(lambda: segment(InProcessFrames(mp4)), args.repeat)
        t_child = median_time(lambda: segment(open_frames(mp4)), args.repeat)
        print(f"segmentation of the MPEG-4 clip: in process {t_in:.3f} s, from the child {t_child:.3f} s: "
              f"ratio {t_child / t_in:.2f}")


if __name__ == "__main__":
    main()
