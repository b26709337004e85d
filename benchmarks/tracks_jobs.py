"""Tracks beside in several processes (``Tracker(..., jobs=N)``, ``track --jobs N``): the
elapsed time of tracking real motion with tracks beside the first, in one process and in
N, in the same run, and whether the two tracks are the same to the last bit.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/tracks_jobs.py [--only walk-2cam-320]
        [--seed 60] [--frames N] [--jobs N] [--repeats 2] [--second-track TRACKS]

The masks are ``realmotion.py``'s (CMU trial 131/01 rendered as capsules, 5 % noise), the
tracker its preset with the tracks beside of the accurate rows of docs/tracking.md (by
default the four tracks, ``--second-track``).  Each repeat tracks the frames once in one
process and once in ``--jobs`` (default: one per track, at most the cores this process may
use), the order alternating, and prints the frames/s of elapsed (wall-clock) time of each; then
the medians and their ratio.  Elapsed time, not process time: the point is the cores at once.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from realmotion import BVH, CACHE, CASES, load_sequence, rendered, rig

from kms2pin.ecm import Tracker
from kms2pin.ecm.options import track_changes
from kms2pin.ecm.stretches import track_poses
from kms2pin.ecm.workers import usable_cores

#: the four tracks of docs/tracking.md's most accurate rows
FOUR = "midline=1; midline=1,midline_legs=0.1; prediction_memory=3"


def tracked(seq, cameras, masks, preset, tracks: str, jobs: int) -> tuple[float, np.ndarray]:
    """Frames/s of elapsed time (the tracker made included) and every frame's every track's pose."""
    t0 = time.perf_counter()
    with Tracker(seq.model, cameras, preset, q0=seq.floor[0], second_track=tracks, jobs=jobs) as tr:
        poses = []
        for k, m in enumerate(masks):
            tr.step(m, source=f"frame {k}")
            poses.append(track_poses(tr))
    return len(masks) / (time.perf_counter() - t0), np.array(poses)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bvh", type=Path, default=BVH, help="the motion capture (default: the shared CMU walk)")
    p.add_argument("--only", default="walk-2cam-320", choices=sorted(CASES), help="the case (default walk-2cam-320)")
    p.add_argument("--seed", type=int, default=60, help="the masks' noise seed (default 60)")
    p.add_argument("--frames", type=int, help="track only the first N frames")
    p.add_argument("--jobs", type=int, help="processes (default: one per track, at most the usable cores)")
    p.add_argument("--repeats", type=int, default=2, help="runs of each (default 2)")
    p.add_argument("--second-track", default=FOUR, help="the tracks beside (default the four tracks' three)")
    p.add_argument("--cache", type=Path, default=CACHE, help="where rendered masks are kept between runs")
    a = p.parse_args()
    motion, n, factor, preset = CASES[a.only]
    seq = load_sequence(a.bvh, motion, a.frames)
    cameras = rig(seq.path, n, factor)
    masks = rendered(seq.subject, seq.q, cameras, "capsule", a.seed, a.cache)
    tracks = 1 + len(track_changes(a.second_track))
    jobs = a.jobs or min(tracks, usable_cores())
    print(f"{a.only} seed {a.seed}, {len(masks)} frames, {tracks} tracks ({a.second_track!r} beside), "
          f"{usable_cores()} usable cores", flush=True)
    fps: dict[int, list[float]] = {1: [], jobs: []}
    poses: dict[int, np.ndarray] = {}
    for r in range(a.repeats):
        for j in ((1, jobs) if r % 2 == 0 else (jobs, 1)):
            f, poses[j] = tracked(seq, cameras, masks, preset, a.second_track, j)
            fps[j].append(f)
            print(f"  repeat {r + 1}: {j} process{'es' if j > 1 else ''}: {f:5.2f} frames/s elapsed", flush=True)
    one, many = float(np.median(fps[1])), float(np.median(fps[jobs]))
    same = np.array_equal(poses[1], poses[jobs])
    print(f"median: 1 process {one:.2f} frames/s, {jobs} processes {many:.2f}: {many / one:.2f}x; every track's "
          f"every pose the same to the last bit: {'yes' if same else 'NO'}", flush=True)


if __name__ == "__main__":
    main()
