"""Static update benchmark: fast path vs a scipy least-squares baseline vs the SymPy reference.

For each spec: N random updates (random primary configuration within the spec's joint
limits, intermediate bodies with up to 30 deg / 20 % of body length of noise).  Prints
per method the median time, median iterations and success rate, and the ratios to the
fast path measured in the same run.  Success: the final ||B^T Q|| (eq. 2.28, evaluated
by the same code for every method; with joint limits, its part along the joints not
held at a limit, and the result within the limits) is below 1e-6.  The least-squares
baseline gets the limits as bounds; the reference (the thesis's formulation) has none.

Targets: full-body model under 1 ms median, >= 5x faster than the least-squares
baseline, >= 100x faster than the reference, success >= 99 % (compiler issue #3); the
human (spherical hips, shoulders, waist, neck) under 0.15 ms with the C kernels, >= 100x
the reference, >= 99 % success (issue #29).

Loop specs (fourbar, delta, stewart; issue #33): the random configurations and the fast
path's results close every loop; success also needs the closures to hold (residual below
1e-9) and ||B^T Q|| is along them (the null space of their Jacobian, the joints held at a
limit left out).  Their baseline is an independent constrained optimizer instead: SciPy's
SLSQP on the spring energy over the joint coordinates (tangent space of the start), the
closures' residual rows as equality constraints, the joint limits as bounds, gradients by
finite differences.  Target: the Delta robot under 0.3 ms with the C kernels, >= 99 %
success, >= 5x faster than SLSQP.

Run: python benchmarks/static_update.py [--updates 200] [--reference-updates 20] [--rounds 3] [--only human,...]

KMS2PIN_NATIVE=0 times the NumPy fallback instead of the C kernels.
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
import scipy.linalg
from scipy.optimize import least_squares, minimize

import kms2pin
from kms2pin import native, reference
from kms2pin.virtual_work import (
    _closed_system,
    _Evaluator,
    perturbed_targets,
    static_update,
    stiffness_array,
    target_array,
)

SPECS = Path(__file__).resolve().parents[1] / "specs"
NAMES = ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry", "fourbar", "delta", "stewart")
SUCCESS = 1e-6


def gradient_norm(robot, q, targets) -> float:
    """||B^T Q|| at q, less the parts held by active joint limits (inf outside the limits)."""
    if np.any(q < robot.lower_limits - 1e-9) or np.any(q > robot.upper_limits + 1e-9):
        return float("inf")
    tgt, mask = target_array(robot, targets)
    ev = _Evaluator(robot, tgt, stiffness_array(robot, 1.0, mask))
    if robot.closures:  # along the closures, which must hold
        if robot.closure_residual(q).max() > 1e-9:
            return float("inf")
        _, grad, H, _ = ev.linearize(q)
        return float(np.sqrt(_closed_system(robot, ev.s, q, grad, H)[4]))
    _, grad, H, _ = ev.linearize(q, hessian=False)
    for j in robot.joints:  # a limited joint at a limit, pushed outwards, holds its part
        i = j.idx_q
        if j.nq == 1 and np.isfinite(robot.lower_limits[i]):
            span = robot.upper_limits[i] - robot.lower_limits[i]
            low = q[i] <= robot.lower_limits[i] + 1e-12 * span and grad[j.idx_v] > 0
            high = q[i] >= robot.upper_limits[i] - 1e-12 * span and grad[j.idx_v] < 0
            if low or high:
                grad[j.idx_v] = 0.0
    return float(np.linalg.norm(grad))


def _bounds(robot, q0):
    """Bounds of the tangent displacement from q0: a limited revolute or prismatic joint's
    coordinate is its q entry, the rest is unbounded."""
    lo, hi = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
    for j in robot.joints:
        if j.nq == 1 and np.isfinite(robot.lower_limits[j.idx_q]):
            lo[j.idx_v] = robot.lower_limits[j.idx_q] - q0[j.idx_q]
            hi[j.idx_v] = robot.upper_limits[j.idx_q] - q0[j.idx_q]
    return lo, hi


def baseline(robot, q0, targets):
    """What a user would write: least squares on sqrt(k)(q_max(q) - q') over the joint
    coordinates (the tangent space of q0: spherical joints and a free root are not
    vector spaces), 2-point finite differences, the joint limits as bounds."""
    t = targets.copy()

    def resid(x):
        q = pin.integrate(robot.model, q0, x)
        qm = robot.maximal_coordinates(q)
        tt = t.copy()
        tt[np.sum(tt[:, 3:] * qm[:, 3:], axis=1) < 0, 3:] *= -1
        return (qm - tt).ravel()

    sol = least_squares(resid, np.zeros(robot.nv), method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-10,
                        bounds=_bounds(robot, q0))
    return pin.integrate(robot.model, q0, sol.x), sol.nfev


def constrained_baseline(robot, q0, targets):
    """An independent constrained optimizer for a model with loops: SLSQP on the spring
    energy over the joint coordinates (the tangent space of q0), the closures' residual rows
    (``Robot``'s Pinocchio constraints) as equality constraints, the joint limits as bounds,
    finite-difference gradients.  Returns the configuration and the energy evaluations."""
    t = targets.copy()
    model, data, C = robot.model, robot.data, robot._closures

    def energy(x):
        qm = robot.maximal_coordinates(pin.integrate(model, q0, x))
        tt = t.copy()
        tt[np.sum(tt[:, 3:] * qm[:, 3:], axis=1) < 0, 3:] *= -1
        return 0.5 * float(np.sum((qm - tt) ** 2))

    # the independent rows at the start (pivoted QR of their Jacobian): SLSQP stops on the
    # rows a planar loop repeats (a revolute closure's out-of-plane rows are zero)
    pin.computeJointJacobians(model, data, q0)
    J = C.jacobian(model, data)
    _, r, piv = scipy.linalg.qr(J.T, mode="economic", pivoting=True)
    d = np.abs(np.diagonal(r))
    rows = np.sort(piv[: int((d > 1e-9 * d[0]).sum()) if d.size and d[0] > 0 else 0])

    def closures(x):
        pin.forwardKinematics(model, data, pin.integrate(model, q0, x))
        return C.residual(model, data)[rows]

    lo, hi = _bounds(robot, q0)
    sol = minimize(energy, np.zeros(robot.nv), method="SLSQP", bounds=list(zip(lo, hi)),
                   constraints=[{"type": "eq", "fun": closures}], options={"ftol": 1e-14, "maxiter": 500})
    return pin.integrate(model, q0, sol.x), sol.nfev


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--updates", type=int, default=200)
    ap.add_argument("--reference-updates", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=3, help="alternating timing rounds (medians over all)")
    ap.add_argument("--only", default=",".join(NAMES), help=f"comma-separated specs (default: {','.join(NAMES)})")
    args = ap.parse_args()
    header = (f"{'spec':10s} {'method':10s} {'n':>4s} {'median ms':>10s} {'med iter':>9s} "
              f"{'success':>8s} {'x fast':>8s}")
    print(header)
    print("-" * len(header))
    summary = {}
    for name in args.only.split(","):
        robot = kms2pin.load(SPECS / f"{name}.kms")
        sym = reference.symbolic_model(robot.system, "spec")
        rng = np.random.default_rng(args.seed)
        cases = []
        for _ in range(args.updates):
            q0 = robot.clamp(robot.random_configuration(rng, 120))
            cases.append((q0, perturbed_targets(robot, q0, rng)))
        static_update(robot, *cases[0])  # warm caches
        # Each method runs its cases as a block (warm caches, as in a tracking loop); the
        # blocks alternate over --rounds rounds so that the machine's noise (2 shared
        # cores) hits every method alike.  The reference, being slow, runs on the first
        # --reference-updates cases only and is compared with the fast path on those.
        times = {m: [] for m in ("fast", "lsq", "reference")}
        iters = {m: [] for m in times}
        ok = dict.fromkeys(times, 0)
        for rnd in range(args.rounds):
            for method in ("fast", "lsq", "reference"):
                todo = cases if method != "reference" else cases[: args.reference_updates]
                for q0, t in todo:
                    t0 = time.perf_counter()
                    if method == "fast":
                        res = static_update(robot, q0, t)
                        q, it = res.q, res.iterations
                    elif method == "lsq":
                        q, it = (constrained_baseline if robot.closures else baseline)(robot, q0, t)
                    else:
                        ref = reference.solve_equilibrium(
                            robot.system, robot.maximal_coordinates(q0), t, 1.0, model=sym
                        )
                        it = ref.iterations
                        q = None
                    times[method].append(time.perf_counter() - t0)
                    if rnd:
                        continue
                    iters[method].append(it)
                    if q is None:
                        ok[method] += ref.converged and ref.residual < SUCCESS
                    else:
                        ok[method] += gradient_norm(robot, q, t) < SUCCESS
        n_ref = len(cases[: args.reference_updates])
        fast_paired = statistics.median(
            [x for r in range(args.rounds) for x in times["fast"][r * len(cases) : r * len(cases) + n_ref]]
        )
        rows = {m: (len(iters[m]), statistics.median(times[m]), statistics.median(iters[m]), ok[m] / len(iters[m]))
                for m in times}
        fast_t = rows["fast"][1]
        for method, (n, med, it, rate) in rows.items():
            base = fast_paired if method == "reference" else fast_t
            print(f"{name:10s} {method:10s} {n:4d} {med * 1e3:10.3f} {it:9.1f} {rate * 100:7.1f}% "
                  f"{med / base:8.1f}")
        summary[name] = rows
        summary[name]["fast_paired"] = fast_paired
    print()
    for name, target_ms in (("fullbody", 1.0), ("human", 0.15), ("delta", 0.3)):
        if name not in summary:
            continue
        row = summary[name]
        what, goal = ("SLSQP", "target >= 5") if name == "delta" else ("least squares", "target >= 5")
        ref_goal = "" if name == "delta" else "target >= 100, "
        print(f"{name}: fast path median {row['fast'][1] * 1e3:.3f} ms "
              f"({row['fast'][1] / (target_ms * 1e-3):.2f} x the {target_ms:g} ms target); "
              f"{what} / fast = {row['lsq'][1] / row['fast'][1]:.1f} ({goal}); "
              f"reference / fast = {row['reference'][1] / row['fast_paired']:.0f} ({ref_goal}same cases); "
              f"fast success {row['fast'][3] * 100:.1f} % (target >= 99 %)")
    print("(lsq 'iterations' are residual evaluations, for the loop specs SLSQP's energy evaluations; reference "
          "iterations are Newton steps; the reference's 'x fast' is against the fast path's median on the same cases)")
    print(f"fast path kernels: {'native C (kms2pin/_kernels.c)' if native.ENABLED else 'NumPy'}")


if __name__ == "__main__":
    main()
