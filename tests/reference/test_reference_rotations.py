"""Eq. 2.4, 2.5, 2.7 and 2.12 as implemented by the reference."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin import model as shared
from kms2pin.reference.rotations import (
    alignment_matrix,
    axis_angle_matrix,
    axis_angle_quat,
    joint_rotation,
    matrix_to_quat,
    quat_to_matrix,
)

from ._support import random_unit_quaternion

SEED = 20240521


def _half_turn_quaternions(rng):
    """Unit quaternions with theta0 == 0 (180 deg rotations), axis-aligned and random."""
    axes = [np.eye(3)[k] for k in range(3)] + [-np.eye(3)[k] for k in range(3)]
    axes += [v / np.linalg.norm(v) for v in rng.normal(size=(20, 3))]
    axes += [np.array([1.0, 1.0, 0.0]) / np.sqrt(2), np.array([0.0, -1.0, 1.0]) / np.sqrt(2)]
    return [np.concatenate([[0.0], a]) for a in axes]


def _test_quaternions():
    rng = np.random.default_rng(SEED)
    quats = [random_unit_quaternion(rng) for _ in range(200)]
    quats += _half_turn_quaternions(rng)
    # near half turns and near identity
    for eps in (1e-3, 1e-8):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        quats.append(axis_angle_quat(a, np.pi - eps))
        quats.append(axis_angle_quat(a, eps))
    quats.append(np.array([1.0, 0.0, 0.0, 0.0]))
    return quats


def test_quaternion_to_matrix_gives_a_proper_rotation():
    for q in _test_quaternions():
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


def test_quaternion_matrix_quaternion_round_trip_recovers_the_quaternion_up_to_sign():
    for q in _test_quaternions():
        back = matrix_to_quat(quat_to_matrix(q))
        sign = 1.0 if back @ q >= 0 else -1.0
        np.testing.assert_allclose(sign * back, q, atol=1e-12, err_msg=f"quaternion {q}")


def test_matrix_quaternion_matrix_round_trip_recovers_the_matrix_including_half_turns():
    rng = np.random.default_rng(SEED + 1)
    mats = [quat_to_matrix(q) for q in _test_quaternions()]
    mats += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
    for _ in range(50):  # rotations from a QR decomposition, independent of eq. 2.7
        Qm, Rm = np.linalg.qr(rng.normal(size=(3, 3)))
        Qm = Qm @ np.diag(np.sign(np.diag(Rm)))
        mats.append(Qm * np.linalg.det(Qm))
    for R in mats:
        q = matrix_to_quat(R)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
        assert q[0] >= 0.0
        np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)


def test_axis_angle_matrix_eq_2_4_equals_eq_2_7_of_the_eq_2_5_quaternion():
    rng = np.random.default_rng(SEED + 2)
    for _ in range(100):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        angle = rng.uniform(-2 * np.pi, 2 * np.pi)
        np.testing.assert_allclose(axis_angle_matrix(a, angle), quat_to_matrix(axis_angle_quat(a, angle)), atol=1e-14)


def test_rotations_are_right_handed():
    np.testing.assert_allclose(axis_angle_matrix([0, 0, 1], np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(quat_to_matrix(axis_angle_quat([1, 0, 0], np.pi / 2)) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def _axis_pairs(rng):
    pairs = [(rng.normal(size=3), rng.normal(size=3)) for _ in range(100)]
    e = np.eye(3)
    pairs += [(e[i], e[j]) for i in range(3) for j in range(3)]
    pairs += [(e[i], -e[j]) for i in range(3) for j in range(3)]
    pairs += [(v, -v) for v in rng.normal(size=(10, 3))]
    pairs.append(((1.0, 0.0, 0.0), (0.9848077530122081, -0.17364817766693036, 0.0)))
    return [(p / np.linalg.norm(p), c / np.linalg.norm(c)) for p, c in pairs]


def test_alignment_matrix_maps_the_child_axis_onto_the_parent_axis_by_the_eq_2_12_angle():
    rng = np.random.default_rng(SEED + 3)
    for p, c in _axis_pairs(rng):
        R = alignment_matrix(p, c)
        np.testing.assert_allclose(R @ c, p, atol=1e-14)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
        assert angle == pytest.approx(np.arccos(np.clip(p @ c, -1, 1)), abs=1e-7)


def test_alignment_matrix_agrees_with_the_one_the_urdf_export_uses():
    rng = np.random.default_rng(SEED + 4)
    for p, c in _axis_pairs(rng):
        np.testing.assert_allclose(alignment_matrix(p, c), shared.alignment_matrix(p, c), atol=1e-15)


def test_revolute_joint_rotation_is_a_right_handed_turn_about_the_parent_axis_after_alignment():
    rng = np.random.default_rng(SEED + 5)
    for p, c in _axis_pairs(rng)[:30]:
        angle = rng.uniform(-np.pi, np.pi)
        R = joint_rotation("revolute", p, c, angle)
        np.testing.assert_allclose(R, axis_angle_matrix(p, angle) @ alignment_matrix(p, c), atol=1e-14)
        # eq. 2.16's second form: R_align Rot(o_ji, angle)
        np.testing.assert_allclose(R, alignment_matrix(p, c) @ axis_angle_matrix(c, angle), atol=1e-13)
        np.testing.assert_allclose(joint_rotation("fixed", p, c, angle), alignment_matrix(p, c), atol=0)
