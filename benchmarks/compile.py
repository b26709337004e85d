"""Compile-and-load and forward-kinematics timings for the specs (and the time to write the
URDF + SRDF and the MJCF text), and big generated models.

Prints median times over repeated runs (the machine is noisy: medians, not means),
and the ratio to the targets of the compiler issue: full-body model compiled and
loaded in under 50 ms; all body poses of the full-body model in under 20 us.

Big models (issue #32): generated specs of 100, 1,000 and 10,000 bodies, as a binary
tree and as a chain; ``kms2pin check``, ``kms2pin export`` and ``kms2pin.load`` each run
in a fresh process (after the same command on the PUMA spec, which imports everything),
which reports its wall time and its peak resident memory (and the rise over the
process's memory before it); then the growth per tenfold bodies.
Targets: a 1,000-body tree and chain export in under 5 s and 1 GB.

Run: python benchmarks/compile.py [--repeat N] [--sizes 100,1000,10000] [--no-big]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only add overhead

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
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


# one command in a fresh process: its wall time and peak memory (ru_maxrss, KiB on Linux)
_CHILD = """
import contextlib, json, os, resource, sys, time
import kms2pin
from kms2pin.cli import main
command, path, out, warm_up = sys.argv[1:5]


def run(spec):
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
        if command == "load":
            kms2pin.load(spec)
        else:
            assert main([command, spec] + (["-o", out] if command == "export" else [])) == 0


run(warm_up)  # imports, the grammar: once per process, not per model
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
run(path)
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": seconds, "peak_mb": peak / 1024, "rise_mb": (peak - before) / 1024}))
"""


def generated_spec(n: int, shape: str) -> str:
    """A spec of ``n`` bodies joined by revolute joints: a binary ``"tree"`` (body k hangs
    from body (k - 1) // 2) or a ``"chain"``."""
    parts = [
        "ellipsoidBody Link() { innerLam(0.1, 0.5, 0.1); outerLam(0.1, 0.5, 0.1);",
        "    bvec top { pos(0, 0.5, 0); orient(1, 0, 0); } bvec left { pos(-0.1, -0.5, 0); orient(1, 0, 0); }",
        "    bvec right { pos(0.1, -0.5, 0); orient(0, 0, 1); } }",
        "bvec origin { pos(0, 0, 0); orient(1, 0, 0); }",
        "rigidBodySystem big {",
    ]
    parts += [f"    Link b{k}();" for k in range(n)]
    for k in range(1, n):
        parent, end = (k - 1, "left") if shape == "chain" else ((k - 1) // 2, "left" if k % 2 else "right")
        parts.append(f"    constraint revolute(b{parent}.{end}, b{k}.top, 1);")
    parts += ["}", "constraint revolute(origin, big.b0.top);"]
    return "\n".join(parts) + "\n"


def big_models(sizes: list[int]) -> None:
    print(f"\n{'model':14s} {'command':8s} {'seconds':>8s} {'peak MB':>8s} {'rise MB':>8s}")
    rows: dict[tuple[str, str], list[tuple[int, dict]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for shape in ("tree", "chain"):
            for n in sizes:
                path = Path(tmp) / f"{shape}{n}.kms"
                path.write_text(generated_spec(n, shape))
                for command in ("check", "export", "load"):
                    out = subprocess.run([sys.executable, "-c", _CHILD, command, str(path), str(Path(tmp) / "out"),
                                          str(SPECS / "puma600.kms")], capture_output=True, text=True, check=True)
                    r = json.loads(out.stdout)
                    rows.setdefault((shape, command), []).append((n, r))
                    print(f"{shape + str(n):14s} {command:8s} {r['seconds']:8.2f} {r['peak_mb']:8.0f} "
                          f"{r['rise_mb']:8.0f}", flush=True)
    print("\ngrowth per tenfold bodies (time; memory rise): 10 = linear, 100 = quadratic")
    for (shape, command), results in rows.items():
        steps = [f"{n0}->{n1}: {r1['seconds'] / r0['seconds']:.1f}x; {r1['rise_mb'] / max(r0['rise_mb'], 1):.1f}x"
                 for (n0, r0), (n1, r1) in zip(results, results[1:])]
        print(f"  {shape:5s} {command:7s} " + ", ".join(steps))
    for shape in ("tree", "chain"):
        r = dict(rows[(shape, "export")]).get(1000)
        if r is not None:
            print(f"{shape} of 1000 bodies: export {r['seconds']:.2f} s (target 5 s), peak {r['peak_mb']:.0f} MB "
                  "(target 1024 MB)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--sizes", default="100,1000,10000", help="body counts of the generated models")
    ap.add_argument("--no-big", action="store_true", help="skip the generated big models")
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
    for name in ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry"):
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
    if not args.no_big:
        big_models([int(x) for x in args.sizes.split(",")])


if __name__ == "__main__":
    main()
