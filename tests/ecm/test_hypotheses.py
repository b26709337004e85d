"""Alternative hypotheses: the mirror image and the left/right swap, tracked beside the pose."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.hypotheses import mirror_pose
from kms2pin.ecm.limbs import sagittal_mirror
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.symmetry import Symmetry
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.robot import load

from ._tracking import (
    DIR,
    _anatomical,
    _cams,
    _robot,
    _root_angle_deg,
    centre_error,
)


def test_alternative_hypotheses_are_on_for_one_camera_and_a_left_right_model(tmp_path):
    robot = _anatomical()
    one = Tracker(robot, _cams(robot, 1))
    assert one.options.hypotheses.mirror_hypothesis and one.options.hypotheses.swap_hypothesis
    two = Tracker(robot, _cams(robot, 2))
    assert not two.options.hypotheses.mirror_hypothesis and not two.options.hypotheses.swap_hypothesis
    off = Tracker(robot, _cams(robot, 1), mirror_hypothesis=False, swap_hypothesis=False)
    assert not off.options.hypotheses.mirror_hypothesis and not off.options.hypotheses.swap_hypothesis
    hand = _robot("jplhand")  # no left/right bodies
    assert not Tracker(hand, _cams(hand, 1)).options.hypotheses.mirror_hypothesis
    assert not Tracker(hand, _cams(hand, 1)).options.hypotheses.swap_hypothesis
    with pytest.raises(ValueError, match="left/right"):
        Tracker(hand, _cams(hand, 1), mirror_hypothesis=True)
    with pytest.raises(ValueError, match="left/right"):
        Tracker(hand, _cams(hand, 1), swap_hypothesis=True)
    capitals = tmp_path / "capitals.kms"  # LeftThigh / RightThigh: names compared in lower case
    capitals.write_text((DIR / "anatomical" / "lowerbody.kms").read_text().replace("left", "Left").replace("right", "Right"))
    cap = load(capitals, root="free")
    assert "LeftThigh_hip" in cap.joint_names
    assert Tracker(cap, _cams(cap, 1)).options.hypotheses.swap_hypothesis and Tracker(cap, _cams(cap, 1)).options.hypotheses.mirror_hypothesis
    thesis = _robot("lowerbody")  # no joint limits: the mirror only, unless asked
    assert Tracker(thesis, _cams(thesis, 1)).options.hypotheses.mirror_hypothesis
    assert not Tracker(thesis, _cams(thesis, 1)).options.hypotheses.swap_hypothesis
    assert Tracker(thesis, _cams(thesis, 1), swap_hypothesis=True).options.hypotheses.swap_hypothesis


@pytest.mark.parametrize("name", ["anatomical/lowerbody", "anatomical/fullbody", "human"])
def test_the_swap_hypothesis_is_the_body_reflected_through_its_own_left_right_plane(name):
    """Exchanging the left and right joints (a spherical hip's rotation mirrored onto its
    twin, an unpaired spherical waist's mirrored in place) puts every body where the
    reflection of the body through its sagittal plane puts its twin (leftThigh <->
    rightThigh, the trunk onto itself), seen from any camera as the same silhouette
    under a reflection: checked with forward kinematics at random poses."""
    robot = load(DIR / f"{name}.kms", root="free")
    symmetry = Symmetry.of(robot)
    twins = {j.name for j in symmetry.swapped_joints() if j.name.startswith("left")}
    assert twins == {j.name for j in robot.joints if j.name.startswith("left") and j.kind != "fixed"}
    root0 = pin.XYZQUATToSE3(robot.q_rest[:7])
    hips = [robot.body_pose(robot.q_rest, n).translation for n in ("leftThigh", "rightThigh")]
    lateral = root0.rotation.T @ (hips[0] - hips[1])
    lateral /= np.linalg.norm(lateral)
    reflect = np.eye(3) - 2 * np.outer(lateral, lateral)  # independent of the tracker's own
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = robot.clamp(robot.random_configuration(rng, 40))
        s = symmetry.swap(q)
        back = symmetry.swap(s)
        np.testing.assert_allclose(pin.difference(robot.model, back, q), 0.0, atol=1e-12)  # an involution
        root = pin.XYZQUATToSE3(q[:7])
        for body in robot.bodies:
            twin = body.replace("left", "RIGHT").replace("right", "left").replace("RIGHT", "right")
            p = root.actInv(robot.body_pose(q, body)).translation
            p_twin = root.actInv(robot.body_pose(s, twin)).translation
            np.testing.assert_allclose(p_twin, reflect @ p, atol=1e-9 * robot.height)


def test_the_mirror_image_looks_the_same_from_afar_and_is_an_involution():
    """For a left/right-symmetric pose the mirror hypothesis is the body reflected
    through the plane across the viewing ray: under (near) orthographic projection its
    silhouette is the same, though the root is turned by up to 180 degrees."""
    robot = _anatomical()
    centre = robot.q_rest[:3]
    far = Camera.look_at(position=centre + [0.0, 0.0, -80.0], target=centre, fov_deg=4.0)
    sagittal = sagittal_mirror(robot)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q = robot.q_rest.copy()
        yaw = rng.uniform(-np.pi, np.pi)
        R = pin.exp3(np.array([0.0, yaw, 0.0])) @ pin.XYZQUATToSE3(q[:7]).rotation
        q[3:7] = pin.Quaternion(R).coeffs()
        m = mirror_pose(q, far, sagittal)
        np.testing.assert_allclose(mirror_pose(m, far, sagittal), q, atol=1e-12)  # an involution
        np.testing.assert_allclose(m[7:], q[7:])  # joints kept
        a, b = render(robot, q, [far])[0], render(robot, m, [far])[0]
        assert (a & b).sum() / (a | b).sum() > 0.97
    # facing the camera <-> facing away from it: a half turn about the vertical
    cam = Camera.default()
    m = mirror_pose(robot.q_rest, cam, sagittal)
    assert _root_angle_deg(m, robot.q_rest) == pytest.approx(180.0, abs=1e-6)


@pytest.mark.slow
def test_mirror_hypothesis_brings_back_a_track_started_mirrored_in_one_view():
    """One camera, the walk's second turn (frames 178-210, from facing the camera to
    side-on), 5 % noise and 10 % size mismatch, the tracker started at the mirror image
    of the true pose (137 deg off; the same silhouette): with the mirror hypothesis it
    ends facing the true way on every noise seed, and it has switched to the mirror on
    every seed where a single hypothesis stays mirrored (measured: seed 2 ends 174 deg
    off with one hypothesis, 16 deg with both; on seed 0 the main hypothesis turns
    through by itself, 2.5 deg, and on seed 1 ends 5.7 deg off against 4.8).

    (A track started at the true pose in the middle of the turn, frames 150-210, ends
    the right way round or mirrored about as often with the mirror hypothesis as
    without it: the outcome of a turn seen in one view depends on the noise seed.)"""
    from kms2pin.ecm.synth import synthesize

    robot = _anatomical()
    motion = make_motion(robot, "walk", 300)[178:210]
    cams = [Camera.default()]
    q0 = mirror_pose(motion[0], cams[0], sagittal_mirror(robot))
    assert _root_angle_deg(q0, motion[0]) > 120.0
    final, switched = {}, {}
    for seed in range(3):
        rng = np.random.default_rng(seed)
        data = [m for _, m in synthesize(robot, motion, cams, noise=0.05, size_mismatch=0.1, rng=rng)]
        for mirror in (True, False):
            # the limb search off: it too can bring a mirrored track back (measured: seed 2
            # ends 15 deg off with it and one hypothesis)
            tr = Tracker(robot, cams, q0=q0, mirror_hypothesis=mirror, calibrate_sizes=False, limb_search=False)
            results = [tr.step(m) for m in data]
            switched[seed, mirror] = any(
                "switched to the mirror hypothesis" in f for r in results for f in r.flags
            )
            final[seed, mirror] = _root_angle_deg(results[-1].q, motion[-1])
            if mirror:
                assert final[seed, mirror] < 20.0
                # measured 1.5, 0.9 and 5.3 % (one view, sizes not calibrated); the
                # mirrored end is 12.6 % off
                assert centre_error(robot, results[-1].q, motion[-1]) < 8.0
        # tracked on binned masks the mirror hypothesis still brings the track back
        # (measured 4.2, 4.9 and 17.3 deg; 1.2, 0.9 and 6.8 %)
        tr = Tracker(robot, cams, q0=q0, calibrate_sizes=False, binned_hypotheses=True)
        results = [tr.step(m) for m in data]
        assert _root_angle_deg(results[-1].q, motion[-1]) < 20.0
        assert centre_error(robot, results[-1].q, motion[-1]) < 8.0
    assert not any(switched[s, False] for s in range(3))
    assert max(final[s, False] for s in range(3)) > 90.0
    for s in range(3):
        if final[s, False] > 90.0:
            assert switched[s, True]


def test_binned_hypotheses_track_the_alternatives_on_binned_masks():
    """binned_hypotheses: every ECM iteration of an alternative hypothesis runs on the
    cameras binned 2x2 (half the width and height), the main one's at full resolution;
    off, all run at full resolution.  (The limb search, whose own iterations come
    between, is off.)"""
    robot = _anatomical()
    motion = make_motion(robot, "walk", 300)[178:184]
    cams = [Camera.default()]
    frames = [render(robot, q, cams) for q in motion]
    for binned in (False, True):
        tr = Tracker(robot, cams, q0=motion[0], calibrate_sizes=False, binned_hypotheses=binned, limb_search=False)
        widths = []
        iterate = tr.ecm.iterate

        def spy(q, views, delta_px, timings, *priors):
            widths.append(views.cameras[0].width)
            assert views.masks[0].shape == (views.cameras[0].height, widths[-1])
            return iterate(q, views, delta_px, timings, *priors)

        tr.ecm.iterate = spy
        per_frame = []
        for m in frames:
            widths.clear()
            r = tr.step(m)
            per_frame.append((r.iterations, list(widths)))
        for main_its, w in per_frame:
            assert w[:main_its] == [320] * main_its  # the main hypothesis: full resolution
            assert w[main_its:] == ([160] if binned else [320]) * (len(w) - main_its)
        # alternatives are spawned on the second frame and tracked from the third
        assert sum(len(w) > its for its, w in per_frame[2:]) >= 3
