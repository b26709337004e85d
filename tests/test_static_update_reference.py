"""The fast static update (Pinocchio joint coordinates) against the SymPy reference
(the thesis's maximal-coordinate formulation, eq. 2.22-2.32): same equilibrium."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import kms2pin
from kms2pin import reference
from kms2pin.virtual_work import perturbed_targets, static_update

SPECS = Path(__file__).resolve().parents[1] / "specs"
CASES = [(n, r) for n in ("puma600", "lowerbody", "fullbody", "jplhand") for r in ("spec", "free")]


def same_up_to_quaternion_sign(a: np.ndarray, b: np.ndarray) -> float:
    flip = np.sum(a[:, 3:] * b[:, 3:], axis=1) < 0
    b = b.copy()
    b[flip, 3:] *= -1
    return float(np.abs(a - b).max())


@pytest.mark.parametrize("name,root", CASES)
def test_fast_path_and_reference_reach_the_same_equilibrium(name, root, backend):
    robot = kms2pin.load(SPECS / f"{name}.kms", root=root)
    sym = reference.symbolic_model(robot.system, root)
    rng = np.random.default_rng(11)
    n_cases = 6 if name == "fullbody" else 8
    for _ in range(n_cases):
        q0 = robot.random_configuration(rng, 120)
        targets = perturbed_targets(robot, q0, rng, angle_deg=30.0, fraction=0.2)
        k = rng.uniform(0.5, 2.0, (len(robot.bodies), 7))
        fast = static_update(robot, q0, targets, k, tol=1e-11)
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
