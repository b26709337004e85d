"""The fast static update (Pinocchio joint coordinates) against the SymPy reference
(the thesis's maximal-coordinate formulation, eq. 2.22-2.32): same equilibrium."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import MIXED_JOINTS

import kms2pin
from kms2pin import reference
from kms2pin.virtual_work import perturbed_targets, static_update

SPECS = Path(__file__).resolve().parents[1] / "specs"
NAMES = ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry", "mixed")  # mixed: every joint type
CASES = [(n, r) for n in NAMES for r in ("spec", "free")]


def same_up_to_quaternion_sign(a: np.ndarray, b: np.ndarray) -> float:
    flip = np.sum(a[:, 3:] * b[:, 3:], axis=1) < 0
    b = b.copy()
    b[flip, 3:] *= -1
    return float(np.abs(a - b).max())


@pytest.mark.parametrize("name,root", CASES)
def test_fast_path_and_reference_reach_the_same_equilibrium(name, root, backend):
    robot = kms2pin.load(kms2pin.parse(MIXED_JOINTS) if name == "mixed" else SPECS / f"{name}.kms", root=root)
    sym = reference.symbolic_model(robot.system, root)
    rng = np.random.default_rng(11)
    n_cases = 6 if name in ("fullbody", "human") else 8
    compared = 0
    for _ in range(10 * n_cases):
        if compared == n_cases:
            break
        q0 = robot.random_configuration(rng, 120)
        lo, hi = robot.lower_limits, robot.upper_limits
        limited = np.isfinite(lo)  # those away from their limits (the middle 60 %)
        q0[limited] = rng.uniform(lo[limited] + 0.2 * (hi - lo)[limited], hi[limited] - 0.2 * (hi - lo)[limited])
        targets = perturbed_targets(robot, q0, rng, angle_deg=30.0, fraction=0.2)
        k = rng.uniform(0.5, 2.0, (len(robot.bodies), 7))
        fast = static_update(robot, q0, targets, k, tol=1e-11)
        at_limit = (fast.q <= robot.lower_limits + 1e-9) | (fast.q >= robot.upper_limits - 1e-9)
        if at_limit.any():
            continue  # the thesis's formulation has no joint limits: compare interior equilibria
        compared += 1
        ref = reference.solve_equilibrium(robot.system, robot.maximal_coordinates(q0), targets, k, root, model=sym)
        assert fast.converged, fast.message
        assert ref.converged
        q_fast = robot.maximal_coordinates(fast.q)
        assert same_up_to_quaternion_sign(q_fast, ref.q) < 1e-6
        assert fast.energy == pytest.approx(ref.energy, rel=1e-8, abs=1e-14)
        # the fast result satisfies the thesis's own constraints and eq. 2.28 with its B_di
        assert np.abs(sym.C(q_fast.ravel())).max() < 1e-10
        Q = reference.spring_forces(q_fast, targets, k).ravel()
        assert np.linalg.norm(sym.B_di(q_fast.ravel()).T @ Q) < 1e-7 * max(1.0, np.linalg.norm(Q))
    assert compared == n_cases
