"""The limb search: limbs swung, put back at rest, twins exchanged."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.limbs import limb_joints
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.robot import load

from ._tracking import (
    DIR,
    _cams,
    _folded_finger_frame,
    _robot,
    centre_error,
    joint_errors,
)


def test_limbs_are_the_chains_off_the_root_and_the_branching_bodies():
    fullbody = load(DIR / "fullbody.kms", root="free")
    assert limb_joints(fullbody) == [
        "leftThigh_hip", "rightThigh_hip", "trunk_waist", "leftUpperArm_shoulder", "rightUpperArm_shoulder",
    ]
    hand = _robot("jplhand")  # the palm's wrist hangs off the free root, the fingers off the palm
    assert limb_joints(hand) == ["palm_wrist", "lowFinger1_lowerJoint", "lowFinger2_lowerJoint", "lowThumb_lowerJoint"]
    # on the spec's root the wrist is on the world: the root is not a limb
    assert "palm_wrist" not in limb_joints(load(DIR / "jplhand.kms"))
    assert Tracker(fullbody, _cams(fullbody, 1)).options.limbs.limb_search
    assert Tracker(fullbody, _cams(fullbody, 2)).options.limbs.limb_search
    assert not Tracker(fullbody, _cams(fullbody, 2), limb_search=False).options.limbs.limb_search


@pytest.mark.parametrize("frame", [120, 246])
def test_limb_search_swings_back_an_arm_stuck_on_the_wrong_side(frame):
    """One camera, clean silhouettes of the walk: the left arm started on the other
    side of its rest angle (the shoulder's swing reflected) is a local minimum of ECM
    (measured: still 39-42 deg off after a frame's iterations), and the limb search
    finds the true side."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    qt = make_motion(robot, "walk", 300)[frame]
    cams = [Camera.default()]
    masks = render(robot, qt, cams)
    iq = robot.model.joints[robot.model.getJointId("leftUpperArm_shoulder")].idx_q
    q0 = qt.copy()
    q0[iq] = 2.0 * robot.q_rest[iq] - qt[iq]
    assert np.degrees(abs(q0[iq] - qt[iq])) > 30.0
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert np.degrees(abs(q_ecm[iq] - qt[iq])) > 25.0  # ECM alone stays on the wrong side
    q, fit, move = tr.swing_limbs(q0, masks)
    assert move.kind == "swing" and move.joints == ("leftUpperArm_shoulder",)
    assert fit > fit_ecm + 0.03
    assert joint_errors(robot, q, qt).max() < 3.0
    assert centre_error(robot, q, qt) < 0.5
    np.testing.assert_array_equal(tr.q, qt)  # the tracker is left as it was
    # from the truth there is nothing to swing
    q, fit, move = tr.swing_limbs(qt, masks)
    assert move is None and joint_errors(robot, q, qt).max() < 3.0


@pytest.mark.parametrize("frame", [258, 296])
def test_limb_search_exchanges_arms_that_took_each_others_place(frame):
    """One camera, side-on, clean silhouettes of the walk (left arm back, right arm
    forward): the left arm started on the right arm's image and the right arm hidden
    near rest behind the trunk (as seen after the arms cross) is a local minimum of ECM
    (both arms stay more than 15 deg off) that no single limb's swing leaves; the
    exchange of the twin limbs finds the truth."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    qt = make_motion(robot, "walk", 300)[frame]
    cams = [Camera.default()]
    masks = render(robot, qt, cams)
    m = robot.model
    il, ir = (m.joints[m.getJointId(f"{s}UpperArm_shoulder")].idx_q for s in ("left", "right"))
    assert np.degrees(qt[ir] - qt[il]) > 30.0  # the arms well apart
    q0 = qt.copy()
    q0[il] = qt[ir]
    q0[ir] = robot.q_rest[ir] - 0.3 * (qt[ir] - robot.q_rest[ir])
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert min(np.degrees(abs(q_ecm[i] - qt[i])) for i in (il, ir)) > 15.0
    pairs, tr.limbs.pairs = tr.limbs.pairs, []  # the single limbs' swings alone do not help
    assert tr.swing_limbs(q0, masks)[2] is None
    tr.limbs.pairs = pairs
    q, fit, move = tr.swing_limbs(q0, masks)
    assert move.kind == "exchange" and move.joints == ("leftUpperArm_shoulder", "rightUpperArm_shoulder")
    assert fit > fit_ecm + 0.005
    assert joint_errors(robot, q, qt).max() < 3.0
    assert centre_error(robot, q, qt) < 0.5


def test_two_views_exchange_no_twins():
    """The arms traded as in the test above, seen by a second, raised camera too: two
    views tell twins apart, so the limb search offers no exchange (with one view it is
    what finds the truth; on a real walker seen by two cameras exchanges that fit a
    little better traded the legs)."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    qt = make_motion(robot, "walk", 300)[258]
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=qt[:3])]
    masks = render(robot, qt, cams)
    m = robot.model
    il, ir = (m.joints[m.getJointId(f"{s}UpperArm_shoulder")].idx_q for s in ("left", "right"))
    q0 = qt.copy()
    q0[il] = qt[ir]
    q0[ir] = robot.q_rest[ir] - 0.3 * (qt[ir] - robot.q_rest[ir])
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    kinds = {move.kind for move, _ in tr.limbs.candidates(q0)}
    assert "exchange" in kinds and "exchange" not in {move.kind for move, _ in tr.limbs.candidates(q0, exchange=False)}
    move = tr.swing_limbs(q0, masks)[2]
    assert move is None or move.kind != "exchange"
    one = Tracker(robot, cams[:1], q0=qt, calibrate_sizes=False)
    assert one.swing_limbs(q0, masks[:1])[2].kind == "exchange"


@pytest.mark.parametrize("seed,frame,off_deg", [(0, 40, (-40, 100)), (2, 40, (30, -120))])
def test_limb_search_unfolds_a_finger_folded_the_wrong_way(seed, frame, off_deg):
    """One camera, clean silhouettes of the hand's random motion: the first finger's
    middle and tip joints started far off (the tip folded back, as seen on noisy
    one-camera tracks) is a local minimum of ECM (the tip stays more than 60 deg off);
    the limb search's candidate with the finger put back at rest below its first joint
    finds the truth."""
    robot = _robot("jplhand")
    qt = make_motion(robot, "random", 300, np.random.default_rng(seed))[frame]
    cams = [Camera.default()]
    masks = render(robot, qt, cams)
    m = robot.model
    mid, tip = (m.joints[m.getJointId(n)].idx_q for n in ("midFinger1_lowerJoint", "tip1_joint"))
    q0 = qt.copy()
    q0[mid] += np.radians(off_deg[0])
    q0[tip] += np.radians(off_deg[1])
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert np.degrees(abs(q_ecm[tip] - qt[tip])) > 60.0  # ECM alone keeps the fold
    q, fit, move = tr.swing_limbs(q0, masks)
    assert move.kind == "reset" and move.joints == ("lowFinger1_lowerJoint",)
    assert fit > fit_ecm + 0.05
    assert np.degrees(np.abs(q[[mid, tip]] - qt[[mid, tip]])).max() < 5.0
    # one view fixes the rest only so far (the thumb's lower joint, the hand's distance)
    assert joint_errors(robot, q, qt).max() < 10.0 and centre_error(robot, q, qt) < 1.0


def test_with_two_cameras_a_folded_finger_gets_the_limb_search_by_default():
    """Front and side cameras, clean silhouettes of the hand: the second finger started
    folded the wrong way (tip 120 deg off) is a local minimum of ECM with both views
    too, and the default tracker's step puts the finger back at rest and finds it."""
    results, off = {}, {}
    for search in (None, False):
        _, results[search], qt, tip = _folded_finger_frame(_cams(_robot("jplhand"), 2), 2, (30.0, -120.0), search)
        off[search] = np.degrees(abs(results[search].q[tip] - qt[tip]))
    assert off[False] > 60.0 and not results[False].flags
    assert off[None] < 5.0 and results[None].fit > results[False].fit + 0.02
    assert results[None].flags == ("put the joints below 'lowFinger2_lowerJoint' back at rest",)


@pytest.mark.parametrize("n_cams", [1, 2])
def test_twin_limbs_are_tried_exchanged_after_crossing_with_one_camera_only(n_cams, monkeypatch):
    """Two views tell the arms apart after they cross: the exchange after a crossing
    (which ran on every crossing and cost the two-camera walkers 0.55-0.70x the
    frames/s) is tried with one camera only; the search on a falling fit runs with both
    (asked for on every frame by a drop of -1, once the running fit has settled: from
    frame 1 with a smoothing of 1; a spy stands in for it, so the test stays fast)."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    walk = make_motion(robot, "walk", 300)
    cams = _cams(robot, n_cams)
    tr = Tracker(robot, cams, q0=walk[0], calibrate_sizes=False, mirror_hypothesis=False, swap_hypothesis=False,
                 limb_hypothesis=False, limb_search_drop=-1.0, hypothesis_smoothing=1.0)
    calls, searches = [], []
    real = tr.limbs.exchange_crossed
    monkeypatch.setattr(tr.limbs, "exchange_crossed", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(tr.limbs, "search", lambda q, fit, *a, **k: searches.append((tr.frame, k)) or (q, fit, None))
    for f in range(3):
        tr.step(render(robot, walk[f], cams))
    assert tr.options.limbs.limb_search and len(calls) == (2 if n_cams == 1 else 0)
    assert searches == [(1, {}), (2, {})]  # the full search (not screen_only), with either camera count


def test_a_finger_put_back_at_rest_is_flagged_and_carries_no_velocity():
    """Tracking the hand with one camera from the truth, then a frame starting with the
    first finger folded the wrong way: its fit falls, the limb search puts the finger
    back at rest below its first joint, and the frame says so; the move is no motion,
    so the finger's joints are not predicted to go on."""
    results = {}
    for search in (False, True):
        tr, r, qt, tip = _folded_finger_frame([Camera.default()], 1, (-40.0, 100.0), search)
        results[search] = r
        err = np.degrees(abs(r.q[tip] - qt[tip]))
        assert (err < 5.0) if search else (err > 60.0)
    assert results[True].flags == ("put the joints below 'lowFinger1_lowerJoint' back at rest",)
    assert not results[False].flags
    v, m = tr.ecm.motion.velocity(tr.state.prev, tr.q), tr.robot.model
    for n in ("midFinger1_lowerJoint", "tip1_joint"):
        assert v[m.joints[m.getJointId(n)].idx_v] == 0.0


@pytest.mark.parametrize("hypothesis", [True, False])
def test_a_limb_search_candidate_is_tracked_beside_the_pose_and_becomes_it_when_it_fits_better(hypothesis):
    """One camera, clean silhouettes of the hand, the first finger folded the wrong way
    on frame 40 as above, but the search on a falling fit kept out (its drop set to 1):
    the fit falls by more than ``limb_hypothesis_drop``, so the limb search's best
    screened candidate (the finger put back at rest) is tracked beside the pose, with no
    velocity in the moved finger, and becomes the pose once its running fit leads by
    ``limb_margin`` (flag).  Without the hypothesis the fold stays."""
    cams = [Camera.default()]
    tr, r, qt, tip = _folded_finger_frame(cams, 1, (-40.0, 100.0), True, limb_search_drop=1.0,
                                          limb_hypothesis=hypothesis)
    assert not r.flags and np.degrees(abs(r.q[tip] - qt[tip])) > 60.0
    if hypothesis:
        alt = tr.hypotheses.alts["limb"]
        assert alt.fit > r.fit + 0.003 and alt.score > tr.state.running.score  # it fit this frame better
        assert np.degrees(abs(alt.q[tip] - qt[tip])) < 6.0 and alt.prev[tip] == alt.q[tip]  # measured 4.8 deg
    else:
        assert not tr.hypotheses.alts
    motion = make_motion(tr.robot, "random", 300, np.random.default_rng(0))
    flags = []
    for f in range(41, 46):
        r = tr.step(render(tr.robot, motion[f], cams))
        flags += r.flags
    err = np.degrees(abs(r.q[tip] - motion[45][tip]))
    if hypothesis:
        assert flags == ["switched to the limb-search hypothesis"] and err < 5.0
    else:
        assert not flags and err > 60.0


def test_the_limb_hypothesis_is_on_with_one_camera_and_the_limb_search():
    robot = _robot("jplhand")
    assert Tracker(robot, [Camera.default()]).options.limbs.limb_hypothesis
    assert not Tracker(robot, _cams(robot, 2)).options.limbs.limb_hypothesis
    off = Tracker(robot, [Camera.default()], limb_search=False, limb_hypothesis=True)
    assert not off.options.limbs.limb_hypothesis


def test_arms_that_have_just_crossed_get_their_exchange_tried():
    """One camera, clean silhouettes of the walk: frames 251-255 tracked, each from its
    true pose, while the arms cross (frame 252, side-on: they overlap).  Frame 256
    starts from the place the previous test starts from: the left arm on the right
    arm's image, the right arm hidden near rest.  The fit hardly falls (the search on
    a falling fit is kept out of it here), but the exchange tried after a crossing
    finds the truth; without the limb search the arms stay off."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    walk = make_motion(robot, "walk", 300)
    cams = [Camera.default()]
    m = robot.model
    arms = [m.joints[m.getJointId(f"{s}UpperArm_shoulder")] for s in ("left", "right")]
    il, ir = (j.idx_q for j in arms)
    assert np.degrees(abs(walk[252][il] - walk[252][ir])) < 1.0  # the arms cross at frame 252
    qt = walk[256]
    bad = qt.copy()
    bad[il] = qt[ir]
    bad[ir] = robot.q_rest[ir] - 0.3 * (qt[ir] - robot.q_rest[ir])
    out = {}
    for search in (False, True):
        tr = Tracker(robot, cams, q0=walk[251], prediction="previous", calibrate_sizes=False,
                     mirror_hypothesis=False, swap_hypothesis=False, limb_search=search, limb_search_drop=1.0)
        for f in range(251, 257):
            tr.q[:] = walk[f] if f < 256 else bad
            r = tr.step(render(robot, walk[f], cams))
        out[search] = r, tr.ecm.motion.velocity(tr.state.prev, tr.q)[[j.idx_v for j in arms]]
    r, v = out[False]
    assert max(np.degrees(abs(r.q[i] - qt[i])) for i in (il, ir)) > 15.0  # measured 25 and 13 deg
    fit_without = r.fit
    r, v = out[True]
    assert "swapped 'leftUpperArm_shoulder' and 'rightUpperArm_shoulder'" in r.flags
    assert max(np.degrees(abs(r.q[i] - qt[i])) for i in (il, ir)) < 3.0
    assert joint_errors(robot, r.q, qt).max() < 6.0  # measured: the right elbow 4.9 deg
    assert r.fit > fit_without + 0.005
    assert not v.any()  # the exchange is no motion to carry on


def test_twins_exchanged_back_in_the_same_frame_are_not_flagged(monkeypatch):
    """The falling-fit search and the crossing's exchange can both exchange the same twin
    limbs in one frame: the limbs are then back in place, and the frame says nothing of
    an exchange.  Two different exchanges are both flagged."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    walk = make_motion(robot, "walk", 300)
    cams = [Camera.default()]
    arms = ("leftUpperArm_shoulder", "rightUpperArm_shoulder")
    legs = ("leftThigh_hip", "rightThigh_hip")
    flags = {}
    for second in (arms, legs):
        tr = Tracker(robot, cams, q0=walk[6], prediction="previous", calibrate_sizes=False,
                     mirror_hypothesis=False, swap_hypothesis=False, limb_search_drop=-1.0)
        for f in range(6, 11):  # the search on a falling fit waits for the running fit to settle
            tr.step(render(robot, walk[f], cams))
        monkeypatch.setattr(tr.limbs, "search", lambda q, fit, *a: (q, fit, tr.limbs.exchange_move(*arms)))
        monkeypatch.setattr(tr.limbs, "exchange_crossed",
                            lambda q, fit, *a, p=second: (q, fit, tr.limbs.exchange_move(*p)))
        flags[second] = tr.step(render(robot, walk[11], cams)).flags
    assert not any("swapped" in f for f in flags[arms])
    assert [f for f in flags[legs] if "swapped" in f] == [
        "swapped 'leftUpperArm_shoulder' and 'rightUpperArm_shoulder'",
        "swapped 'leftThigh_hip' and 'rightThigh_hip'",
    ]


def test_a_frame_that_falls_behind_the_running_fit_gets_the_limb_search():
    """Tracking the walk with one camera from the truth, then a frame whose starting
    pose has the arm swung the wrong way (as after a bad prediction): its fit falls
    below the running fit, the limb search runs and the frame is flagged."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    walk = make_motion(robot, "walk", 300)
    cams = [Camera.default()]
    iq = robot.model.joints[robot.model.getJointId("leftUpperArm_shoulder")].idx_q
    flags = {}
    for search in (False, True):
        tr = Tracker(robot, cams, q0=walk[240], prediction="previous", calibrate_sizes=False,
                     mirror_hypothesis=False, swap_hypothesis=False, limb_search=search)
        for f in range(240, 246):  # the search on a falling fit waits for the running fit to settle
            assert not any("swung" in x for x in tr.step(render(robot, walk[f], cams)).flags)
        tr.q[iq] = 2.0 * robot.q_rest[iq] - walk[246][iq]  # a bad start for frame 246
        r = tr.step(render(robot, walk[246], cams))
        flags[search] = r.flags
        err = np.degrees(abs(r.q[iq] - walk[246][iq]))
        assert (err < 3.0) if search else (err > 25.0)
        if search:  # the swing is no motion: the shoulder is not predicted to go on
            iv = robot.model.joints[robot.model.getJointId("leftUpperArm_shoulder")].idx_v
            assert tr.ecm.motion.velocity(tr.state.prev, tr.q)[iv] == 0.0
    assert "swung 'leftUpperArm_shoulder' the other way" in flags[True]
    assert not any("swung" in x for x in flags[False])


def test_the_search_on_a_falling_fit_waits_for_the_running_fit_to_settle(monkeypatch):
    """The running fit averages about 1 / hypothesis_smoothing frames (5); before that it
    is mostly the first frame's, which the calibration or the initialization fitted to
    that very frame.  With a search asked for on every frame (a drop of -1), the first
    five frames get none, the next ones do."""
    robot = load(DIR / "anatomical" / "fullbody.kms", root="free")
    walk = make_motion(robot, "walk", 300)
    cams = [Camera.default()]
    tr = Tracker(robot, cams, q0=walk[0], calibrate_sizes=False, mirror_hypothesis=False, swap_hypothesis=False,
                 limb_hypothesis=False, limb_search_drop=-1.0)
    frames = []
    monkeypatch.setattr(tr.limbs, "search", lambda q, fit, *a: frames.append(tr.frame) or (q, fit, None))
    for f in range(8):
        tr.step(render(robot, walk[f], cams))
    assert frames == [5, 6, 7]
