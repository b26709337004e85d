"""The static update (thesis §2.3): equilibrium, sign consistency, stiffness, bad input.

Energies and gradients here are recomputed independently of the solver: the
spring energy 1/2 sum k (q' - q)^2 from ``robot.maximal_coordinates`` and its
derivatives by finite differences taken with ``pin.integrate``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import MIXED_JOINTS, require_kernels

import kms2pin
from kms2pin.virtual_work import StaticUpdateResult, _Evaluator, static_update, stiffness_array, target_array

SPECS = Path(__file__).resolve().parents[1] / "specs"

ROBOTS = {}


def robot(name: str, root: str = "spec") -> kms2pin.Robot:
    """A spec of specs/ (``mixed``: conftest.MIXED_JOINTS), loaded once."""
    key = (name, root)
    if key not in ROBOTS:
        spec = kms2pin.parse(MIXED_JOINTS) if name == "mixed" else SPECS / f"{name}.kms"
        ROBOTS[key] = kms2pin.load(spec, root=root)
    return ROBOTS[key]


NAMES = ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry", "mixed")
CASES = [(n, r) for n in NAMES for r in ("spec", "free")]


def qmul(a, b):
    return np.array([
        a[0] * b[0] - a[1:] @ b[1:],
        *(a[0] * b[1:] + b[0] * a[1:] + np.cross(a[1:], b[1:])),
    ])


def noisy_targets(r: kms2pin.Robot, q, rng, angle_deg=30.0, frac=0.2):
    """Intermediate bodies: each primary body moved by up to `frac` of the model height
    and turned by up to `angle_deg` about a random axis (thesis §4.1's synthetic M-steps)."""
    t = r.maximal_coordinates(q)
    t[:, :3] += rng.uniform(-1, 1, (len(t), 3)) * frac * r.height / np.sqrt(3)
    for i in range(len(t)):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        half = np.radians(rng.uniform(0, angle_deg)) / 2
        t[i, 3:] = qmul(np.r_[np.cos(half), np.sin(half) * axis], t[i, 3:])
    return t


def energy(r, q, targets, k=1.0):
    """Spring energy with each target's Euler parameters on the primary's side."""
    qm = r.maximal_coordinates(q)
    t = targets.copy()
    flip = np.sum(t[:, 3:] * qm[:, 3:], axis=1) < 0
    t[flip, 3:] *= -1
    return 0.5 * np.sum(np.broadcast_to(k, qm.shape) * (qm - t) ** 2)


def fd_gradient(r, q, f, h=1e-6):
    g = np.zeros(r.nv)
    for a in range(r.nv):
        e = np.zeros(r.nv)
        e[a] = h
        g[a] = (f(pin.integrate(r.model, q, e)) - f(pin.integrate(r.model, q, -e))) / (2 * h)
    return g


@pytest.mark.parametrize("name,root", CASES)
def test_targets_from_a_valid_configuration_are_recovered_exactly(name, root, backend):
    r = robot(name, root)
    rng = np.random.default_rng(1)
    for _ in range(5):
        q_star = r.clamp(r.random_configuration(rng, 90))  # valid: within the spec's joint limits
        if root == "free":
            q_star[:3] += rng.normal(0, 0.3, 3)
        q0 = pin.integrate(r.model, q_star, rng.normal(0, 0.25, r.nv))
        res = static_update(r, q0, r.maximal_coordinates(q_star), tol=1e-11)
        assert res.converged, res.message
        assert np.linalg.norm(pin.difference(r.model, res.q, q_star)) < 1e-8
        assert res.energy < 1e-16


@pytest.mark.parametrize("name,root", CASES)
def test_noisy_updates_reach_a_stationary_point_of_the_spring_energy(name, root, backend):
    """B^T Q = 0 (eq. 2.28) checked without the solver's Jacobian: the finite-difference
    gradient of the independently computed energy vanishes at the result, but for a
    coordinate held at a joint limit, where it must push outwards (a KKT point)."""
    r = robot(name, root)
    rng = np.random.default_rng(2)
    for _ in range(3):
        q0 = r.clamp(r.random_configuration(rng, 90))
        t = noisy_targets(r, q0, rng)
        res = static_update(r, q0, t)
        assert res.converged, res.message
        assert res.energy == pytest.approx(energy(r, res.q, t), rel=1e-12)
        assert res.energy < energy(r, q0, t)
        g = fd_gradient(r, res.q, lambda q: energy(r, q, t))
        tol = 1e-6 * max(1.0, res.energy)
        for j in r.joints:
            if j.nq == 1 and np.isfinite(r.lower_limits[j.idx_q]):
                at_lower = res.q[j.idx_q] <= r.lower_limits[j.idx_q] + 1e-12
                at_upper = res.q[j.idx_q] >= r.upper_limits[j.idx_q] - 1e-12
                if at_lower or at_upper:
                    assert (g[j.idx_v] > -tol) if at_lower else (g[j.idx_v] < tol)
                    g[j.idx_v] = 0.0
        assert np.abs(g).max() < tol
        # forces are eq. 2.33 at the equilibrium
        qm = r.maximal_coordinates(res.q)
        tt = t.copy()
        tt[np.sum(tt[:, 3:] * qm[:, 3:], axis=1) < 0, 3:] *= -1
        np.testing.assert_allclose(res.forces, tt - qm, atol=1e-12)


@pytest.mark.parametrize("name,root", [("fullbody", "spec"), ("jplhand", "free"), ("puma600", "free"),
                                       ("human", "free"), ("gantry", "spec"), ("mixed", "spec")])
def test_gradient_and_newton_hessian_match_finite_differences(name, root, backend):
    r = robot(name, root)
    rng = np.random.default_rng(3)
    q = r.random_configuration(rng, 120)
    t = noisy_targets(r, q, rng, 60, 0.3)
    tgt, mask = target_array(r, t)
    k = rng.uniform(0.5, 2.0, (len(r.bodies), 7))
    ev = _Evaluator(r, tgt, stiffness_array(r, k, mask))
    e, grad, H, _ = ev.linearize(q)
    assert e == pytest.approx(energy(r, q, t, k), rel=1e-12)
    np.testing.assert_allclose(grad, fd_gradient(r, q, lambda x: energy(r, x, t, k)), atol=1e-6)
    h = 1e-6
    Hfd = np.zeros_like(H)
    for a in range(r.nv):
        d = np.zeros(r.nv)
        d[a] = h
        Hfd[:, a] = (ev.linearize(pin.integrate(r.model, q, d))[1] - ev.linearize(pin.integrate(r.model, q, -d))[1]) / (2 * h)
    if root == "free":
        # The free flyer's tangent space is not a vector space: differencing the gradient along
        # pin.integrate adds a skew-symmetric term to the root's own 6x6 block (the Lie bracket
        # with the root's gradient, entries up to ~3 here), so that block is compared by its
        # symmetric part, which agrees with H's to ~1e-8 (entries up to ~100); the other blocks
        # have no such term and are compared as they are.
        Hfd[:6, :6] = 0.5 * (Hfd[:6, :6] + Hfd[:6, :6].T)
    for j in r.joints:  # a spherical joint's rotations do not commute either: the same for its 3x3 block
        if j.kind == "spherical":
            b = slice(j.idx_v, j.idx_v + 3)
            Hfd[b, b] = 0.5 * (Hfd[b, b] + Hfd[b, b].T)
    np.testing.assert_allclose(H, Hfd, atol=1e-5)


def test_a_target_equal_to_the_primary_pose_exerts_no_force_whatever_its_sign():
    r = robot("fullbody")
    q = r.random_configuration(np.random.default_rng(4), 90)
    t = r.maximal_coordinates(q)
    t[::2, 3:] *= -1  # the same rotations with the other sign (thesis §2.2.1)
    res = static_update(r, q, t)
    assert res.converged and res.iterations == 0
    assert np.abs(res.forces).max() < 1e-12
    assert res.energy < 1e-24
    np.testing.assert_array_equal(res.q, q)


def test_a_much_stiffer_body_ends_much_closer_to_its_own_target():
    """As k_i grows, body i approaches the closest pose it can reach alone (its target
    may be unreachable: the spec's root joint only turns), whatever the others want."""
    r = robot("lowerbody")
    rng = np.random.default_rng(5)
    q = r.random_configuration(rng, 60)
    t = noisy_targets(r, q, rng)
    i = r.index("leftShin")

    def dist(res):
        qm = r.maximal_coordinates(res.q)[i]
        return min(np.linalg.norm(qm - t[i]), np.linalg.norm(qm - np.r_[t[i, :3], -t[i, 3:]]))

    alone = static_update(r, q, {"leftShin": t[i]})
    soft = static_update(r, q, t)
    k = np.ones(len(r.bodies))
    k[i] = 1e4
    stiff = static_update(r, q, t, stiffness=k)
    assert alone.converged and soft.converged and stiff.converged
    assert dist(soft) > 1.5 * dist(alone)
    assert dist(stiff) - dist(alone) < 0.02 * (dist(soft) - dist(alone))


def test_per_coordinate_stiffness_zero_on_orientation_pulls_positions_only():
    r = robot("puma600")
    rng = np.random.default_rng(6)
    q = r.random_configuration(rng, 60)
    q_star = r.random_configuration(rng, 60)
    t = r.maximal_coordinates(q_star)
    t[:, 3:] = noisy_targets(r, q_star, rng, 90, 0.0)[:, 3:]  # orientations that disagree
    k = np.zeros((len(r.bodies), 7))
    k[:, :3] = 1.0
    res = static_update(r, q, t, stiffness=k)
    assert res.converged
    assert np.abs(res.forces[:, 3:]).max() == 0.0
    assert res.energy == pytest.approx(energy(r, res.q, t, k), rel=1e-12)


def test_bodies_left_out_of_a_mapping_pull_with_no_spring():
    r = robot("fullbody")
    q = r.q_rest
    goal = r.random_configuration(np.random.default_rng(7), 40)
    pose = r.body_pose(goal, "leftHand")
    res = static_update(r, q, {"leftHand": pose})
    assert res.converged
    assert res.energy < 1e-16
    reached = r.body_pose(res.q, "leftHand")
    assert np.abs(reached.translation - pose.translation).max() < 1e-7
    others = [i for i, b in enumerate(r.bodies) if b != "leftHand"]
    assert np.abs(res.forces[others]).max() == 0.0


@pytest.mark.parametrize(
    "bad,match",
    [
        (lambda t: t.__setitem__((5, 0), np.nan), "leftFoot"),
        (lambda t: t.__setitem__((7, slice(3, 7)), [1.0, 1.0, 0.0, 0.0]), "rightShin"),
    ],
)
def test_nan_or_non_unit_targets_raise_a_value_error_naming_the_body(bad, match):
    r = robot("lowerbody")
    t = r.maximal_coordinates(r.q_rest)
    bad(t)
    with pytest.raises(ValueError, match=match):
        static_update(r, r.q_rest, t)


def test_malformed_targets_and_stiffness_are_rejected_with_clear_messages():
    r = robot("lowerbody")
    t = r.maximal_coordinates(r.q_rest)
    with pytest.raises(kms2pin.TargetError, match=r"\(9, 7\)"):
        static_update(r, r.q_rest, t[:4])
    with pytest.raises(kms2pin.TargetError, match="did you mean 'leftShin'"):
        static_update(r, r.q_rest, {"leftShn": pin.SE3.Identity()})
    with pytest.raises(kms2pin.TargetError, match="stiffness"):
        static_update(r, r.q_rest, t, stiffness=-1.0)


def test_a_zero_root_quaternion_is_refused_without_a_warning():
    r = robot("lowerbody", "free")
    q = r.q_rest
    bad = np.r_[q[:3], 0, 0, 0, 0, q[7:]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(kms2pin.TargetError, match=r"quaternion q\[3:7\].*scalar last.*zero norm"):
            static_update(r, bad, r.maximal_coordinates(q))


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_q_is_refused_naming_its_joint(value):
    r = robot("lowerbody", "free")
    q = r.q_rest.copy()
    hip = r.model.joints[r.model.getJointId("leftThigh_hip")].idx_q
    q[hip] = value
    with pytest.raises(kms2pin.TargetError, match=rf"^q\[{hip}\] \(joint 'leftThigh_hip'\)"):
        static_update(r, q, r.maximal_coordinates(r.q_rest))
    with pytest.raises(kms2pin.TargetError, match=r"shape \(13,\)"):
        static_update(r, q[:5], r.maximal_coordinates(r.q_rest))


def test_a_non_unit_root_quaternion_is_normalized(backend):
    r = robot("lowerbody", "free")
    rng = np.random.default_rng(4)
    q = r.random_configuration(rng, 40)
    t = noisy_targets(r, q, rng)
    scaled = q.copy()
    scaled[3:7] *= 3.0
    a, b = static_update(r, q, t), static_update(r, scaled, t)
    assert a.converged and b.converged
    np.testing.assert_allclose(b.q, a.q, atol=1e-9)
    assert np.linalg.norm(b.q[3:7]) == pytest.approx(1.0, abs=1e-12)


def test_a_non_converging_update_returns_its_diagnostics_instead_of_raising(backend):
    r = robot("jplhand")
    rng = np.random.default_rng(8)
    q = r.random_configuration(rng, 90)
    t = noisy_targets(r, q, rng, 60, 0.3)
    res = static_update(r, q, t, max_iter=1)
    assert isinstance(res, StaticUpdateResult)
    assert not res.converged and res.iterations == 1
    assert res.residual > 1e-9 and "limit" in res.message
    assert np.isfinite(res.energy) and res.forces.shape == (len(r.bodies), 7)


def test_native_kernel_rejects_malformed_arrays_instead_of_crashing():
    k = require_kernels()
    J, X = np.zeros((6, 4)), np.zeros((3, 7))
    with pytest.raises(ValueError, match="wrong shape"):
        k.linearize(J, X, np.zeros((2, 7)), np.zeros((3, 7)), np.zeros((3, 4)), np.zeros((4, 4)),
                    np.zeros(4), np.zeros((4, 4)), np.zeros((3, 7)), True)
    with pytest.raises(TypeError, match="float64"):
        k.linearize(J.astype(np.float32), X, X, X, np.zeros((3, 4)), np.zeros((4, 4)),
                    np.zeros(4), np.zeros((4, 4)), np.zeros((3, 7)), True)
    assert k.solve_shifted(-np.eye(3), np.ones(3), 0.0, np.zeros(3)) is False  # not positive definite
    step = np.zeros(3)
    assert k.solve_shifted(np.diag([1.0, 2.0, 4.0]), np.ones(3), 0.0, step) is True
    np.testing.assert_allclose(step, [-1.0, -0.5, -0.25])
