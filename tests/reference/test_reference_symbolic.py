"""The symbolic constraints, their Jacobian, the partitioning and B_di (eq. 2.22-2.32)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from kms2pin.reference import SymbolicModel, forward_kinematics, symbolic_model
from kms2pin.reference.symbolic import Partition

from ._support import JOINT_DOF, load_system, moving_joints, random_configuration, revolute_names

SEED = 11


def _expected_rows(system, root):
    """Per body its Euler parameter norm; per joint 3 position rows and 3 axis rows
    (revolute) or 9 orientation rows (fixed), 3 position rows (spherical), or 9
    orientation rows and 2 line rows (prismatic)."""
    rows = len(system.bodies)
    for j in system.joints:
        if root == "free" and j.parent is None:
            continue
        rows += {"revolute": 6, "fixed": 12, "spherical": 3, "prismatic": 11}[j.kind]
    return rows


def test_there_is_one_labelled_row_per_constraint_with_all_redundant_rows(system, root, model):
    assert model.nc == _expected_rows(system, root) == len(model.labels) == len(model.constraints)
    assert model.nq == 7 * len(system.bodies) == len(model.symbols) == len(model.coordinate_labels)
    assert len(set(model.labels)) == model.nc
    for j in system.joints:
        present = f"{j.name} position x" in model.labels
        assert present == (not (root == "free" and j.parent is None) and j.kind != "prismatic")
        if j.kind == "prismatic" and not (root == "free" and j.parent is None):
            assert f"{j.name} line n1" in model.labels and f"{j.name} line n2" in model.labels


def test_fullbody_row_labels_read_as_joint_and_component():
    model = symbolic_model(load_system("fullbody"))
    assert "leftShin_knee position x" in model.labels
    assert "leftShin_knee axis z" in model.labels
    assert "head_neck orientation R[1][2]" in model.labels
    assert "pelvis Euler parameter norm" in model.labels
    assert model.coordinate_labels[7:10] == ("leftThigh.mu_x", "leftThigh.mu_y", "leftThigh.mu_z")


def test_the_degrees_of_freedom_are_the_joints_plus_six_for_a_free_root(system, root, model):
    """One per revolute or prismatic joint, three per spherical joint."""
    assert model.dof == sum(JOINT_DOF[j.kind] for j in moving_joints(system, root)) + (6 if root == "free" else 0)


def test_constraint_jacobian_matches_central_finite_differences(system, root, model):
    rng = np.random.default_rng(SEED)
    q = rng.normal(size=model.nq)  # anywhere, not only on the constraint manifold
    J = model.C_q(q)
    h = 1e-6
    fd = np.empty_like(J)
    for k in range(model.nq):
        e = np.zeros(model.nq)
        e[k] = h
        fd[:, k] = (model.C(q + e) - model.C(q - e)) / (2 * h)
    np.testing.assert_allclose(J, fd, atol=1e-7 * max(1.0, np.abs(J).max()))


def test_the_ring_derived_jacobian_equals_sympys_jacobian_of_the_constraint_expressions():
    model = symbolic_model(load_system("puma600"))
    full = sp.Matrix(model.constraints).jacobian(model.symbols)
    assert (full - sp.Matrix(model.jacobian_matrix())).is_zero_matrix


def test_constraint_hessian_contraction_matches_differences_of_the_jacobian():
    model = symbolic_model(load_system("jplhand"), "free")
    rng = np.random.default_rng(SEED + 2)
    q, lam, dq = rng.normal(size=model.nq), rng.normal(size=model.nc), rng.normal(size=model.nq)
    W = model.constraint_hessian(q, lam)
    # C_q is linear in q, so lam^T (C_q(q + dq) - C_q(q)) is exactly dq^T W
    np.testing.assert_allclose(lam @ (model.C_q(q + dq) - model.C_q(q)), W @ dq, atol=1e-12)
    np.testing.assert_allclose(W, W.T, atol=0)


def test_moving_one_body_breaks_exactly_the_rows_of_its_joints():
    system = load_system("fullbody")
    model = symbolic_model(system)
    q, _, _ = random_configuration(system, np.random.default_rng(SEED + 3))
    i = [b.name for b in system.bodies].index("leftShin")
    q[i, 0] += 0.01
    broken = {model.labels[r] for r in np.flatnonzero(np.abs(model.C(q)) > 1e-12)}
    assert broken == {"leftShin_knee position x", "leftFoot_ankle position x"}
    q[i, 3:] *= 1.01
    broken = {model.labels[r] for r in np.flatnonzero(np.abs(model.C(q)) > 1e-12)}
    assert "leftShin Euler parameter norm" in broken
    assert all(lab.split()[0] in ("leftShin", "leftShin_knee", "leftFoot_ankle") for lab in broken)


def test_b_di_spans_the_tangent_space_of_the_constraints(system, root, model):
    rng = np.random.default_rng(SEED + 4)
    for _ in range(3):
        q, _, _ = random_configuration(system, rng, root)
        B = model.B_di(q)
        assert B.shape == (model.nq, model.dof)
        np.testing.assert_allclose(model.C_q(q) @ B, 0.0, atol=1e-12)
        assert np.linalg.matrix_rank(B, tol=1e-8) == model.dof
        part = model.partition(q)
        np.testing.assert_array_equal(B[part.independent], np.eye(model.dof))
        assert sorted(np.concatenate([part.independent, part.dependent])) == list(range(model.nq))


def test_fullbody_b_di_rank_is_12_with_the_spec_root_and_17_with_a_free_root():
    system = load_system("fullbody")
    q = forward_kinematics(system)
    assert np.linalg.matrix_rank(symbolic_model(system, "spec").B_di(q)) == 12
    assert np.linalg.matrix_rank(symbolic_model(system, "free").B_di(q)) == 17  # 11 joints + 6


def test_numerical_partition_works_where_the_thesis_theta0_choice_is_singular():
    """Fig. 2.2(c)-type failure: at a body orientation of identity dθ0/dθ = 0, so taking
    θ_{j,0} as the independent coordinate of every revolute joint leaves C_qd singular."""
    system = load_system("fullbody")
    model = symbolic_model(system)
    angles = {name: 0.0 for name in revolute_names(system)}
    q = forward_kinematics(system, angles)
    assert q[0, 3] == pytest.approx(1.0)  # the pelvis is not rotated at all
    thesis_ind = np.array([7 * k + 3 for k, j in enumerate(system.joints) if j.kind == "revolute"])
    thesis = Partition(thesis_ind, np.setdiff1d(np.arange(model.nq), thesis_ind))
    Cq = model.C_q(q)
    sv = np.linalg.svd(Cq[:, thesis.dependent], compute_uv=False)
    assert sv[model.n_dependent - 1] < 1e-12 * sv[0]  # rank deficient
    ours = model.partition(q)
    sv = np.linalg.svd(Cq[:, ours.dependent], compute_uv=False)
    assert sv[model.n_dependent - 1] > 1e-3 * sv[0]
    np.testing.assert_allclose(Cq @ model.B_di(q), 0.0, atol=1e-12)


def test_symbolic_models_are_cached_per_system_and_root():
    system = load_system("puma600")
    assert symbolic_model(system) is symbolic_model(system, "spec")
    assert symbolic_model(system, "free") is not symbolic_model(system)
    assert isinstance(symbolic_model(system), SymbolicModel)
