"""The static update of §2.3.3: springs (eq. 2.33), B_diᵀQ = 0 (eq. 2.28) and the solver."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from kms2pin.errors import TargetError
from kms2pin.reference import (
    aligned_targets,
    energy,
    equilibrium_residual,
    forward_kinematics,
    solve_equilibrium,
    spring_forces,
    symbolic_model,
)
from kms2pin.reference.rotations import matrix_to_quat, quat_to_matrix

from ._support import load_system, random_configuration

SEED = 1999


def _noisy(q, rng, pos=0.1, quat=0.1):
    t = q.copy()
    t[:, :3] += rng.normal(0, pos, (len(t), 3))
    t[:, 3:] += rng.normal(0, quat, (len(t), 4))
    t[:, 3:] /= np.linalg.norm(t[:, 3:], axis=1, keepdims=True)
    return t


def _moved(system, angles, pose, rng, sigma, root="spec"):
    """FK at angles (and root pose) moved by about sigma radians / units."""
    moved = {n: a + rng.normal(0, sigma, np.shape(a)) for n, a in angles.items()}
    if pose is not None:
        turn = quat_to_matrix(np.concatenate([[1.0], rng.normal(0, sigma / 2, 3)]) / np.sqrt(1 + 3 * sigma**2 / 4))
        pose = (pose[0] + rng.normal(0, sigma, 3), matrix_to_quat(turn @ quat_to_matrix(pose[1])))
    return forward_kinematics(system, moved, pose, root=root)


def _same_configuration(a, b, atol):
    np.testing.assert_allclose(a[:, :3], b[:, :3], atol=atol)
    sign = np.where(np.einsum("ij,ij->i", a[:, 3:], b[:, 3:]) < 0, -1.0, 1.0)
    np.testing.assert_allclose(a[:, 3:], sign[:, None] * b[:, 3:], atol=atol)


# ---------------------------------------------------------------------- springs
def test_flipping_a_targets_euler_parameters_changes_neither_energy_nor_forces():
    rng = np.random.default_rng(SEED)
    system = load_system("jplhand")
    q, _, _ = random_configuration(system, rng)
    t = _noisy(q, rng, quat=0.5)
    k = rng.uniform(0.1, 3.0, q.shape)
    flipped = t.copy()
    flipped[::2, 3:] *= -1
    assert energy(q, flipped, k) == pytest.approx(energy(q, t, k), rel=1e-15)
    np.testing.assert_allclose(spring_forces(q, flipped, k), spring_forces(q, t, k), atol=1e-15)
    aligned = aligned_targets(q, flipped)
    assert np.all(np.einsum("ij,ij->i", aligned[:, 3:], q[:, 3:]) >= 0)


def test_spring_forces_are_eq_2_33_with_aligned_targets_and_minus_the_energy_gradient():
    rng = np.random.default_rng(SEED + 1)
    q = rng.normal(size=(4, 7))
    t = rng.normal(size=(4, 7))
    t[:, 3:] /= np.linalg.norm(t[:, 3:], axis=1, keepdims=True)
    t[0, 3:] = -q[0, 3:] / np.linalg.norm(q[0, 3:])  # certainly needs flipping
    k = rng.uniform(0.5, 2.0, (4, 7))
    F = spring_forces(q, t, k)
    np.testing.assert_allclose(F[0, 3:], k[0, 3:] * (-t[0, 3:] - q[0, 3:]))
    h = 1e-6
    grad = np.zeros(q.size)
    for i in range(q.size):
        e = np.zeros(q.size)
        e[i] = h
        grad[i] = (energy(q + e.reshape(q.shape), t, k) - energy(q - e.reshape(q.shape), t, k)) / (2 * h)
    np.testing.assert_allclose(-grad, F.reshape(-1), atol=1e-7)
    assert energy(q, t, k) == pytest.approx(0.5 * np.sum(F**2 / k))


def test_stiffness_broadcasts_from_scalar_and_per_body_and_zero_means_no_spring():
    rng = np.random.default_rng(SEED + 2)
    q = rng.normal(size=(3, 7))
    t = q + 0.1
    t[:, 3:] /= np.linalg.norm(t[:, 3:], axis=1, keepdims=True)
    per_body = np.array([1.0, 0.0, 2.0])
    np.testing.assert_allclose(spring_forces(q, t, per_body), per_body[:, None] * (aligned_targets(q, t) - q))
    np.testing.assert_allclose(spring_forces(q, t, 2.0), 2.0 * (aligned_targets(q, t) - q))
    assert np.all(spring_forces(q, t, per_body)[1] == 0)


@pytest.mark.parametrize(
    "targets, stiffness, message",
    [
        (np.zeros((5, 6)), 1.0, "shape"),
        (np.full((5, 7), np.nan), 1.0, "not finite"),
        (np.ones((5, 7)), 1.0, "not unit"),
        (None, -1.0, ">= 0"),
        (None, np.ones(4), "stiffness must be"),
    ],
)
def test_malformed_targets_and_stiffness_are_refused(targets, stiffness, message):
    system = load_system("puma600")
    q = forward_kinematics(system)
    with pytest.raises(TargetError, match=message):
        solve_equilibrium(system, q, q if targets is None else targets, stiffness)


def test_an_invalid_start_is_refused_naming_the_violated_constraint():
    system = load_system("puma600")
    q = forward_kinematics(system)
    q[2, 0] += 0.5
    with pytest.raises(TargetError, match="link2_lowerLink position x"):
        solve_equilibrium(system, q, forward_kinematics(system), 1.0)


# ---------------------------------------------------------------------- the solver
@pytest.mark.parametrize(
    "spec_name, root",
    [("puma600", "spec"), ("fullbody", "spec"), ("jplhand", "free"), ("lowerbody", "free"), ("human", "spec"),
     ("gantry", "free"), ("mixed", "spec")],
)
def test_targets_from_a_nearby_valid_configuration_are_recovered_exactly(spec_name, root):
    rng = np.random.default_rng(SEED + 3)
    system = load_system(spec_name)
    q0, angles, pose = random_configuration(system, rng, root)
    q_star = _moved(system, angles, pose, rng, 0.1, root)
    res = solve_equilibrium(system, q0, q_star, 1.0, root=root)
    assert res.converged
    assert res.energy < 1e-20
    _same_configuration(res.q, q_star, 1e-9)
    assert res.constraint_error < 1e-12


@pytest.mark.parametrize(
    "spec_name, root",
    [("puma600", "spec"), ("fullbody", "spec"), ("fullbody", "free"), ("jplhand", "spec"), ("human", "free"),
     ("gantry", "spec"), ("mixed", "spec"), ("mixed", "free")],
)
def test_noisy_targets_end_in_a_valid_configuration_where_b_di_transpose_q_vanishes(spec_name, root):
    rng = np.random.default_rng(SEED + 4)
    system = load_system(spec_name)
    model = symbolic_model(system, root)
    q0, angles, pose = random_configuration(system, rng, root)
    targets = _noisy(_moved(system, angles, pose, rng, 0.2, root), rng)
    k = rng.uniform(0.5, 2.0, q0.shape)
    res = solve_equilibrium(system, q0, targets, k, root=root)
    assert res.converged and res.iterations < 50
    assert np.max(np.abs(model.C(res.q))) < 1e-12
    assert res.residual < 1e-10
    assert equilibrium_residual(system, res.q, targets, k, root) < 1e-10
    assert res.energy == pytest.approx(energy(res.q, targets, k), rel=1e-14)
    assert res.energy < energy(q0, targets, k)
    # B_di^T Q = 0 means Q is orthogonal to every valid motion, whichever partition gives B_di
    Q = spring_forces(res.q, targets, k).reshape(-1)
    C_q = model.C_q(res.q)
    null = np.linalg.svd(C_q)[2][-model.dof :]
    assert np.linalg.norm(null @ Q) < 1e-10


def _minimal_coordinate_minimum(system, angles0, targets, k):
    """Independent check: minimise E(FK(angles)) over the joint angles with BFGS."""
    names = list(angles0)

    def f(x):
        return energy(forward_kinematics(system, dict(zip(names, x))), targets, k)

    out = minimize(f, np.array([angles0[n] for n in names]), method="BFGS", options={"gtol": 1e-11, "maxiter": 2000})
    return forward_kinematics(system, dict(zip(names, out.x))), out.fun


@pytest.mark.parametrize("spec_name", ["puma600", "jplhand"])
def test_equilibrium_matches_a_direct_minimisation_over_joint_angles(spec_name):
    rng = np.random.default_rng(SEED + 5)
    system = load_system(spec_name)
    q0, angles, _ = random_configuration(system, rng)
    targets = _noisy(
        forward_kinematics(system, {n: a + rng.normal(0, 0.2) for n, a in angles.items()}), rng, 0.05, 0.05
    )
    k = rng.uniform(0.5, 2.0, q0.shape)
    res = solve_equilibrium(system, q0, targets, k)
    q_min, e_min = _minimal_coordinate_minimum(system, angles, targets, k)
    assert res.energy == pytest.approx(e_min, rel=1e-8)
    _same_configuration(res.q, q_min, 1e-5)


@pytest.mark.parametrize("root", ["spec", "free"])
def test_a_much_stiffer_body_ends_closer_to_its_own_target(root):
    rng = np.random.default_rng(SEED + 6)
    system = load_system("fullbody")
    q0, angles, pose = random_configuration(system, rng, root)
    targets = _noisy(_moved(system, angles, pose, rng, 0.3, root), rng, 0.15, 0.15)
    i = [b.name for b in system.bodies].index("leftShin")
    uniform = solve_equilibrium(system, q0, targets, 1.0, root=root)
    stiff = np.ones(len(system.bodies))
    stiff[i] = 1000.0
    heavy = solve_equilibrium(system, q0, targets, stiff, root=root)
    assert uniform.converged and heavy.converged

    def miss(res):
        return np.linalg.norm(aligned_targets(res.q, targets)[i] - res.q[i])

    assert miss(heavy) < miss(uniform)
    if root == "free":  # pelvis (6) + hip + knee give the shin all 6 DoF: it can sit on its target
        assert miss(heavy) < 0.05 * miss(uniform)


def test_springs_on_positions_only_still_reach_equilibrium():
    rng = np.random.default_rng(SEED + 7)
    system = load_system("puma600")
    q0, angles, _ = random_configuration(system, rng)
    targets = _noisy(forward_kinematics(system, {n: a + 0.3 for n, a in angles.items()}), rng)
    k = np.zeros(q0.shape)
    k[:, :3] = 1.0
    res = solve_equilibrium(system, q0, targets, k)
    assert res.converged
    assert res.residual < 1e-10
    # flipping the targets' Euler parameters cannot matter when they carry no spring
    res2 = solve_equilibrium(system, q0, targets * np.array([1, 1, 1, -1, -1, -1, -1]), k)
    _same_configuration(res.q, res2.q, 1e-12)


def test_a_start_with_tiny_constraint_drift_is_projected_onto_the_constraints():
    rng = np.random.default_rng(SEED + 8)
    system = load_system("jplhand")
    q0, angles, _ = random_configuration(system, rng)
    q_star = forward_kinematics(system, {n: a + 0.05 for n, a in angles.items()})
    drifted = q0 + rng.normal(0, 1e-9, q0.shape)
    res = solve_equilibrium(system, drifted, q_star, 1.0)
    assert res.converged and res.energy < 1e-20


def test_solver_stops_at_max_iter_and_says_it_did_not_converge():
    rng = np.random.default_rng(SEED + 9)
    system = load_system("fullbody")
    q0, angles, _ = random_configuration(system, rng)
    targets = _noisy(q0, rng, 0.3, 0.3)
    res = solve_equilibrium(system, q0, targets, 1.0, max_iter=1)
    assert res.iterations == 1
    assert not res.converged
    assert res.residual > 1e-6


def test_euler_parameter_signs_of_the_start_and_of_the_targets_do_not_change_the_result():
    rng = np.random.default_rng(SEED + 10)
    system = load_system("puma600")
    q0, angles, _ = random_configuration(system, rng)
    targets = _noisy(forward_kinematics(system, {n: a + 0.2 for n, a in angles.items()}), rng)
    a = solve_equilibrium(system, q0, targets, 1.0)
    flip = np.array([1, 1, 1, -1, -1, -1, -1.0])
    q0f = q0.copy()
    q0f[1::2] *= flip
    tf = targets.copy()
    tf[::2] *= flip
    b = solve_equilibrium(system, q0f, tf, 1.0)
    assert b.energy == pytest.approx(a.energy, rel=1e-10)
    _same_configuration(a.q, b.q, 1e-9)
