"""The tracker on spherical and prismatic joints: the left/right symmetry with spherical
twins, the limb search on spherical limbs, translations on the angles' scale."""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.limbs import is_left, left_right_pairs, limb_joints, twin_name
from kms2pin.ecm.limbsearch import LimbSearch
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.prediction import Motion
from kms2pin.ecm.symmetry import Symmetry
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.lang import parse_text
from kms2pin.robot import Robot, load

from ._tracking import CMU_WALK, DIR, centre_error, cmu_walker


def _joint(robot, name):
    return next(j for j in robot.joints if j.name == name)


def _rotation(q, j):
    x = q[j.idx_q : j.idx_q + 4]
    return pin.Quaternion(x[3], x[0], x[1], x[2]).normalized().toRotationMatrix()


def test_the_humans_spherical_hips_and_shoulders_are_limbs_with_twins():
    human = load(DIR / "human.kms", root="free")
    assert set(limb_joints(human)) == {"torso_waist", "head_neck", "leftUpperArm_shoulder", "rightUpperArm_shoulder",
                                       "leftThigh_hip", "rightThigh_hip"}
    symmetry = Symmetry.of(human)
    assert symmetry.twin["leftThigh_hip"].name == "rightThigh_hip"
    assert symmetry.twin["leftShin_knee"].name == "rightShin_knee"
    assert "torso_waist" not in symmetry.twin  # unpaired: mirrored in place
    assert Symmetry.of(load(DIR / "jplhand.kms", root="free")) is None  # no left/right
    assert Symmetry.of(load(DIR / "human.kms")) is None  # the spec's root: no sagittal plane to reflect


def test_an_abducted_hip_is_mirrored_onto_its_twin():
    """The left hip abducted (its leg out to the left, -x) and flexed: the exchange gives
    the right hip the same flexion and the abduction out to the right (+x), in the
    pelvis's axes (computed here: a rotation about z conjugated by the x reflection)."""
    human = load(DIR / "human.kms", root="free")
    symmetry = Symmetry.of(human)
    left, right = _joint(human, "leftThigh_hip"), _joint(human, "rightThigh_hip")
    q = human.q_rest.copy()
    abduct, flex = np.radians(-20.0), np.radians(30.0)
    R = pin.exp3(np.array([flex, 0.0, 0.0])) @ pin.exp3(np.array([0.0, 0.0, abduct]))
    q[left.idx_q : left.idx_q + 4] = pin.Quaternion(R @ _rotation(human.q_rest, left)).coeffs()
    out = symmetry.exchange(q, [left], [right])
    expected = pin.exp3(np.array([flex, 0.0, 0.0])) @ pin.exp3(np.array([0.0, 0.0, -abduct]))
    np.testing.assert_allclose(_rotation(out, right), expected @ _rotation(human.q_rest, right), atol=1e-12)
    np.testing.assert_allclose(_rotation(out, left), _rotation(human.q_rest, left), atol=1e-12)  # the rest mirrored
    # the left foot went out to -x; the right one now goes out to +x by as much
    lf, rf = (human.body_pose(x, n).translation for x, n in ((q, "leftFoot"), (out, "rightFoot")))
    lf0, rf0 = (human.body_pose(human.q_rest, n).translation for n in ("leftFoot", "rightFoot"))
    assert (lf - lf0)[0] < -0.1 and (rf - rf0)[0] == pytest.approx(-(lf - lf0)[0], abs=1e-9)


def test_a_spherical_limb_swung_the_other_way_reflects_its_swing_about_the_joint_axis():
    """A shoulder turned from rest by w = (35, -10, 15) deg (parent axes, x its end's axis):
    swung the other way it is turned by (-35, -10, 15) deg: the swing one view confuses is
    reflected, the rest of the rotation kept."""
    human = load(DIR / "human.kms", root="free")
    tracker = Tracker(human, [Camera.default()], calibrate_sizes=False)
    search = LimbSearch(human, tracker.ecm, Symmetry.of(human))
    shoulder = _joint(human, "leftUpperArm_shoulder")
    assert tuple(shoulder.spec.parent_bvec.orient) == (1.0, 0.0, 0.0)
    R0 = _rotation(human.q_rest, shoulder)
    q = human.q_rest.copy()
    q[shoulder.idx_q : shoulder.idx_q + 4] = pin.Quaternion(pin.exp3(np.radians([35.0, -10.0, 15.0])) @ R0).coeffs()
    swings = [c for move, c in search.candidates(q) if move.kind == "swing" and move.joints == (shoulder.name,)]
    assert swings
    np.testing.assert_allclose(_rotation(swings[0], shoulder), pin.exp3(np.radians([-35.0, -10.0, 15.0])) @ R0,
                               atol=1e-12)


def test_the_limb_search_brings_back_a_spherical_shoulder_swung_the_wrong_way():
    """Clean silhouettes of the human's walk, the front camera and one left-front: the
    left shoulder started swung the other way (forward where the images have it back; its
    sway kept) stays more than 25 deg off under ECM alone; the limb search on that frame
    brings it within 10 deg (measured 30 -> 7 deg; the move kept is the arm put back at
    rest below the shoulder, from which ECM finds the way)."""
    human = load(DIR / "human.kms", root="free")
    qt = make_motion(human, "walk", 60)[45]
    c = human.q_rest[:3]
    cams = [Camera.default(), Camera.look_at(position=c + [-2.7, 1.35, -2.7], target=c)]
    masks = render(human, qt, cams)
    shoulder = _joint(human, "leftUpperArm_shoulder")
    R0, R = _rotation(human.q_rest, shoulder), _rotation(qt, shoulder)
    v = pin.log3(R @ R0.T)  # parent axes
    assert abs(np.degrees(v[0])) > 15.0  # swung about the shoulder's axis (x)
    q0 = qt.copy()  # the swing the other way, the sway kept
    q0[shoulder.idx_q : shoulder.idx_q + 4] = pin.Quaternion(pin.exp3(v * [-1.0, 1.0, 1.0]) @ R0).coeffs()
    tr = Tracker(human, cams, q0=qt, calibrate_sizes=False)

    def off(q):
        return np.degrees(np.linalg.norm(pin.log3(_rotation(q, shoulder).T @ R)))

    q_ecm, fit_ecm = tr.refine(q0, masks)
    assert off(q_ecm) > 25.0
    q, fit, move = tr.swing_limbs(q0, masks)
    assert move is not None and fit > fit_ecm + 0.02
    assert off(q) < 10.0 and centre_error(human, q, qt) < centre_error(human, q_ecm, qt)


def test_translations_count_on_the_angles_scale():
    """A prismatic offset of 1 % of the model's height counts as 1 degree, as a free
    root's translation does (the convergence test and the prediction cap)."""
    gantry = load(DIR / "gantry.kms")
    motion = Motion(gantry, max_prediction_deg=20.0)
    slide = next(j for j in gantry.joints if j.kind == "prismatic")
    q1 = gantry.q_rest.copy()
    q1[slide.idx_q] += 0.01 * gantry.height
    assert motion.change(gantry.q_rest, q1) == pytest.approx(np.radians(1.0))
    far = gantry.q_rest.copy()
    far[slide.idx_q] += 0.5 * gantry.height
    assert motion.velocity(gantry.q_rest, far)[slide.idx_v] == pytest.approx(20.0 * 0.01 * gantry.height)


@pytest.mark.slow
def test_the_human_is_tracked_by_three_cameras_as_it_walks_out_of_the_sagittal_plane():
    """Clean silhouettes, three cameras (the front, raised right and left-rear ones: every
    arm seen by two): within 1 % of the height on every frame (measured: 0.54 % at worst,
    0.10 % on average).  With the front and right cameras alone the left arm, hidden from
    the right, flips for a few frames (20 % at the hand; docs/tracking.md)."""
    human = load(DIR / "human.kms", root="free")
    motion = make_motion(human, "walk", 40)
    c = human.q_rest[:3]
    cams = [Camera.default(), Camera.look_at(position=c + [3.6, 1.35, 3.6], target=c),
            Camera.look_at(position=c + [-2.7, 1.35, -2.7], target=c)]
    tr = Tracker(human, cams, calibrate_sizes=False)
    errors = [centre_error(human, tr.step(render(human, q, cams)).q, q) for q in motion]
    assert max(errors) < 1.0 and np.mean(errors) < 0.3


def test_twin_names_in_the_spellings_skeletons_use():
    """``left*`` / ``right*`` always; a side word (Unreal's ``thigh_l``, Blender's
    ``hand.l``, and the ``*_joint`` an import names after them) or the first letter (CMU's
    ``lhand``) only where the other side's name exists, and only as each other's twins."""
    assert twin_name("leftthigh") == "rightthigh" and twin_name("rightthigh") == "leftthigh"
    names = {"lhand", "rhand", "lowerback", "thigh_l", "thigh_r", "thigh_l_joint", "thigh_r_joint", "hand.l",
             "hand.r", "lhipjoint", "rhipjoint", "arm_left", "arm_right"}
    assert twin_name("lhand") == "lhand"  # no names to look in: not a twin
    for a, b in (("lhand", "rhand"), ("thigh_l", "thigh_r"), ("thigh_l_joint", "thigh_r_joint"), ("hand.l", "hand.r"),
                 ("lhipjoint", "rhipjoint"), ("arm_left", "arm_right")):
        assert twin_name(a, names) == b and twin_name(b, names) == a
        assert is_left(a, b) and not is_left(b, a)
    assert twin_name("lowerback", names | {"rowerback_x"}) == "lowerback"
    # a side word goes first: rib_l and rib_r are twins, and lib_l, whose first letter
    # turned gives rib_l, has none (rib_l is not its twin back)
    ribs = {"rib_l", "rib_r", "lib_l"}
    assert (twin_name("rib_l", ribs), twin_name("rib_r", ribs), twin_name("lib_l", ribs)) == ("rib_r", "rib_l", "lib_l")
    names = ["Hips", "LHipJoint", "RHipJoint", "LeftHip", "RightHip", "lhand", "rhand", "lowerback", "LThumb", "RThumb"]
    assert sorted(left_right_pairs(names)) == [(1, 2), (3, 4), (5, 6), (8, 9)]  # (left, right) each
    # after a prefix (Mixamo's "mixamorig:", 3ds Max's "Bip01 "), the same spellings word by word
    prefixed = [f"mixamorig_{n}" for n in names] + ["bip01_l_thigh", "bip01_r_thigh", "bip01 l hand", "bip01 r hand"]
    assert sorted(left_right_pairs(prefixed)) == [(1, 2), (3, 4), (5, 6), (8, 9), (10, 11), (12, 13)]
    assert twin_name("mixamorig_lowerback", {n.lower() for n in prefixed}) == "mixamorig_lowerback"


def test_an_unreal_named_skeleton_has_its_twins(tmp_path):
    """The CMU walker's joints renamed as Unreal names them (``Hip_l``, ``Knee_r``): the
    import's joints (``Hip_l_joint``) are paired, and the model has a symmetry."""
    text = CMU_WALK.read_text()
    for side, mark in (("Left", "_l"), ("Right", "_r")):
        text = re.sub(rf"\b{side}(\w+)", rf"\1{mark}", text)
    assert "Hip_l" in text and "Left" not in text
    (tmp_path / "unreal.bvh").write_text(text)
    robot, _ = cmu_walker(tmp_path / "unreal.bvh")
    symmetry = Symmetry.of(robot)
    assert symmetry is not None and symmetry.twin["Hip_l_joint"].name == "Hip_r_joint"
    assert symmetry.twin["Elbow_r_joint"].name == "Elbow_l_joint"


def test_a_mixamo_named_skeleton_has_its_twins(tmp_path):
    """The CMU walker's joints named as Mixamo exports them (``mixamorig:LeftUpLeg``): the
    import's names (``mixamorig_LeftHip_joint``) are paired, and the model has a symmetry."""
    text = re.sub(r"\b(ROOT|JOINT) (\w+)", r"\1 mixamorig:\2", CMU_WALK.read_text())
    assert "JOINT mixamorig:LeftHip" in text
    (tmp_path / "mixamo.bvh").write_text(text)
    robot, _ = cmu_walker(tmp_path / "mixamo.bvh")
    symmetry = Symmetry.of(robot)
    assert symmetry is not None
    twins = {a: j.name for a, j in symmetry.twin.items()}
    for left, right in (("LeftHip", "RightHip"), ("LeftShoulder", "RightShoulder"), ("lhand", "rhand")):
        a, b = (next(n for n in twins if n.startswith(f"mixamorig_{side}")) for side in (left, right))
        assert twins[a] == b and twins[b] == a


def test_a_real_subjects_sides_mirror_each_other_within_the_tolerance():
    """A real skeleton is not symmetric (CMU's subject 131 as imported: the swapped pose's
    centres up to 3.6 % of the height from the reflected ones, its hands, fingers and hip
    joints named ``l*`` / ``r*``), yet its twins are found and swapped: every twin pair,
    those too, and a swap twice gives the pose back.  A spec whose one thigh is 40 %
    longer has none."""
    walker, qs = cmu_walker()
    symmetry = Symmetry.of(walker)
    assert symmetry is not None
    assert {k: v.name for k, v in symmetry.twin.items() if k.lower().startswith(("l", "left"))} == {
        "LeftHip_joint": "RightHip_joint", "LeftKnee_joint": "RightKnee_joint", "LeftAnkle_joint": "RightAnkle_joint",
        "LeftToe_joint": "RightToe_joint", "LeftCollar_joint": "RightCollar_joint",
        "LeftShoulder_joint": "RightShoulder_joint", "LeftElbow_joint": "RightElbow_joint", "lhand_joint": "rhand_joint",
        "LHipJoint_joint": "RHipJoint_joint", "LFingers_joint": "RFingers_joint", "LThumb_joint": "RThumb_joint"}
    q = qs[40]
    back = symmetry.swap(symmetry.swap(q))
    np.testing.assert_allclose(walker.maximal_coordinates(back)[:, :3], walker.maximal_coordinates(q)[:, :3], atol=1e-9)
    # the swapped pose's left hand is the reflection of the pose's right hand, within the sides' difference
    S, root = symmetry.S, pin.XYZQUATToSE3(q[:7])
    lh, rh = (root.actInv(walker.body_pose(x, n)).translation for x, n in ((symmetry.swap(q), "lhand"), (q, "rhand")))
    assert np.linalg.norm(lh - S @ rh) < 0.05 * walker.height
    text = (DIR / "human.kms").read_text()
    longer = text.replace("Thigh leftThigh(hipHeight - kneeHeight, 0.045*H);",
                          "Thigh leftThigh(1.4*(hipHeight - kneeHeight), 0.045*H);")
    assert longer != text
    assert Symmetry.of(load(longer, root="free")) is None


def _knee_flipped_lowerbody():
    """The thesis's lower body with the left knee's axis turned round (its thigh's and shin's
    knee vectors point +x, the right ones -x) and its rest angle negated: the same body at
    rest, its knees' axes mirror images as polar vectors, so a mirrored bend negates the angle."""
    text = (DIR / "lowerbody.kms").read_text()
    knee = "    bvec knee {{\n        pos(0, 0, {}*length);\n        orient(-1, 0, 0);\n    }}"
    sided = "    bvec knee {{\n        pos(0, 0, {}*length);\n        if (leftSide) {{ orient(1, 0, 0); }} else {{ orient(-1, 0, 0); }}\n    }}"
    for edit in ((knee.format("-0.8"), sided.format("-0.8")), (knee.format("0.8"), sided.format("0.8")),
                 ("Shin(double length, double radius)", "Shin(double length, double radius, bool leftSide)"),
                 ("leftShin(0.55, 0.23);", "leftShin(0.55, 0.23, true);"),
                 ("rightShin(0.55, 0.23);", "rightShin(0.55, 0.23, false);"),
                 ("revolute(leftShin.knee, leftThigh.knee, 2*postureDelta)", "revolute(leftShin.knee, leftThigh.knee, -2*postureDelta)")):
        assert edit[0] in text
        text = text.replace(*edit)
    spec = parse_text(text, "lowerbody-flipped.kms")
    return Robot(spec, spec.system(), "free")


def test_twin_hinges_whose_axes_point_the_same_way_are_mirrored_by_negating_the_angle():
    """A hinge twin whose axis is its twin's mirror image as a polar vector (left +x, right -x
    here) bends the other way for the same angle, so the mirror image negates it: the swap
    then puts every body centre onto its twin's reflected one exactly, where exchanging the
    angles as they are bent both knees the wrong way (and the model had no symmetry)."""
    plain, flipped = load(DIR / "lowerbody.kms", root="free"), _knee_flipped_lowerbody()
    rest = [np.array([M.translation for M in r.body_poses(r.q_rest)]) for r in (plain, flipped)]
    assert np.allclose(rest[0], rest[1], atol=1e-12)  # the same body at rest
    rng = np.random.default_rng(3)
    for robot, knee_sign in ((plain, 1.0), (flipped, -1.0)):
        symmetry = Symmetry.of(robot)
        assert symmetry is not None
        signs = {j.name: symmetry.sign(j) for j in robot.joints if j.kind == "revolute"}
        assert signs == {n: (knee_sign if "knee" in n else 1.0) for n in signs}
        names = {b.lower(): i for i, b in enumerate(robot.bodies)}
        twin = [names[twin_name(b, names)] for b in names]
        for _ in range(5):
            q = robot.q_rest.copy()
            q[:3] += rng.normal(size=3)
            q[3:7] = pin.Quaternion(pin.exp3(rng.normal(size=3))).coeffs()
            for j in robot.joints[1:]:
                q[j.idx_q] += rng.uniform(-1.0, 1.0)
            root = pin.XYZQUATToSE3(q[:7])
            before, after = (np.array([root.actInv(M).translation for M in robot.body_poses(x)])
                             for x in (q, symmetry.swap(q)))
            assert np.abs(after - (before @ symmetry.S.T)[twin]).max() < 1e-9 * robot.height
