"""The reach search: a lost or missed limb re-aimed at the masks."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm import reach as reach_module
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.loop import new_timings
from kms2pin.ecm.masks import Views
from kms2pin.ecm.reach import ALWAYS_REFINED, REFINE_MARGIN, REFINED, TWISTS_DEG, ReachSearch, sphere_directions
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.errors import OptionError
from kms2pin.robot import load

from ._tracking import DIR


def test_the_trial_directions_cover_the_sphere_evenly():
    d = sphere_directions(40)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    gaps = np.degrees(np.arccos(np.clip(d @ sphere_directions(2000).T, -1, 1))).min(axis=0)
    assert gaps.max() < 25.0  # no direction of the sphere farther than 25 deg from a trial


def _arm_scene(truth_up: bool):
    """The human seen by two cameras with its left arm raised sideways (80 deg) or
    hanging at rest; the start has the arm the other way."""
    robot = load(DIR / "human.kms", root="free")
    up = robot.with_coordinates(robot.q_rest, {"leftUpperArm_shoulder_z": 80.0})
    qt, q0 = (up, robot.q_rest.copy()) if truth_up else (robot.q_rest.copy(), up)
    centre = robot.body_pose(qt, "torso").translation
    cams = [Camera.look_at(centre + [0.5, 0.2, 4.5], centre, width=640, height=480),
            Camera.look_at(centre + [-1.5, 3.5, 2.5], centre, width=640, height=480)]
    return robot, qt, q0, cams, render(robot, qt, cams)


def _arm_error_cm(robot, q, qt) -> float:
    """The largest centre error of the left arm's bodies (cm): the arm's twist about its
    own axis, which a nearly straight elbow hardly shows, is left out."""
    return max(100 * float(np.linalg.norm(robot.body_pose(q, b).translation - robot.body_pose(qt, b).translation))
               for b in ("leftUpperArm", "leftForeArm", "leftHand"))


@pytest.mark.parametrize("truth_up", [True, False])
def test_an_arm_ecm_leaves_on_the_wrong_side_is_re_aimed_at_the_masks(truth_up):
    """An arm started hanging by the trunk while the masks show it raised, or raised
    while they show it hanging: ECM alone stays far off (lying over the background, or
    leaving the arm's image unexplained), and the reach search brings the arm back."""
    robot, qt, q0, cams, masks = _arm_scene(truth_up)
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert _arm_error_cm(robot, q_ecm, qt) > 40.0  # a local minimum of ECM
    reach = ReachSearch(robot, tr.ecm)
    views = Views.of(cams, masks)
    arm = robot.index("leftUpperArm")
    assert arm in reach.lost(q_ecm, views) + reach.missed(q_ecm, views)
    q, fit, moves = reach.search(q_ecm, fit_ecm, views, views.binned({c: c.binned(2) for c in cams}), None, new_timings())
    assert moves[0].flag() == "pointed 'leftUpperArm_shoulder' at the masks"
    assert fit > fit_ecm + 0.05
    off = {b: np.linalg.norm(robot.body_pose(q, b).translation - robot.body_pose(qt, b).translation)
           for b in robot.bodies}
    assert off["leftUpperArm"] < 0.02 and off["leftForeArm"] < 0.02  # from 40-90 cm
    assert max(off.values()) < 0.08  # the hand's turn about the nearly straight arm is seen least


def test_a_pose_that_fits_has_nothing_lost_or_missed():
    robot, qt, _, cams, masks = _arm_scene(True)
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    reach = ReachSearch(robot, tr.ecm)
    views = Views.of(cams, masks)
    assert reach.lost(qt, views) == [] and reach.missed(qt, views) == []
    q, fit, moves = reach.search(qt, tr.fit(qt, masks), views, None, None, new_timings())
    assert moves == [] and np.array_equal(q, qt)


def test_the_reach_search_is_an_option_of_the_tracker_and_flags_its_moves():
    robot, qt, q0, cams, masks = _arm_scene(True)
    assert Tracker(robot, cams).reach is None
    tr = Tracker(robot, cams, q0=q0, calibrate_sizes=False, reach_search=True, prediction="previous")
    res = tr.step(masks)
    assert any(f.startswith("pointed '") and f.endswith("' at the masks") for f in res.flags)
    assert _arm_error_cm(robot, res.q, qt) < 2.0


def test_a_body_no_trial_of_which_beats_its_pose_costs_no_ecm_run(monkeypatch):
    """The limb is reported lost while it fits (the truth): every re-aimed trial scores
    below the pose, so none is screened or refined, and the body rests."""
    robot, qt, _, cams, masks = _arm_scene(True)
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    reach = ReachSearch(robot, tr.ecm)
    views = Views.of(cams, masks)
    arm = robot.index("leftUpperArm")
    monkeypatch.setattr(reach, "lost", lambda q, v: [arm])
    starts = reach._starts(qt, reach.reaches[arm], views)
    assert starts[0] is qt and len(starts) > 1  # the truth ranks first of the trials
    runs = []
    monkeypatch.setattr(tr.ecm, "run", lambda *a, **k: runs.append(a) or (a[0], None, None))
    binned = views.binned({c: c.binned(2) for c in cams})
    q, fit, moves = reach.search(qt, tr.fit(qt, masks), views, binned, None, new_timings())
    assert runs == [] and moves == [] and q is qt
    assert reach._failed == {arm: 1}  # it rests for the next REST_FRAMES frames


@pytest.mark.parametrize("rest", [0, 2])
def test_a_body_whose_search_found_nothing_rests_as_many_frames_as_told(rest, monkeypatch):
    """A limb reported lost on every frame while it fits (the truth): searched on the first
    frame, then again only after ``rest`` frames (the tracker's option reach_rest)."""
    robot, qt, _, cams, masks = _arm_scene(True)
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False, reach_search=True, reach_rest=rest)
    reach = tr.reach
    assert reach.rest == rest
    views = Views.of(cams, masks)
    arm = robot.index("leftUpperArm")
    monkeypatch.setattr(reach, "lost", lambda q, v: [arm])
    searched = []
    starts = reach._starts
    monkeypatch.setattr(reach, "_starts", lambda q, r, v: searched.append(reach._searches) or starts(q, r, v))
    for _ in range(7):
        reach.search(qt, tr.fit(qt, masks), views, None, None, new_timings())
    assert searched == ([1, 2, 3, 4, 5, 6, 7] if rest == 0 else [1, 4, 7])


def _bent_arm_scene():
    """The human with its left arm raised sideways and the elbow bent 90 degrees, seen by
    two cameras; the start has the upper arm turned half a turn about its own axis, so
    the forearm points the other way in the same plane."""
    robot = load(DIR / "human.kms", root="free")
    qt = robot.with_coordinates(robot.q_rest, {"leftUpperArm_shoulder_z": 80.0, "leftForeArm_elbow": 90.0})
    centre = robot.body_pose(qt, "torso").translation
    cams = [Camera.look_at(centre + [0.5, 0.2, 4.5], centre, width=640, height=480),
            Camera.look_at(centre + [-1.5, 3.5, 2.5], centre, width=640, height=480)]
    return robot, qt, cams, render(robot, qt, cams)


def test_a_turn_about_the_bone_keeps_the_body_and_swings_the_hinge_below():
    robot, qt, cams, masks = _bent_arm_scene()
    reach = ReachSearch(robot, Tracker(robot, cams, q0=qt, calibrate_sizes=False).ecm)
    arm = reach.reaches[robot.index("leftUpperArm")]
    assert arm.child.kind == "revolute"
    turned = reach._twisted(qt, arm.joint, arm.body)
    assert len(turned) == len(TWISTS_DEG)
    hand = robot.body_pose(qt, "leftHand").translation
    robot.forward(qt)
    shoulder = robot.data.oMi[robot.model.getJointId(arm.joint.name)].translation.copy()
    axis = robot.body_pose(qt, "leftUpperArm").translation - shoulder
    axis /= np.linalg.norm(axis)
    radius = np.linalg.norm((hand - shoulder) - ((hand - shoulder) @ axis) * axis)  # the hand from the bone's line
    assert radius > 0.1  # the elbow bent 90 degrees: the hand well off the bone
    for angle, c in zip(TWISTS_DEG, turned):
        # the upper arm's centre stays, the elbow keeps its angle, and the hand turns about
        # the bone's line by the angle: a chord of 2 r sin(angle / 2)
        assert np.allclose(robot.body_pose(c, "leftUpperArm").translation,
                           robot.body_pose(qt, "leftUpperArm").translation, atol=1e-9)
        assert c[arm.child.idx_q] == qt[arm.child.idx_q]
        moved = np.linalg.norm(robot.body_pose(c, "leftHand").translation - hand)
        assert moved == pytest.approx(2 * radius * abs(np.sin(np.radians(angle) / 2)), rel=1e-6)


@pytest.mark.parametrize("twists", [True, False])
def test_a_hinge_bent_in_the_wrong_plane_is_turned_back_by_the_reach_search(twists, monkeypatch):
    """The forearm bent the other way (the upper arm half a turn about its bone): ECM
    alone leaves it there; once the upper arm is searched (reported lost here: a forearm
    that small a share of the masks is neither lost nor missed), the turns about the
    bone bring it back, and without them (TWISTS_DEG empty) it stays."""
    robot, qt, cams, masks = _bent_arm_scene()
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False)
    reach = ReachSearch(robot, tr.ecm)
    arm = reach.reaches[robot.index("leftUpperArm")]
    q0 = reach._twisted(qt, arm.joint, arm.body)[TWISTS_DEG.index(180.0)]
    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert _arm_error_cm(robot, q_ecm, qt) > 20.0
    if not twists:
        monkeypatch.setattr("kms2pin.ecm.reach.TWISTS_DEG", ())
    monkeypatch.setattr(reach, "lost", lambda q, v: [arm.body])
    monkeypatch.setattr(reach, "missed", lambda q, v: [])
    views = Views.of(cams, masks)
    q, fit, moves = reach.search(q_ecm, fit_ecm, views, views.binned({c: c.binned(2) for c in cams}), None,
                                 new_timings())
    if twists:
        assert "pointed 'leftUpperArm_shoulder' at the masks" in [m.flag() for m in moves]
        assert _arm_error_cm(robot, q, qt) < 3.0 and fit > fit_ecm + 0.01
    else:
        assert _arm_error_cm(robot, q, qt) > 10.0


@pytest.mark.parametrize("which, bodies", [
    ("none", set()),
    ("arms", {"leftUpperArm", "rightUpperArm"}),
    ("limbs", {"leftUpperArm", "rightUpperArm", "leftThigh", "rightThigh"}),
])
def test_the_limbs_re_aimed_on_every_frame_are_the_hinged_limbs_or_those_off_the_floor(which, bodies):
    """``reach_always``: the spherical joints with a hinge below (shoulders above elbows,
    hips above knees; not the waist or the neck, nor a hinge itself), and of them the arms:
    the limbs holding none of the bodies on the floor at the starting pose."""
    robot, qt, cams, _ = _bent_arm_scene()
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False, reach_search=True, reach_always=which)
    assert {robot.bodies[i] for i in tr.reach.always} == bodies


def test_reach_always_is_checked():
    robot, qt, cams, _ = _bent_arm_scene()
    with pytest.raises(OptionError, match="reach_always"):
        Tracker(robot, cams, q0=qt, reach_search=True, reach_always="legs")


@pytest.mark.parametrize("always", ["none", "arms"])
def test_an_arm_neither_lost_nor_missed_is_re_aimed_only_when_the_arms_are_always_searched(always):
    """The forearm bent the other way: the arm keeps its silhouette on the masks and leaves
    no blob, so the search finds nothing to re-aim unless it re-aims the arms anyway; then
    the turn about the bone brings the forearm back."""
    robot, qt, cams, masks = _bent_arm_scene()
    tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False, reach_search=True, reach_always=always,
                 reach_skip=False)
    arm = tr.reach.reaches[robot.index("leftUpperArm")]
    q_ecm, fit_ecm = tr.refine(tr.reach._twisted(qt, arm.joint, arm.body)[TWISTS_DEG.index(180.0)], masks)
    views = Views.of(cams, masks)
    assert tr.reach.lost(q_ecm, views) == [] and tr.reach.missed(q_ecm, views) == []
    assert _arm_error_cm(robot, q_ecm, qt) > 20.0
    q, fit, moves = tr.reach.search(q_ecm, fit_ecm, views, views.binned({c: c.binned(2) for c in cams}), None,
                                    new_timings())
    if always == "none":
        assert moves == [] and q is q_ecm
    else:
        assert "pointed 'leftUpperArm_shoulder' at the masks" in [m.flag() for m in moves]
        assert _arm_error_cm(robot, q, qt) < 3.0 and fit > fit_ecm + 0.01


def test_a_limb_always_re_aimed_screens_fewer_starts_than_a_flagged_one():
    """A body of ``always`` keeps its ``reach_always_directions`` best directions (by
    default :data:`ALWAYS_REFINED`; each with its best bend as it is and turned about the
    bone), a flagged body its :data:`REFINED`."""
    robot, qt, cams, masks = _bent_arm_scene()
    views = Views.of(cams, masks)
    counts = {}
    for always, n in (("none", None), ("arms", None), ("arms", 5)):
        more = {} if n is None else {"reach_always_directions": n}
        tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False, reach_search=True, reach_always=always, **more)
        arm = tr.reach.reaches[robot.index("leftUpperArm")]
        counts[always, n] = len(tr.reach._starts(qt, arm, views))
    assert counts == {("none", None): 2 * REFINED, ("arms", None): 2 * ALWAYS_REFINED, ("arms", 5): 2 * 5}
    with pytest.raises(OptionError, match="reach_always_directions"):
        Tracker(robot, cams, q0=qt, reach_search=True, reach_always_directions=0)


def test_a_trial_that_screens_well_below_the_pose_is_not_refined(monkeypatch):
    """The arm at the truth, searched anyway (``reach_skip=False``): its trials are
    screened, and those that screen more than :data:`REFINE_MARGIN` below the truth's fit
    are not refined by the frame's ECM; refining them all keeps the truth as well."""
    robot, qt, cams, masks = _bent_arm_scene()
    views = Views.of(cams, masks)
    binned = views.binned({c: c.binned(2) for c in cams})
    found = {}
    for margin in (REFINE_MARGIN, 1.0):
        monkeypatch.setattr(reach_module, "REFINE_MARGIN", margin)
        tr = Tracker(robot, cams, q0=qt, calibrate_sizes=False, reach_search=True, reach_always="arms",
                     reach_skip=False)
        fit = tr.fit(qt, masks)
        run, screens, refined = tr.ecm.run, [], []

        def counted(q, v, timings, max_iterations=None, coarse=None, binned=False):
            out = run(q, v, timings, max_iterations, coarse, binned)
            (screens if binned else refined).append(tr.ecm.fit(out[0], views))
            return out

        monkeypatch.setattr(tr.ecm, "run", counted)
        q, _, moves = tr.reach.search(qt, fit, views, binned, None, new_timings())
        found[margin] = (q is qt, moves, len(screens), len(refined))
        if margin == REFINE_MARGIN:
            assert screens and sorted(screens)[-1] < fit - REFINE_MARGIN
    assert found[REFINE_MARGIN] == (True, [], found[1.0][2], 0)
    assert found[1.0][:2] == (True, []) and found[1.0][3] > 0


def test_a_limbs_root_turned_across_the_midline_is_not_a_trial():
    """The roots of the CMU walker's limbs (every joint spherical: the collars and the hips'
    first bones, which hang from the chest and the pelvis) stay on their side of the
    sagittal plane of the body they hang from: the left collar turned 180 degrees about the
    chest's vertical (the left shoulder where the right one is, the arms traded) is
    crossed, turned 20 degrees it is not, and the bodies below are not guarded (a hand
    may reach across)."""
    import pinocchio as pin

    from kms2pin.ecm.limbs import sides

    from ._tracking import cmu_walker

    robot, qs = cmu_walker()
    sd = sides(robot)
    names = {robot.bodies[b]: robot.bodies[a] for b, a in zip(sd.body, sd.anchor)}
    assert names == {"LHipJoint": "Hips", "RHipJoint": "Hips", "LeftCollar": "Chest", "RightCollar": "Chest"}

    def crossed(q):
        poses = robot.body_poses(q)
        return bool(sd.crossed(np.array([[p.rotation for p in poses]]), np.array([[p.translation for p in poses]]))[0])

    assert not any(crossed(x) for x in qs[::10])  # the walk itself never crosses
    q = qs[0]
    collar = next(j for j in robot.joints if j.name == "LeftCollar_joint")
    parent = robot.body_pose(q, collar.spec.parent).rotation
    up = robot.body_pose(q, "Chest").rotation @ np.array([0.0, 1.0, 0.0])  # the chest's vertical, world

    def turned(deg):  # the left collar turned by deg about the chest's vertical
        out = q.copy()
        R = parent @ pin.exp3(np.radians(deg) * (parent.T @ up)) @ parent.T  # the turn, world
        out[collar.idx_q : collar.idx_q + 4] = pin.Quaternion(parent.T @ R @ parent @ pin.Quaternion(
            *q[[collar.idx_q + 3, collar.idx_q, collar.idx_q + 1, collar.idx_q + 2]]).matrix()).coeffs()
        return out

    assert crossed(turned(180.0)) and not crossed(turned(20.0))
    read, guard = ReachSearch(robot, None)._guard(tuple(range(len(robot.bodies))))
    assert guard is not None and len(guard.body) == 4
