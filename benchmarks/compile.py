"""Compile-and-load and forward-kinematics timings for the four thesis specs (and the
time to write the URDF + SRDF and the MJCF text).

Prints median times over repeated runs (the machine is noisy: medians, not means),
and the ratio to the targets of the compiler issue: full-body model compiled and
loaded in under 50 ms; all body poses of the full-body model in under 20 us.
Run: python benchmarks/compile.py [--repeat N]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only add overhead

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import kms2pin
from kms2pin.lang import parse_text
from kms2pin.mjcf import to_mjcf
from kms2pin.robot import Robot
from kms2pin.urdf import to_srdf, to_urdf

SPECS = Path(__file__).resolve().parents[1] / "specs"


def median_time(fn, repeat: int, inner: int = 1) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - t0) / inner)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=30)
    args = ap.parse_args()
    t0 = time.perf_counter()
    try:
        kms2pin.parse_text("rigidBodySystem s {}")
    except kms2pin.SpecError:
        pass
    print(f"grammar load (first parse in a process): {(time.perf_counter() - t0) * 1e3:.1f} ms")
    print(f"{'spec':10s} {'bodies':>6s} {'nq':>3s} {'parse ms':>9s} {'urdf ms':>8s} {'mjcf ms':>8s} {'pin ms':>7s} "
          f"{'total ms':>9s} {'FK us':>7s} {'FK+poses us':>12s} {'all J us':>9s}")
    rows = {}
    for name in ("puma600", "lowerbody", "fullbody", "jplhand"):
        text = (SPECS / f"{name}.kms").read_text()
        spec = parse_text(text, f"{name}.kms")
        system = spec.system()
        t_parse = median_time(lambda: parse_text(text, f"{name}.kms"), args.repeat)
        t_urdf = median_time(lambda: (to_urdf(system), to_srdf(system)), args.repeat)
        t_mjcf = median_time(lambda: to_mjcf(system), args.repeat)
        t_total = median_time(lambda: kms2pin.load(text), args.repeat)
        t_pin = median_time(lambda: Robot(spec, system), args.repeat) - t_urdf  # own URDF flavour, Pinocchio model, frames, SRDF
        robot = Robot(spec, system)
        q = robot.random_configuration(np.random.default_rng(0), 90)
        m, d = robot.model, robot.data
        t_fk = median_time(lambda: pin.framesForwardKinematics(m, d, q), args.repeat, 2000)
        t_poses = median_time(lambda: robot.body_poses(q), args.repeat, 500)
        t_jac = median_time(lambda: pin.computeJointJacobians(m, d, q), args.repeat, 2000)
        rows[name] = (t_total, t_fk)
        print(f"{name:10s} {len(robot.bodies):6d} {robot.nq:3d} {t_parse * 1e3:9.2f} {t_urdf * 1e3:8.2f} {t_mjcf * 1e3:8.2f} "
              f"{t_pin * 1e3:7.2f} {t_total * 1e3:9.2f} {t_fk * 1e6:7.2f} {t_poses * 1e6:12.2f} {t_jac * 1e6:9.2f}")
    total, fk = rows["fullbody"]
    print()
    print(f"full body compile+load: {total * 1e3:.2f} ms median = {total / 50e-3:.2f} x the 50 ms target")
    print(f"full body all body poses (pinocchio.framesForwardKinematics): {fk * 1e6:.2f} us median "
          f"= {fk / 20e-6:.2f} x the 20 us target")


if __name__ == "__main__":
    main()
