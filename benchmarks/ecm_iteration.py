"""One ECM iteration on a real-motion frame, by the three paths of the E-step and M-step
(issue #31, "speed where it counts"): the same arithmetic, so the same configuration to
the last bit, at three costs.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/ecm_iteration.py [--case walk-2cam-320]
        [--frame 40] [--repeats 7] [--iterations 100]

- ``per body``: every body's view made and fitted one by one (``UnionEStep(fused=False)``);
- ``fused``: a camera's E-step in one kernel call, the views and fits still per body
  (``UnionEStep(pack=False)``; the E-step and M-step of the default before 2026-11-28's
  tenth session);
- ``packed``: the views left packed and every body fitted in one kernel call (the default).

The track of ``realmotion.py``'s case (``PEOPLE``) is run to ``--frame``, then one ECM
iteration from that pose on the next frame's masks is timed per path, at full resolution
and on the masks binned 2x2 (the searches' screening): the median over ``--repeats`` of
the mean over ``--iterations`` (process time, ms), the parts (E-step, M-step, static
update) and each path's ratio to ``fused``.  Every path's new configuration is checked
equal to ``packed``'s (the script fails otherwise).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import realmotion as rm  # noqa: E402

from kms2pin.ecm.estep import UnionEStep  # noqa: E402
from kms2pin.ecm.loop import new_timings  # noqa: E402
from kms2pin.ecm.masks import Views  # noqa: E402

#: the paths: the E-step's switches
PATHS = {"per body": {"fused": False}, "fused": {"pack": False}, "packed": {}}


def timed(ecm, q: np.ndarray, views: Views, delta: float, repeats: int, iterations: int) -> tuple[float, dict]:
    """The median over ``repeats`` of one iteration's mean time (ms) over ``iterations``,
    and the parts' mean times (ms) of the median repeat."""
    runs = []
    for _ in range(repeats):
        parts = new_timings()
        t0 = time.process_time()
        for _ in range(iterations):
            ecm.iterate(q, views, delta, parts)
        runs.append((1e3 * (time.process_time() - t0) / iterations, {k: 1e3 * v / iterations for k, v in parts.items()}))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--case", default="walk-2cam-320", help="a case of realmotion.py (default walk-2cam-320)")
    p.add_argument("--frame", type=int, default=40, help="track to this frame, time the next (default 40)")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--iterations", type=int, default=100)
    a = p.parse_args()
    if a.case not in rm.CASES:
        p.error(f"--case: no case {a.case}; the cases are {', '.join(rm.CASES)}")
    motion, n, factor, preset = rm.CASES[a.case]
    seq = rm.load_sequence(rm.BVH, motion, a.frame + 2)
    cameras = rm.rig(seq.path, n, factor)
    masks = rm.rendered(seq.subject, seq.q, cameras, "capsule", 0, rm.CACHE)
    tracker = rm.Tracker(seq.model, cameras, q0=seq.floor[0], **preset)
    for m in masks[: a.frame + 1]:
        q = tracker.step(m).q
    views = Views.of(tracker.cameras, [np.asarray(m) for m in masks[a.frame + 1]])
    ecm, sil = tracker.ecm, tracker.options.silhouette
    delta = tracker.options.iteration.delta_final
    print(f"{a.case}, frame {a.frame + 1}: one ECM iteration (process time, median of {a.repeats} x {a.iterations})")
    for label, v, d in (("full resolution", views, delta), ("binned 2x2", views.binned(tracker._binned), 0.5 * delta)):
        out = {}
        for name, switches in PATHS.items():
            ecm.estep = UnionEStep(sil.max_pixels, sil.outlier, sil.outlier_px, **switches)
            out[name] = (ecm.iterate(q, v, d, new_timings()), *timed(ecm, q, v, d, a.repeats, a.iterations))
        for name, (q_new, *_) in out.items():
            if not np.array_equal(q_new, out["packed"][0]):
                raise SystemExit(f"{label}: the {name} path's configuration differs from the packed one's")
        base = out["fused"][1]
        print(f"  {label}:")
        for name, (_, ms, parts) in out.items():
            print(f"    {name:9s} {ms:6.3f} ms (E-step {parts['e_step']:.3f}, M-step {parts['m_step']:.3f}, static "
                  f"update {parts['static_update']:.3f}); {base / ms:.2f}x the fused path's speed")
    print("  every path's configuration equal to the packed path's, to the last bit")


if __name__ == "__main__":
    main()
