"""Priors of the static update: depth, upright, rest, twist, ground, midline."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.mstep import BodyFit
from kms2pin.ecm.priors import MIDLINE_MARGIN, DepthPrior, GroundPrior, MidlinePrior, RestPrior, UprightPrior, feet
from kms2pin.ecm.springs import full_update
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.errors import OptionError
from kms2pin.robot import load

from ._tracking import (
    DIR,
    _cams,
    _robot,
    _still_subject,
    centre_error,
    cmu_walker,
)


def test_depth_prior_holds_the_root_distance_along_the_ray():
    """The one-camera depth creep of a still subject (test above) is held by the depth
    spring; its gradient is that of k/2 (n . (p - anchor))^2 in the root's local velocity."""
    robot, cams, qt, masks, kw = _still_subject()
    drift = {}
    for prior in (0.0, 1.0):
        tr = Tracker(robot, cams, depth_prior=prior, **kw)
        res = [tr.step(masks) for _ in range(4)]
        drift[prior] = abs(res[-1].q[2] - qt[2])  # the default camera looks along world z
    with pytest.raises(ValueError, match="depth_prior"):
        Tracker(robot, cams, depth_prior=-0.1)
    assert drift[0.0] > 0.02
    assert drift[1.0] < 0.25 * drift[0.0]
    # the spring's gradient against finite differences of its energy
    anchor = qt[:3] + np.array([0.05, -0.02, 0.3])
    prior = DepthPrior(1.0, anchor, [cams[0].centre])
    q = robot.random_configuration(np.random.default_rng(4), 20)
    nv = robot.model.nv
    A, g = np.eye(nv), np.zeros(nv)
    pin.forwardKinematics(robot.model, robot.data, q)
    k = 0.7
    e0 = prior.add(A, g, q, robot.data, k)
    n = anchor - cams[0].centre
    n /= np.linalg.norm(n)

    def energy(dv):
        p = pin.integrate(robot.model, q, dv)[:3]
        return 0.5 * k * float(n @ (p - anchor)) ** 2

    eps = 1e-6
    fd = [(energy(eps * np.eye(nv)[a]) - energy(-eps * np.eye(nv)[a])) / (2 * eps) for a in range(nv)]
    np.testing.assert_allclose(g, fd, atol=1e-7)
    assert e0 == pytest.approx(energy(np.zeros(nv)), rel=1e-12)


def test_upright_spring_is_the_gradient_of_its_energy_and_free_about_the_vertical():
    """The upright spring adds to the static update the gradient and Gauss-Newton
    Hessian of E = k/2 |R u - up|^2 (R the root's rotation, u its axis vertical at q0),
    in the root's local velocity; E does not change when the root turns about ``up``."""
    robot = _robot("fullbody")
    up = np.array([0.2, 1.0, -0.1])
    tr = Tracker(robot, _cams(robot, 1), upright=1.0, up=up, calibrate_sizes=False)
    up = up / np.linalg.norm(up)
    (prior,) = [p for p in tr.ecm.priors if isinstance(p, UprightPrior)]
    np.testing.assert_allclose(pin.XYZQUATToSE3(robot.q_rest[:7]).rotation @ prior.axis, up, atol=1e-12)
    nv = robot.model.nv
    k = 1.3

    def energy(q):
        R = pin.XYZQUATToSE3(q[:7]).rotation
        return 0.5 * k * float(np.sum((R @ prior.axis - up) ** 2))

    eps = 1e-6
    for seed in range(3):
        rng = np.random.default_rng(seed)
        q = robot.random_configuration(rng, 20)
        q[3:7] = pin.Quaternion(pin.exp3(rng.uniform(-1.0, 1.0, 3))).coeffs()  # a tilted root
        A, g = np.eye(nv), np.zeros(nv)
        pin.forwardKinematics(robot.model, robot.data, q)
        assert prior.add(A, g, q, robot.data, k) == pytest.approx(energy(q), rel=1e-12)
        basis = np.eye(nv)
        fd = [(energy(pin.integrate(robot.model, q, eps * e)) - energy(pin.integrate(robot.model, q, -eps * e))) / (2 * eps) for e in basis]
        np.testing.assert_allclose(g, fd, atol=1e-7)
        assert np.all(g[:3] == 0) and np.all(g[6:] == 0) and np.abs(g[3:6]).max() > 1e-3
        # a turn about the vertical (world axes) keeps the energy
        turned = q.copy()
        M = pin.XYZQUATToSE3(q[:7])
        turned[:7] = pin.SE3ToXYZQUAT(pin.SE3(pin.exp3(up * 1.3) @ M.rotation, M.translation))
        assert energy(turned) == pytest.approx(energy(q), abs=1e-12)
    # at the minimum the Gauss-Newton matrix is the energy's Hessian (finite differences)
    q = robot.q_rest.copy()
    pin.forwardKinematics(robot.model, robot.data, q)
    A, g = np.zeros((nv, nv)), np.zeros(nv)
    A[3:6, 3:6] = np.eye(3)
    prior.add(A, g, q, robot.data, k)
    h = 1e-4
    for a in range(3, 6):
        e = h * np.eye(nv)[a]
        d2 = (energy(pin.integrate(robot.model, q, e)) - 2 * energy(q) + energy(pin.integrate(robot.model, q, -e))) / h**2
        assert A[a, a] - 1.0 == pytest.approx(d2, rel=1e-5, abs=1e-9)
    for bad in (dict(upright=-0.1), dict(upright=float("nan")), dict(up=(0, 0, 0)), dict(up=(1, 2))):
        with pytest.raises(ValueError, match="upright|up"):
            Tracker(robot, _cams(robot, 1), **bad)


def test_rest_prior_spring_is_the_gradient_of_its_energy():
    """The rest prior adds to the static update the gradient and Hessian of
    E = k/2 sum_j (q_j - rest_j)^2 over the joint angles (radians), nothing on the root."""
    robot = _robot("fullbody")
    tr = Tracker(robot, _cams(robot, 1), rest_prior=0.01, calibrate_sizes=False)
    (prior,) = [p for p in tr.ecm.priors if isinstance(p, RestPrior)]
    nv, k = robot.model.nv, 0.7
    angles = [robot.model.joints[j].idx_q for j in range(2, robot.model.njoints)]  # every joint but the root

    def energy(q):
        return 0.5 * k * float(np.sum((q[angles] - robot.q_rest[angles]) ** 2))

    rng = np.random.default_rng(3)
    q = robot.random_configuration(rng, 30)
    A, g = np.zeros((nv, nv)), np.zeros(nv)
    assert prior.add(A, g, q, robot.data, k) == pytest.approx(energy(q), rel=1e-12)
    eps = 1e-6
    fd = [(energy(pin.integrate(robot.model, q, eps * e)) - energy(pin.integrate(robot.model, q, -eps * e))) / (2 * eps)
          for e in np.eye(nv)]
    np.testing.assert_allclose(g, fd, atol=1e-7)
    assert np.all(g[:6] == 0) and np.abs(g[6:]).min() > 0
    np.testing.assert_array_equal(A, np.diag(np.r_[np.zeros(6), np.full(nv - 6, k)]))
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="rest_prior"):
            Tracker(robot, _cams(robot, 1), rest_prior=bad)


def test_static_update_with_the_rest_prior_is_the_equilibrium_of_springs_and_prior():
    """With M-step poses at a configuration q_t and the rest prior on, the static update
    ends in equilibrium (virtual work, B^T Q = 0, eq. 2.28): the springs' generalized
    forces, Q_i = -K_i e_i with e_i = (t_i - t'_i, log(R_i R'_i^T)) mapped by Pinocchio's
    frame Jacobians of the body centres, are zero on the root and k (q_j - rest_j) on
    every joint, with one k for all joints.  Without the prior it ends at q_t."""
    robot = _robot("lowerbody")
    model, data, nv = robot.model, robot.data, robot.model.nv
    rng = np.random.default_rng(5)
    q_t = robot.q_rest.copy()
    angles = [model.joints[j].idx_q for j in range(2, model.njoints)]
    q_t[angles] += rng.uniform(-0.4, 0.4, len(angles))
    targets = robot.body_poses(q_t)
    H = []
    for _ in targets:
        B = rng.normal(size=(6, 6))
        H.append(B @ B.T + 6 * np.eye(6))

    def force(q):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        out = np.zeros(nv)
        for f, T, h in zip(robot.frame_ids, targets, H):
            P = data.oMf[f]
            e = np.r_[P.translation - T.translation, pin.log3(P.rotation @ T.rotation.T)]
            J = pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)
            out -= J.T @ h @ e
        return out

    inner = np.array([robot.inner(b) for b in robot.bodies])
    joint_dofs = np.arange(6, nv)
    for prior in (0.0, 0.05):
        terms = [RestPrior(prior, model, robot.q_rest, joint_dofs)] if prior else []
        fits = [BodyFit(P, h.copy(), 0.0, 0.0) for P, h in zip(targets, H)]
        q = full_update(robot, q_t.copy(), fits, inner, 0.0, 60, terms)
        if prior == 0.0:
            np.testing.assert_allclose(q, q_t, atol=1e-9)
            continue
        Q = force(q)
        d = q[angles] - robot.q_rest[angles]
        assert np.abs(Q[:6]).max() < 1e-7 * np.abs(Q).max()
        k = Q[6:] / d  # the prior's stiffness, the same for every joint
        np.testing.assert_allclose(k, np.median(k), rtol=1e-6)
        assert np.median(k) > 0
        # the prior pulls the joints as a whole towards rest (each one need not move so:
        # the springs couple them)
        assert np.linalg.norm(d) < np.linalg.norm(q_t[angles] - robot.q_rest[angles])


def test_upright_prior_tracks_a_turn_that_one_camera_loses():
    """The full body with joint limits seen by one camera through the walk's second
    turn, from the true pose on clean silhouettes.  Without the prior the pelvis pitches
    while the hips and waist make up for it, and the track is lost (measured: 88 % of
    the height, the pelvis upside down); with it the turn is tracked."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    seg = make_motion(robot, "walk", 200)[160:200]
    cams = [Camera.default()]
    tr = Tracker(robot, cams, q0=seg[0], upright=0.1, calibrate_sizes=False)
    res = [tr.step(render(robot, q, cams)) for q in seg]
    assert max(centre_error(robot, r.q, q) for r, q in zip(res, seg)) < 4.0
    (prior,) = tr.ecm.priors
    tilt = [np.arccos(np.clip(pin.XYZQUATToSE3(r.q[:7]).rotation @ prior.axis @ prior.up, -1, 1)) for r in res]
    assert np.degrees(max(tilt)) < 5.0
    # the truth's heading turns by 180 degrees over the segment; the track's ends with it
    Ra, Rb = (pin.XYZQUATToSE3(x[:7]).rotation for x in (res[-1].q, seg[-1]))
    assert np.degrees(np.linalg.norm(pin.log3(Ra.T @ Rb))) < 10.0


def _turned(robot, joint, rotvec):
    """The rest pose with spherical ``joint`` turned by ``rotvec`` (rad, its own axes: R Exp(r))."""
    q = robot.q_rest.copy()
    x = q[joint.idx_q : joint.idx_q + 4]
    R = pin.Quaternion(x[3], x[0], x[1], x[2]).toRotationMatrix() @ pin.exp3(np.asarray(rotvec, dtype=float))
    q[joint.idx_q : joint.idx_q + 4] = pin.Quaternion(R).coeffs()
    return q


def _energy_of(prior, robot, k):
    """``q -> the prior's energy at q`` (its Newton terms thrown away), after the forward
    pass and Jacobians at q that the static update makes (a prior may read them)."""
    nv = robot.model.nv

    def energy(q):
        pin.computeJointJacobians(robot.model, robot.data, q)
        return prior.add(np.zeros((nv, nv)), np.zeros(nv), q, robot.data, k)

    return energy


def _assert_gradient(prior, robot, q, k):
    """The prior's gradient at ``q`` against central differences of its energy (steps by
    pin.integrate); returns the gradient."""
    nv, energy, eps = robot.model.nv, _energy_of(prior, robot, k), 1e-6
    g = np.zeros(nv)
    pin.computeJointJacobians(robot.model, robot.data, q)
    prior.add(np.zeros((nv, nv)), g, q, robot.data, k)
    fd = [(energy(pin.integrate(robot.model, q, eps * e)) - energy(pin.integrate(robot.model, q, -eps * e))) / (2 * eps)
          for e in np.eye(nv)]
    np.testing.assert_allclose(g, fd, atol=1e-6)
    return g


def test_twist_prior_is_the_gradient_of_its_energy_and_leaves_the_swing_free():
    """The twist prior on the human's round limbs (upper arms, thighs): its gradient is
    that of E = k/2 sum theta^2 (finite differences with pin.integrate), theta the twist
    of each joint relative to rest about its child's long axis; a swing (a turn about an
    axis across the limb) leaves its energy at 0; the thesis's models have none."""
    from kms2pin.ecm.priors import TwistPrior

    human = load(DIR / "human.kms", root="free")
    nv = human.model.nv
    prior = TwistPrior.of(1.0, human, np.arange(6, nv))
    names = {human.model.names[human.model.getJointId(j.name)] for j in human.joints if j.idx_q in
             {iq for iq, *_ in prior.joints}}
    assert {"leftUpperArm_shoulder", "rightUpperArm_shoulder", "leftThigh_hip", "rightThigh_hip"} <= names
    assert "torso_waist" not in names  # a wide trunk shows its twist
    k = 0.8
    energy = _energy_of(prior, human, k)
    q = human.random_configuration(np.random.default_rng(2), 60)
    assert energy(q) > 0
    _assert_gradient(prior, human, q, k)
    # a swing of the left upper arm about the shoulder's axis (across the arm) has no twist
    arm = next(j for j in human.joints if j.name == "leftUpperArm_shoulder")
    assert energy(_turned(human, arm, [0.7, 0.0, 0.0])) == pytest.approx(0.0, abs=1e-20)
    assert TwistPrior.of(1.0, load(DIR / "fullbody.kms", root="free"), np.arange(6, 23)) is None


def _ground_energy(robot, q, prior, k):
    """E = k/2 max(min_i h_i, 0)^2 + k/2 sum_i min(h_i, 0)^2 from the body poses: h_i the
    lowest height of foot i's ellipsoid along up above the floor, min over the ellipsoid
    of up . (t + R L s), |s| = 1, which is up . t - |L R^T up|."""
    poses = robot.body_poses(q)
    h = np.array([poses[i].translation @ prior.up - np.linalg.norm(prior.inner[i] * (poses[i].rotation.T @ prior.up))
                  for i in prior.feet]) - prior.height
    return 0.5 * k * max(h.min(), 0.0) ** 2 + 0.5 * k * float(np.sum(np.minimum(h, 0.0) ** 2)), h


def _ground_prior(robot, q, height=None, up=(0.0, 1.0, 0.0)):
    inner = np.array([robot.inner(b) for b in robot.bodies])
    return GroundPrior.of(1.0, robot, up, inner, q, height)


def test_ground_prior_is_the_gradient_of_its_energy():
    """The ground prior's gradient against finite differences (pin.integrate) of its
    energy, computed from the body poses, with the lowest foot above the floor (pulled
    down), with feet below it (pushed up), on a tilted 'up'; its feet are the human's."""
    human = load(DIR / "human.kms", root="free")
    model, data, nv = human.model, human.data, human.model.nv
    up = np.array([0.1, 1.0, 0.2]) / np.linalg.norm([0.1, 1.0, 0.2])
    prior = _ground_prior(human, human.q_rest, up=up)
    assert {human.bodies[i] for i in prior.feet} >= {"leftFoot", "rightFoot"}
    assert not {"leftThigh", "torso", "leftHand"} & {human.bodies[i] for i in prior.feet}
    k, eps = 0.8, 1e-6
    rng = np.random.default_rng(1)
    for lift in (0.05, -0.04, -0.2):
        q = human.random_configuration(rng, 25)
        q[:3] = human.q_rest[:3] + lift * up
        q[3:7] = pin.Quaternion(pin.exp3(rng.uniform(-0.2, 0.2, 3))).coeffs()
        e, h = _ground_energy(human, q, prior, k)
        assert (h.min() > 0) == (lift > 0)
        A, g = np.zeros((nv, nv)), np.zeros(nv)
        pin.computeJointJacobians(model, data, q)
        assert prior.add(A, g, q, data, k) == pytest.approx(e, rel=1e-12)
        fd = [(_ground_energy(human, pin.integrate(model, q, eps * v), prior, k)[0]
               - _ground_energy(human, pin.integrate(model, q, -eps * v), prior, k)[0]) / (2 * eps) for v in np.eye(nv)]
        np.testing.assert_allclose(g, fd, atol=1e-7)
        assert np.abs(g).max() > 1e-3
        # Gauss-Newton: A = k sum of the active points' gradient outer products, positive semi-definite
        assert np.linalg.eigvalsh(A).min() > -1e-12 and np.trace(A) > 0


def test_ground_prior_pushes_a_foot_below_the_floor_up_and_leaves_one_on_it():
    """The static update (eq. 2.28) with the bodies' springs holding a pose: a floor 3 cm
    above the feet pushes them up towards it (the root rises); a floor at the lowest foot
    point (the default, taken at that pose) adds no force, and the pose stays."""
    human = load(DIR / "human.kms", root="free")
    model, data, nv = human.model, human.data, human.model.nv
    inner = np.array([human.inner(b) for b in human.bodies])
    q = human.q_rest.copy()
    q[7:] += np.radians(np.random.default_rng(2).uniform(-5, 5, human.nq - 7))
    q = pin.normalize(model, q)
    on = _ground_prior(human, q)
    _, h_on = _ground_energy(human, q, on, 1.0)
    assert h_on.min() == pytest.approx(0.0, abs=1e-12)
    A, g = np.zeros((nv, nv)), np.zeros(nv)
    pin.computeJointJacobians(model, data, q)
    assert on.add(A, g, q, data, 1.0) == 0.0
    assert not g.any() and not A.any()
    rng = np.random.default_rng(3)
    H = [(lambda B: B @ B.T + 6 * np.eye(6))(rng.normal(size=(6, 6))) for _ in human.bodies]

    def update(prior):
        fits = [BodyFit(P, h.copy(), 0.0, 0.0) for P, h in zip(human.body_poses(q), H)]
        return full_update(human, q.copy(), fits, inner, 0.0, 20, [prior])

    np.testing.assert_allclose(update(on), q, atol=1e-9)
    below = _ground_prior(human, q, height=on.height + 0.03)
    q_up = update(below)
    _, h_after = _ground_energy(human, q_up, below, 1.0)
    _, h_before = _ground_energy(human, q, below, 1.0)
    assert h_before.min() == pytest.approx(-0.03, abs=1e-9)
    assert -0.03 < h_after.min() < -0.003  # pushed up, against the springs
    assert q_up[1] > q[1] + 0.003  # the root rises (world y is up)


def test_tracker_takes_the_floor_at_the_first_pose_with_the_measured_sizes():
    """``ground``: the tracker's prior has the floor at the feet's lowest point at q0
    with the sizes in use, taken again once the first frame has measured them; a given
    ``ground_height`` is kept; off by default and on a fixed root.  (The measured sizes
    are the prior's own array: later refinements move its feet with them.)"""
    robot = _robot("lowerbody")
    cams = _cams(robot, 1)
    qt = robot.q_rest.copy()
    masks = render(robot, qt, cams)
    assert not any(isinstance(p, GroundPrior) for p in Tracker(robot, cams, q0=qt).ecm.priors)
    tr = Tracker(robot, cams, q0=qt, ground=0.5, scales=np.full((len(robot.bodies), 3), 1.2))
    tr.calibrate(masks)  # as the first frame's step does
    (prior,) = [p for p in tr.ecm.priors if isinstance(p, GroundPrior)]
    assert prior.weight == 0.5 and np.abs(tr.scales - 1.2).max() > 0.01  # the sizes were measured
    _, h = _ground_energy(robot, qt, prior, 1.0)
    assert h.min() == pytest.approx(0.0, abs=1e-12)  # at q0 with the measured sizes
    assert prior.inner is tr.sizes.inner
    given = Tracker(robot, cams, q0=qt, ground=0.5, ground_height=-2.5)
    given.step(masks)
    assert [p.height for p in given.ecm.priors if isinstance(p, GroundPrior)] == [-2.5]
    fixed = Tracker(load(DIR / "lowerbody.kms", root="spec"), cams, ground=0.5, calibrate_sizes=False)
    assert not any(isinstance(p, GroundPrior) for p in fixed.ecm.priors)


def test_spine_twist_prior_tells_a_half_turned_trunk_apart():
    """A trunk turned half a turn about its bone casts the silhouettes of the upright one
    (an ellipsoid is symmetric under a half turn; at rest the arms are twins, so they trade
    places): the human's torso so turned renders the same masks.  The spine prior
    (``spine_twist``) is on the joints from the root to the body the arms branch from,
    its twist taken about that body's bone, and its energy is k/2 theta^2 for a turn
    theta about the bone (pi for the half turn), 0 for a bend across it; its gradient
    matches finite differences of that energy."""
    from kms2pin.ecm.priors import TwistPrior, bone_axis, spine_joints

    human = load(DIR / "human.kms", root="free")
    assert [j.name for j in spine_joints(human)] == ["torso_waist"]
    assert spine_joints(load(DIR / "lowerbody.kms", root="free")) == []  # the legs leave the root itself
    assert spine_joints(load(DIR / "human.kms")) == []  # a fixed root has no spine to hold
    waist = spine_joints(human)[0]
    # the torso's bvecs: the waist below, the neck above, the shoulders level and symmetric
    R_align = human.model.frames[human.model.getFrameId("torso", pin.FrameType.BODY)].placement.rotation
    np.testing.assert_allclose(R_align.T @ bone_axis(human, waist), [0.0, 1.0, 0.0], atol=1e-12)
    prior = TwistPrior.spine(1.0, human, np.arange(6, human.model.nv))
    k = 0.7
    energy = _energy_of(prior, human, k)

    def turned(rotvec):
        return _turned(human, waist, rotvec)

    axis = bone_axis(human, waist)
    half = turned(np.pi * axis)
    cams = _cams(human)
    upright = render(human, human.q_rest, cams[:1])[0]

    def changed(q):  # the share of the foreground pixels that change
        return np.sum(render(human, q, cams[:1])[0] != upright) / upright.sum()

    assert upright.sum() > 2000
    assert changed(half) < 0.03 < 0.2 < changed(turned(0.5 * np.pi * axis))  # the quarter turn shows
    assert energy(half) == pytest.approx(0.5 * k * np.pi**2, rel=1e-9)
    assert energy(turned(0.3 * axis)) == pytest.approx(0.5 * k * 0.09, rel=1e-9)
    across = np.cross(axis, [0.0, 0.0, 1.0])
    assert energy(turned(0.4 * across / np.linalg.norm(across))) == pytest.approx(0.0, abs=1e-20)
    g = _assert_gradient(prior, human, human.random_configuration(np.random.default_rng(5), 60), k)
    assert np.flatnonzero(g).min() >= waist.idx_v and np.flatnonzero(g).max() < waist.idx_v + 3
    # the tracker takes it as an option
    tr = Tracker(human, cams, spine_twist=0.05)
    assert any(isinstance(p, TwistPrior) and p.weight == 0.05 for p in tr.ecm.priors)


def test_a_twist_prior_with_a_free_range_is_a_soft_limit():
    """``twist_free``: the round limbs' twist prior leaves a twist within the range free
    (energy 0 for 80° with a 90° range) and is k/2 (|theta| - range)^2 past it (150°:
    k/2 (60°)^2), with the gradient of that energy; a bend across the limb costs nothing."""
    from kms2pin.ecm.priors import TwistPrior

    human = load(DIR / "human.kms", root="free")
    prior = TwistPrior.of(1.0, human, np.arange(6, human.model.nv), free_deg=90.0)
    arm = next(j for j in human.joints if j.name == "leftUpperArm_shoulder")
    axis = next(a for iq, _, a, _ in prior.joints if iq == arm.idx_q)  # the arm's long axis, joint axes
    k = 0.6
    energy = _energy_of(prior, human, k)

    def turned(rotvec):
        return _turned(human, arm, rotvec)

    assert energy(human.q_rest) == 0.0
    assert energy(turned(np.radians(80) * axis)) == 0.0
    assert energy(turned(-np.radians(150) * axis)) == pytest.approx(0.5 * k * np.radians(60) ** 2, rel=1e-9)
    across = np.cross(axis, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    assert energy(turned(2.5 * across)) == pytest.approx(0.0, abs=1e-20)
    q = turned(np.radians(140) * axis + 0.3 * across)
    assert energy(q) > 0
    g = _assert_gradient(prior, human, q, k)
    assert set(np.flatnonzero(g)) <= set(range(arm.idx_v, arm.idx_v + 3))  # the other limbs are within range
    tr = Tracker(human, _cams(human), twist_prior=1.0, twist_free=90.0, spine_twist=1.0, spine_free=30.0)
    assert sorted(p.free for p in tr.ecm.priors if isinstance(p, TwistPrior)) == pytest.approx(np.radians([30, 90]))


def test_rest_prior_pulls_towards_the_starting_pose_with_rest_pose_start():
    """``rest_pose="start"``: the rest prior's pose is the track's q0 (kept over a restart),
    not the spec's rest; a bad value is refused."""
    robot, qs = cmu_walker()
    cams = [Camera.look_at(qs[0][:3] + np.array([5.0, 1.0, 3.0]), qs[0][:3], width=320, height=240, fov_deg=30.0)]
    for which, expected in (("spec", robot.q_rest), ("start", qs[0])):
        tr = Tracker(robot, cams, q0=qs[0], rest_prior=0.01, rest_pose=which, calibrate_sizes=False)
        tr.restart(qs[10])
        (prior,) = [p for p in tr.ecm.priors if isinstance(p, RestPrior)]
        np.testing.assert_array_equal(prior.q_rest, expected)
    with pytest.raises(ValueError, match="rest_pose"):
        Tracker(robot, cams, rest_pose="first")


def test_rest_prior_towards_a_t_pose_pulls_a_seen_walker_off_the_truth():
    """One frame's ECM from the true pose on clean silhouettes (one camera 6 m away) of a
    real walker whose spec rests in the T-pose: the rest prior towards that rest pulls the
    arms up, off the truth (measured 4.5 % of the height, fit 0.83); towards the starting
    pose, here the frame's own, it leaves the walker within 1 % (the springs' small
    bias), fitting better."""
    robot, qs = cmu_walker()
    q = qs[30]
    cams = [Camera.look_at(q[:3] + np.array([5.0, 1.0, 3.0]), q[:3], width=320, height=240, fov_deg=30.0)]
    masks = render(robot, q, cams)
    out = {}
    for which in ("spec", "start"):
        tr = Tracker(robot, cams, q0=q, rest_prior=0.01, rest_pose=which, upright=0.1, calibrate_sizes=False)
        qe, fit = tr.refine(q, masks)
        out[which] = (centre_error(robot, qe, q), fit)
    assert out["spec"][0] > 2.0 and out["start"][0] < 1.0, out
    assert out["start"][1] > out["spec"][1] + 0.05, out


def _midline_offsets(robot, q):
    """The upper arms' and thighs' centres' offsets from the sagittal plane of the torso
    and pelvis (world, from the body poses: the plane's normal is the left/right axis of
    the spec's rest pose, turned with the torso or pelvis), positive on their own side."""
    poses, rest = robot.body_poses(q), robot.body_poses(robot.q_rest)
    out = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        for body, anchor in ((f"{side}UpperArm", "torso"), (f"{side}Thigh", "pelvis")):
            a, b = robot.index(anchor), robot.index(body)
            lateral = rest[robot.index(f"left{body[len(side):]}")].translation - rest[robot.index(f"right{body[len(side):]}")].translation
            n = poses[a].rotation @ (rest[a].rotation.T @ lateral) / np.linalg.norm(lateral)
            out.append(sign * float(n @ (poses[b].translation - poses[a].translation)))
    return np.array(out)


def _arm_swung(human, angle):
    """The rest pose with the left upper arm swung by ``angle`` (rad) about the shoulder's
    front-back axis: up and in, towards the torso's midline (at 1.5 rad its centre is
    3 cm from it, against 21.5 cm at rest)."""
    arm = next(j for j in human.joints if j.name == "leftUpperArm_shoulder")
    return _turned(human, arm, [0.0, 0.0, angle])


def test_midline_prior_is_the_gradient_of_its_energy_and_off_on_its_own_side():
    """The midline prior on the human (its twin limbs' roots: the upper arms on the
    torso, the thighs on the pelvis): its offsets are those of the body poses (the
    sagittal plane turned with the anchor); off (no energy, no terms) at rest and while
    every root keeps more than MIDLINE_MARGIN of its rest offset; past that, energy
    k/2 sum min(h, 0)^2 with h = offset - MIDLINE_MARGIN * rest offset, its gradient
    against finite differences (pin.integrate), its Gauss-Newton matrix positive
    semi-definite.  A model without twins has none."""
    human = load(DIR / "human.kms", root="free")
    model, data, nv = human.model, human.data, human.model.nv
    prior = MidlinePrior.of(1.0, human)
    rest = _midline_offsets(human, human.q_rest)
    assert (rest > 0.03).all()
    # without feet given every root is taken for an arm's
    np.testing.assert_allclose(np.sort(prior.least), np.sort(MIDLINE_MARGIN["arms"] * rest), rtol=1e-9)
    k = 0.6

    def energy(q):
        h = _midline_offsets(human, q) - MIDLINE_MARGIN["arms"] * rest
        return 0.5 * k * float(np.sum(np.minimum(h, 0.0) ** 2)), h

    for q, crossed in ((human.q_rest, False), (_arm_swung(human, 0.3), None), (_arm_swung(human, 1.5), True)):
        e, h = energy(q)
        if crossed is not None:
            assert (h.min() < 0) == crossed
        A, g = np.zeros((nv, nv)), np.zeros(nv)
        pin.computeJointJacobians(model, data, q)
        assert prior.add(A, g, q, data, k) == pytest.approx(e, rel=1e-12, abs=1e-300)
        if e == 0.0:
            assert not A.any() and not g.any()
            continue
        eps = 1e-6
        fd = [(energy(pin.integrate(model, q, eps * v))[0] - energy(pin.integrate(model, q, -eps * v))[0]) / (2 * eps)
              for v in np.eye(nv)]
        np.testing.assert_allclose(g, fd, atol=1e-8)
        assert np.abs(g).max() > 1e-3
        assert np.linalg.eigvalsh(A).min() > -1e-12 and np.trace(A) > 0
    # a random pose with the legs and arms anywhere: the gradient still that of the energy
    q = human.random_configuration(np.random.default_rng(4), 90)
    assert _energy_of(prior, human, k)(q) > 0.0  # a root pushed: the check below is not of zeros
    assert np.abs(_assert_gradient(prior, human, q, k)).max() > 1e-3
    assert MidlinePrior.of(1.0, load(DIR / "puma600.kms")) is None
    # given the feet (as the tracker finds them at its first pose), the thighs keep the legs'
    # margin; a kind whose margin is None (by default the legs) is left out
    inner = np.array([human.inner(b) for b in human.bodies])
    on = feet(human, human.q_rest, inner, (0.0, 1.0, 0.0))[0]
    shares = {"arms": 0.5, "legs": 0.1}
    both = MidlinePrior.of(1.0, human, on, shares)
    names = [human.model.names[int(j)] for j in both.joints[:, 0]]
    kept = dict(zip(names, both.least))
    offset = dict(zip(["leftUpperArm_shoulder", "leftThigh_hip", "rightUpperArm_shoulder", "rightThigh_hip"], rest))
    assert sorted(kept) == sorted(offset)
    for name, least in kept.items():
        share = shares["legs" if "Thigh" in name else "arms"]
        assert least == pytest.approx(share * offset[name], rel=1e-9)
    arms = MidlinePrior.of(1.0, human, on)
    assert MIDLINE_MARGIN["legs"] is None
    assert sorted(human.model.names[int(j)] for j in arms.joints[:, 0]) == ["leftUpperArm_shoulder",
                                                                            "rightUpperArm_shoulder"]
    assert MidlinePrior.of(1.0, human, on, {"arms": None, "legs": None}) is None
    assert MidlinePrior.of(1.0, human, on, {"arms": 0.5}).least.size == 2  # a kind not named: left out
    # a first pose with one foot off the floor: that thigh is a leg still (its twin's pelvis)
    one_foot = [i for i in on if "right" in human.bodies[i]]
    assert one_foot and len(one_foot) < len(on)
    legs = MidlinePrior.of(1.0, human, one_foot, {"arms": None, "legs": 0.1})
    assert sorted(human.model.names[int(j)] for j in legs.joints[:, 0]) == ["leftThigh_hip", "rightThigh_hip"]
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match="midline margin of the legs"):
            MidlinePrior.of(1.0, human, on, {"arms": 0.5, "legs": bad})
    with pytest.raises(TypeError):
        MIDLINE_MARGIN["arms"] = 0.2  # the default cannot be changed by a caller


def test_midline_prior_pushes_an_arm_swung_to_the_chest_back_out():
    """The static update (eq. 2.28) with the bodies' springs holding a pose whose left
    upper arm's centre is swung to within a sixth of its rest offset of the torso's
    midline: the springs alone leave it there, with the prior it ends further out, past
    the margin's pull towards the springs' pose; a pose with every root out past the
    margin stays as it is."""
    human = load(DIR / "human.kms", root="free")
    inner = np.array([human.inner(b) for b in human.bodies])
    rng = np.random.default_rng(3)
    H = [(lambda B: B @ B.T + 6 * np.eye(6))(rng.normal(size=(6, 6))) for _ in human.bodies]
    prior = MidlinePrior.of(10.0, human)  # these springs are stiff: 1 pushes 2 mm

    def update(q, terms):
        fits = [BodyFit(P, h.copy(), 0.0, 0.0) for P, h in zip(human.body_poses(q), H)]
        return full_update(human, q.copy(), fits, inner, 0.0, 20, terms)

    ok = _arm_swung(human, 0.3)
    np.testing.assert_allclose(update(ok, [prior]), ok, atol=1e-9)
    near = _arm_swung(human, 1.5)
    before = _midline_offsets(human, near)[0]
    assert before < MIDLINE_MARGIN["arms"] * _midline_offsets(human, human.q_rest)[0] / 3
    held = _midline_offsets(human, update(near, []))[0]
    pushed = _midline_offsets(human, update(near, [prior]))[0]
    assert held == pytest.approx(before, abs=1e-6)  # the springs alone keep it there
    assert pushed > held + 0.04


def test_tracker_takes_the_midline_prior_as_an_option():
    """``midline``: the tracker adds the prior on the arms of a free root with twin limbs
    (the legs, the limbs that hold the feet at the first pose, left out); none by default
    or with a fixed root."""
    human = load(DIR / "human.kms", root="free")
    cams = _cams(human)
    (prior,) = [p for p in Tracker(human, cams, midline=0.5).ecm.priors if isinstance(p, MidlinePrior)]
    assert prior.weight == 0.5 and len(prior.least) == 2
    whole = MidlinePrior.of(1.0, human, (), {"arms": 1.0, "legs": 1.0})
    rest = {int(j): x for j, x in zip(whole.joints[:, 0], whole.least)}  # the offsets at rest, by joint
    np.testing.assert_allclose(prior.least, [MIDLINE_MARGIN["arms"] * rest[int(j)] for j in prior.joints[:, 0]])
    assert not any(isinstance(p, MidlinePrior) for p in Tracker(human, cams).ecm.priors)
    # midline_legs: the thighs too, each kept out past that share of its offset at rest
    (legs,) = [p for p in Tracker(human, cams, midline=0.5, midline_legs=0.1).ecm.priors
               if isinstance(p, MidlinePrior)]
    names = [human.model.names[int(j)] for j in legs.joints[:, 0]]
    assert sorted(names) == ["leftThigh_hip", "leftUpperArm_shoulder", "rightThigh_hip", "rightUpperArm_shoulder"]
    share = {"Thigh": 0.1, "UpperArm": MIDLINE_MARGIN["arms"]}
    np.testing.assert_allclose(legs.least, [share["Thigh" if "Thigh" in n else "UpperArm"] * rest[int(j)]
                                            for n, j in zip(names, legs.joints[:, 0])])
    with pytest.raises(OptionError, match="midline_legs .* set midline above 0"):
        Tracker(human, cams, midline_legs=0.1)
    with pytest.raises(OptionError, match="midline_legs must be >= 0.0 and <= 1.0 or None"):
        Tracker(human, cams, midline=1.0, midline_legs=1.5)
    fixed = load(DIR / "human.kms")
    assert not any(isinstance(p, MidlinePrior) for p in Tracker(fixed, _cams(fixed), midline=0.5).ecm.priors)
