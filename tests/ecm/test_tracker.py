"""ECM tracker: truth is a fixed point, recovery from a perturbed pose, a short
sequence without drift, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import require_kernels

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.mstep import BodyFit
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker, Trajectory, TrajectoryCsvWriter, limb_joints
from kms2pin.errors import CameraError, InputDataError, OptionError
from kms2pin.robot import load

SPECS = ("puma600", "lowerbody", "fullbody", "jplhand")


DIR = Path(__file__).resolve().parents[2] / "specs"


def _robot(name):
    return load(DIR / f"{name}.kms", root="free")


def _cams(robot, n=2):
    return [Camera.default(), Camera.look_at(position=[8, 0, 8], target=robot.q_rest[:3])][:n]


def centre_error(robot, q, qt) -> float:
    """Mean body-centre error, % of the model height."""
    a = robot.maximal_coordinates(q)[:, :3]
    b = robot.maximal_coordinates(qt)[:, :3]
    return float(np.linalg.norm(a - b, axis=1).mean() / robot.height * 100)


def joint_errors(robot, q, qt) -> np.ndarray:
    """Revolute joint errors (degrees)."""
    return np.degrees(np.abs(pin.difference(robot.model, q, qt)))[6:]


def _perturbed(robot, qt, rng, deg=8.0):
    q0 = qt.copy()
    q0[7:] += np.radians(rng.uniform(-deg, deg, robot.nq - 7))
    q0[:3] += rng.uniform(-1, 1, 3) * 0.01 * robot.height
    return q0


@pytest.mark.parametrize("name", SPECS)
def test_truth_is_a_fixed_point(name):
    robot = _robot(name)
    rng = np.random.default_rng(10)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    tr = Tracker(robot, cams, q0=qt)
    r = tr.step(render(robot, qt, cams))
    assert centre_error(robot, r.q, qt) < 0.5
    # puma600's base is a body of revolution about its own joint axis: with a free root,
    # turning the root about it and link1 back is invisible (a gauge); skip that pair.
    errs = joint_errors(robot, r.q, qt)
    if name == "puma600":
        errs = errs[1:]
    # Joints whose bodies the silhouettes hardly fix (fullbody's right elbow: the forearm
    # lies over the trunk in both views, ~13 deg; jplhand's small finger tips, ~3 deg)
    # drift; all but the two worst joints stay < 2 deg.
    assert np.sort(errs)[-3 if len(errs) > 3 else 0] < 2.0
    assert errs.max() < 15.0
    assert r.fit > 0.97


@pytest.mark.parametrize("name", SPECS)
def test_single_frame_recovers_the_pose(name):
    robot = _robot(name)
    rng = np.random.default_rng(11)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    # ECM run to its fixed point: the default stop (0.2 deg, 0.25 px) is set for
    # tracking, where a frame starts near its answer.  From this 8-degree start the
    # full body's right forearm, which lies over the trunk in both views, crosses a
    # plateau (0.16 deg and 0.23 px in one iteration, 16.8 deg off) before it moves on
    # to 1.7 deg; the default stop ends the frame there.
    tr = Tracker(robot, cams, q0=q0, max_iterations=40, tol_deg=0.02, tol_px=0.02, calibrate_sizes=False)
    r = tr.step(render(robot, qt, cams))  # q0 is not the pose shown
    assert r.converged
    before = centre_error(robot, q0, qt)
    after = centre_error(robot, r.q, qt)
    assert after < 0.5 and after < 0.2 * before
    errs = joint_errors(robot, r.q, qt)
    if name == "puma600":
        errs = errs[1:]
    assert np.median(errs) < 2.0 and errs.max() < 6.0
    assert r.fit > 0.97


@pytest.mark.slow
def test_one_camera_single_frame():
    robot = _robot("lowerbody")
    rng = np.random.default_rng(12)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot, 1)
    q0 = _perturbed(robot, qt, rng)
    r = Tracker(robot, cams, q0=q0, max_iterations=10, calibrate_sizes=False).step(render(robot, qt, cams))
    # One camera fits the silhouette but leaves depth (and the tilts that keep an
    # outline) weakly fixed: the 3-D error need not fall (here 1.2 % -> ~2 %).
    assert r.fit > 0.95
    assert centre_error(robot, r.q, qt) < 3.0


@pytest.mark.slow
def test_walk_sequence_stays_accurate(tmp_path):
    robot = _robot("lowerbody")
    cams = _cams(robot)
    motion = make_motion(robot, "walk", 30)
    tr = Tracker(robot, cams)
    errs = []
    with TrajectoryCsvWriter(robot, tmp_path / "t.csv") as w:
        for f, qt in enumerate(motion):
            r = tr.step(render(robot, qt, cams), source=f"frame {f}")
            w.write(f, r)
            errs.append(centre_error(robot, r.q, qt))
    errs = np.array(errs)
    assert errs.mean() < 1.0 and errs.max() < 2.0
    assert errs[-10:].mean() < 1.0  # no drift
    back = Trajectory.from_csv(robot, tmp_path / "t.csv")
    assert len(back) == 30


def test_empty_mask_keeps_the_pose_and_is_flagged():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams)
    r = tr.step([np.zeros(c.shape, bool) for c in cams])
    assert "empty mask" in r.flags
    np.testing.assert_array_equal(r.q, robot.q_rest)


def test_wrong_mask_size_names_the_frame():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams)
    with pytest.raises(InputDataError, match="frame 7.*camera 1.*100x50"):
        tr.step([np.zeros((240, 320), bool), np.zeros((50, 100), bool)], source="frame 7")
    with pytest.raises(InputDataError, match="1 masks for 2 cameras"):
        tr.step([np.zeros((240, 320), bool)])


def test_camera_that_does_not_see_the_model():
    robot = _robot("lowerbody")
    away = Camera.look_at(position=[0, 0, 20], target=[0, 0, 40], name="away")
    with pytest.raises(CameraError, match="camera 1 'away' does not see the model"):
        Tracker(robot, [Camera.default(), away])


@pytest.mark.slow
def test_noisy_mismatched_walk_does_not_diverge():
    """Regression: 5 % noise + 10 % body-size mismatch, lowerbody walk, 2 cameras.

    With the side camera level with the front one (``[8, 0, 8]``: two level
    orthogonal views share a mirror ambiguity, the trunk turned by +a or -a with the
    legs swapped looks alike in both) the tracker took the mirrored branch as the
    walker started turning and was 10-15 % of the height off from frame 6 on.
    The fix is the rig: a side camera raised 3 units (~20 deg down), as in
    ``benchmarks/ecm.py``, breaks the symmetry (mean error ~0.3 %).
    """
    from kms2pin.ecm.synth import synthesize

    robot = _robot("lowerbody")
    rng = np.random.default_rng(0)
    motion = make_motion(robot, "walk", 40, rng)
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    data = [m for _, m in synthesize(robot, motion, cams, noise=0.05, size_mismatch=0.1, rng=rng)]
    tr = Tracker(robot, cams)
    errs = np.array([centre_error(robot, tr.step(m).q, qt) for m, qt in zip(data, motion)])
    assert errs.mean() < 1.0 and errs.max() < 2.0
    assert errs[-10:].mean() < 1.5 * errs[:10].mean() + 0.2


@pytest.mark.parametrize("outlier, coarse", [(0.0, None), (0.01, None), (0.0, 1.4)])
def test_native_and_numpy_trackers_agree(monkeypatch, outlier, coarse):
    """The C kernels (E-step, M-step) and the NumPy code give the same track, on the
    masks and on their 2x2 binned fractions (coarse_delta_px)."""
    from kms2pin.ecm import mstep

    require_kernels()
    robot = _robot("lowerbody")
    rng = np.random.default_rng(13)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    out = {}
    for native in (True, False):
        monkeypatch.setattr(mstep, "NATIVE", native)
        tr = Tracker(robot, cams, q0=q0, outlier=outlier, calibrate_sizes=False, coarse_delta_px=coarse)
        out[native] = tr.step(render(robot, qt, cams))
    np.testing.assert_allclose(out[True].q, out[False].q, atol=1e-9)
    assert out[True].iterations == out[False].iterations
    assert centre_error(robot, out[True].q, qt) < 0.5


def test_max_pixels_subsamples_the_m_step_and_still_recovers(monkeypatch):
    from kms2pin.ecm import tracker as tracker_mod

    robot = _robot("lowerbody")
    rng = np.random.default_rng(14)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    sizes = []
    real = tracker_mod.fit_bodies

    def spy(views, *a, **k):
        sizes.extend((len(v.y), v.image.stride, len(v.image.dirs)) for vs in views for v in vs)
        return real(views, *a, **k)

    monkeypatch.setattr(tracker_mod, "fit_bodies", spy)
    r = Tracker(robot, cams, q0=q0, max_pixels=400, max_iterations=10, calibrate_sizes=False).step(render(robot, qt, cams))
    assert max(n for n, _, _ in sizes) <= 400 * 1.3  # strided boxes: about max_pixels each
    assert any(stride > 1 for _, stride, _ in sizes)
    assert all(n == m for n, _, m in sizes)  # mask, others and rays subsampled alike
    assert centre_error(robot, r.q, qt) < 1.0


def test_a_frame_the_model_cannot_fit_is_flagged_poor_fit():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    qt = robot.q_rest.copy()
    good = Tracker(robot, cams, q0=qt).step(render(robot, qt, cams))
    assert good.fit > 0.9 and not any(f.startswith("poor fit") for f in good.flags)
    far = qt.copy()
    far[0] += 0.6 * robot.height  # the silhouettes of a subject well to the side
    r = Tracker(robot, cams, q0=qt, max_iterations=1, min_iterations=1, calibrate_sizes=False).step(render(robot, far, cams))
    assert r.fit < 0.5
    assert any(f.startswith("poor fit") for f in r.flags)


def test_a_lost_track_keeps_its_last_pose_and_does_not_coast():
    """Masks that the model's silhouettes do not touch at all (fit 0) carry no
    information: the tracker keeps the last pose instead of following its constant-
    velocity prediction out of the view, and picks the subject up when it is back."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    motion = np.repeat(robot.q_rest[None], 4, axis=0)
    for k in range(4):
        motion[k, 0] += 0.01 * k * robot.height  # walking sideways, 1 % of the height a frame
    tr = Tracker(robot, cams, q0=motion[0], calibrate_sizes=False)
    for k in range(3):
        tr.step(render(robot, motion[k], cams))
    last = tr.q.copy()
    blob = [np.zeros(c.shape, dtype=bool) for c in cams]
    for b in blob:
        b[:6, :6] = True  # a speck in a corner, far from the model
    r = tr.step(blob)
    assert r.fit == 0.0 and "lost: kept the last pose" in r.flags
    np.testing.assert_array_equal(r.q, last)
    r = tr.step(render(robot, motion[3], cams))  # back: no velocity carried over the lost frame
    assert r.fit > 0.9
    assert centre_error(robot, r.q, motion[3]) < 0.5


def test_constant_velocity_prediction_is_capped():
    """A joint that turned 90 deg in the last frame (a poorly seen joint starting to spin)
    is predicted to move at most max_prediction_deg; slow joints keep their velocity."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    tr = Tracker(robot, cams, max_prediction_deg=10.0)  # not the default (20)
    q0 = robot.q_rest.copy()
    q1 = q0.copy()
    q1[7] += np.radians(90.0)  # first revolute joint: a fast spin
    q1[8] += np.radians(3.0)  # a normal walking speed
    q1[0] += 0.5 * robot.height  # the root jumps half a body height
    tr._prev, tr.q = q0, q1
    v = tr._velocity()
    assert np.degrees(v[6]) == pytest.approx(10.0)
    assert np.degrees(v[7]) == pytest.approx(3.0)
    assert np.abs(v[:3]).max() == pytest.approx(0.1 * robot.height)  # root translation, local axes


def test_fit_body_scale_recovers_the_semi_axes_the_camera_sees():
    """One ellipsoid rendered 8 % longer and 6 % thinner than the model, one axis along
    the viewing ray: the two axes in the image plane are measured to 1 %, the hidden
    one keeps the model's size."""
    from kms2pin.ecm.mstep import BodyView, body_image, fit_body_scale
    from kms2pin.ecm.raycast import render_mask

    cam = Camera.default()
    inner = np.array([0.3, 0.8, 0.4])  # x across, y up, z along the ray
    truth = np.array([0.94, 1.08, 1.10])
    pose = pin.SE3(np.eye(3), np.array([0.1, -0.2, 8.0]))
    mask = render_mask(cam, [(pose, inner * truth)])
    img = body_image(cam, pose, inner * 1.35, 0.7, max_pixels=10**9)  # a box that holds both outlines
    img.delta = body_image(cam, pose, inner, 0.7).delta
    y = mask[img.slices].ravel().astype(float)
    f, H = fit_body_scale([BodyView(img, y, np.zeros_like(y))], pose, inner, iterations=10)
    np.testing.assert_allclose(f[:2], truth[:2], rtol=0.01)
    assert abs(f[2] - 1.0) < 0.02  # along the ray: unseen, not moved towards 1.10
    assert H[2, 2] < 1e-2 * max(H[0, 0], H[1, 1])


def test_calibrate_measures_the_body_sizes_at_the_initial_pose():
    """Silhouettes of a subject whose body axes are up to 10 % off the model's
    (synth's size mismatch), at the rest pose, two cameras: the calibrated sizes are
    closer to the true ones than the model's, for most axes within 3 %."""
    from kms2pin.ecm.synth import body_scales

    robot = _robot("lowerbody")
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    truth = body_scales(robot, 0.1, np.random.default_rng(21))
    masks = render(robot, robot.q_rest, cams, truth)
    tr = Tracker(robot, cams)
    est = tr.calibrate(masks)
    err_model = np.abs(np.log(truth))
    err_est = np.abs(np.log(est / truth))
    assert err_est.mean() < 0.4 * err_model.mean()
    assert np.median(err_est) < 0.03
    # the tracker now uses the measured sizes, and the fit at the true pose improves
    fit_cal = tr._iou(robot.q_rest, masks)
    fit_model = Tracker(robot, cams, calibrate_sizes=False)._iou(robot.q_rest, masks)
    assert fit_cal > fit_model + 0.02
    np.testing.assert_allclose(tr.inner[3], robot.inner(robot.bodies[3]) * est[3])


def test_sizes_along_the_viewing_ray_are_measured_once_turned_into_view():
    """One camera, clean silhouettes of the lower body's walk, which starts facing the
    camera and is side-on by frame 20.  The pelvis and the trunk are 15 % deeper than
    the model (the axis along the viewing ray at rest), the rest as modelled.  The
    first frame's calibration cannot see that axis and keeps the model's depth.  Tracked
    on, the refined sizes go more than 40 % of the way to it by frame 100 (measured:
    1.085-1.09; the pose, fitted with the model's sizes, takes up part of the rest), and
    keeping the first frame's sizes (``size_every=0``) stays at the model's."""
    robot = load(DIR / "anatomical" / "lowerbody.kms", root="free")
    walk = make_motion(robot, "walk", 100)
    cam = Camera.default()
    truth = np.ones((len(robot.bodies), 3))
    deep = {}
    for name in ("pelvis", "trunk"):
        i = robot.bodies.index(name)
        P = robot.body_pose(robot.q_rest, name)
        ray = P.translation - cam.centre
        deep[i] = int(np.argmax(np.abs(P.rotation.T @ ray)))  # the body axis along the ray
        assert abs(P.rotation[:, deep[i]] @ ray) > 0.95 * np.linalg.norm(ray)
        truth[i, deep[i]] = 1.15
    frames = [render(robot, q, [cam], truth) for q in walk]
    out = {}
    for every in (0, 5):
        tr = Tracker(robot, [cam], upright=0.1, size_every=every)
        tr.step(frames[0])
        first = tr.scales.copy()
        for masks in frames[1:]:
            tr.step(masks)
        out[every] = first, tr.scales.copy()
    for i, k in deep.items():
        for every in (0, 5):
            assert abs(out[every][0][i, k] - 1.0) < 0.03  # the calibration: the model's depth
        assert abs(out[0][1][i, k] - 1.0) < 0.03  # kept
        assert abs(out[5][1][i, k] - 1.15) < 0.6 * 0.15  # measured once in view
    # the other axes stay near their true sizes (measured: median 0.9 %, the worst 3.5 %)
    seen = np.ones_like(truth, dtype=bool)
    for i, k in deep.items():
        seen[i, k] = False
    err = np.abs(out[5][1][seen] - truth[seen])
    assert np.median(err) < 0.015 and err.max() < 0.05


def test_scales_are_kept_and_checked():
    robot = _robot("lowerbody")
    cams = _cams(robot)
    sc = np.full((len(robot.bodies), 3), 1.05)
    tr = Tracker(robot, cams, scales=sc, calibrate_sizes=False)
    for _ in range(11):  # past two of the size refinement's frames (size_every=5)
        tr.step(render(robot, robot.q_rest, cams))
    np.testing.assert_array_equal(tr.scales, sc)  # neither measured nor refined
    with pytest.raises(ValueError, match="scales"):
        Tracker(robot, cams, scales=np.ones((2, 3)))


# ----------------------------------------------------------------------------- mirror hypothesis


def _anatomical():
    return load(DIR / "anatomical" / "lowerbody.kms", root="free")


def _root_angle_deg(a, b) -> float:
    Ra, Rb = pin.XYZQUATToSE3(a[:7]).rotation, pin.XYZQUATToSE3(b[:7]).rotation
    return float(np.degrees(np.linalg.norm(pin.log3(Ra.T @ Rb))))


def test_alternative_hypotheses_are_on_for_one_camera_and_a_left_right_model(tmp_path):
    robot = _anatomical()
    one = Tracker(robot, _cams(robot, 1))
    assert one.mirror_hypothesis and one.swap_hypothesis
    two = Tracker(robot, _cams(robot, 2))
    assert not two.mirror_hypothesis and not two.swap_hypothesis
    off = Tracker(robot, _cams(robot, 1), mirror_hypothesis=False, swap_hypothesis=False)
    assert not off.mirror_hypothesis and not off.swap_hypothesis
    hand = _robot("jplhand")  # no left/right bodies
    assert not Tracker(hand, _cams(hand, 1)).mirror_hypothesis
    assert not Tracker(hand, _cams(hand, 1)).swap_hypothesis
    with pytest.raises(ValueError, match="left/right"):
        Tracker(hand, _cams(hand, 1), mirror_hypothesis=True)
    with pytest.raises(ValueError, match="left/right"):
        Tracker(hand, _cams(hand, 1), swap_hypothesis=True)
    capitals = tmp_path / "capitals.kms"  # LeftThigh / RightThigh: names compared in lower case
    capitals.write_text((DIR / "anatomical" / "lowerbody.kms").read_text().replace("left", "Left").replace("right", "Right"))
    cap = load(capitals, root="free")
    assert "LeftThigh_hip" in cap.joint_names
    assert Tracker(cap, _cams(cap, 1)).swap_hypothesis and Tracker(cap, _cams(cap, 1)).mirror_hypothesis
    thesis = _robot("lowerbody")  # no joint limits: the mirror only, unless asked
    assert Tracker(thesis, _cams(thesis, 1)).mirror_hypothesis
    assert not Tracker(thesis, _cams(thesis, 1)).swap_hypothesis
    assert Tracker(thesis, _cams(thesis, 1), swap_hypothesis=True).swap_hypothesis


@pytest.mark.parametrize("name", ["lowerbody", "fullbody"])
def test_the_swap_hypothesis_is_the_body_reflected_through_its_own_left_right_plane(name):
    """Exchanging the left and right joints' angles puts every body where the
    reflection of the body through its sagittal plane puts its twin (leftThigh <->
    rightThigh, the trunk onto itself), seen from any camera as the same silhouette
    under a reflection: checked with forward kinematics at random poses."""
    robot = load(DIR / "anatomical" / f"{name}.kms", root="free")
    tr = Tracker(robot, _cams(robot, 1))
    a, b = tr._swap_pairs
    names = [robot.model.names[j] for j in range(1, robot.model.njoints)]
    assert {robot.model.names[j] for j in range(1, robot.model.njoints) if robot.model.joints[j].idx_q in a} == {
        n for n in names if n.startswith("left")
    }
    root0 = pin.XYZQUATToSE3(robot.q_rest[:7])
    hips = [robot.body_pose(robot.q_rest, n).translation for n in ("leftThigh", "rightThigh")]
    lateral = root0.rotation.T @ (hips[0] - hips[1])
    lateral /= np.linalg.norm(lateral)
    reflect = np.eye(3) - 2 * np.outer(lateral, lateral)  # independent of the tracker's own
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = robot.clamp(robot.random_configuration(rng, 40))
        s = tr._swap(q)
        np.testing.assert_array_equal(tr._swap(s), q)
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
    tr = Tracker(robot, [far])
    rng = np.random.default_rng(3)
    for _ in range(4):
        q = robot.q_rest.copy()
        yaw = rng.uniform(-np.pi, np.pi)
        R = pin.exp3(np.array([0.0, yaw, 0.0])) @ pin.XYZQUATToSE3(q[:7]).rotation
        q[3:7] = pin.Quaternion(R).coeffs()
        m = tr._mirror(q)
        np.testing.assert_allclose(tr._mirror(m), q, atol=1e-12)  # an involution
        np.testing.assert_allclose(m[7:], q[7:])  # joints kept
        a, b = render(robot, q, [far])[0], render(robot, m, [far])[0]
        assert (a & b).sum() / (a | b).sum() > 0.97
    # facing the camera <-> facing away from it: a half turn about the vertical
    cam = Camera.default()
    m = Tracker(robot, [cam])._mirror(robot.q_rest)
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
    q0 = Tracker(robot, cams, q0=motion[0])._mirror(motion[0])
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
        iterate = tr.iterate

        def spy(q, masks, delta_px, timings, cameras=None):
            widths.append((cameras or tr.cameras)[0].width)
            assert masks[0].shape == ((cameras or tr.cameras)[0].height, widths[-1])
            return iterate(q, masks, delta_px, timings, cameras)

        tr.iterate = spy
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

def test_image_motion_is_the_pinhole_displacement_of_the_outline_points():
    robot = _robot("lowerbody")
    cam = Camera.default()
    tr = Tracker(robot, [cam])
    q = robot.q_rest.copy()
    a = tr._outline_points(q)
    assert a.shape == (7 * len(robot.bodies), 3)
    # each body's centre and the ends of its inner ellipsoid's axes
    centres = robot.maximal_coordinates(q)[:, :3]
    np.testing.assert_allclose(a.reshape(-1, 7, 3).mean(axis=1), centres, atol=1e-12)
    q2 = q.copy()
    q2[0] += 0.05  # the root 0.05 along world x, across the default camera's view
    b = tr._outline_points(q2)
    np.testing.assert_allclose(b - a, np.tile([0.05, 0.0, 0.0], (len(a), 1)), atol=1e-12)
    # pinhole: a point at depth z moves f * dx / z pixels
    z = (a - cam.centre) @ cam.world_R_camera[:, 2]
    expected = cam.K[0, 0] * 0.05 / z.min()
    assert tr._image_motion(tr._outline_pixels(q), tr._outline_pixels(q2)) == pytest.approx(expected, rel=1e-9)
    # the poses kept for the last configuration follow it, also when it is changed in place
    np.testing.assert_array_equal(tr._outline_points(q), a)
    q[0] += 0.05
    np.testing.assert_array_equal(tr._outline_points(q), b)


def _still_subject():
    """The lower body at a random pose seen by one camera, its clean masks, and tracker
    options starting from that pose with nothing else on."""
    robot = _robot("lowerbody")
    cams = _cams(robot, 1)
    qt = robot.q_rest.copy()
    qt[7:] += np.radians(np.random.default_rng(3).uniform(-15, 15, robot.nq - 7))
    kw = dict(q0=qt, mirror_hypothesis=False, swap_hypothesis=False, calibrate_sizes=False)
    return robot, cams, qt, render(robot, qt, cams), kw


def test_one_camera_still_subject_converges_on_the_outline_test():
    """With one camera, a body's depth is barely seen and creeps from iteration to
    iteration after its outline has settled: the outline test stops the iterations."""
    robot, cams, qt, masks, kw = _still_subject()
    tr = Tracker(robot, cams, **kw)
    res = [tr.step(masks) for _ in range(4)]
    assert all(r.converged for r in res[1:])
    assert max(r.iterations for r in res[1:]) < tr.max_iterations
    # one view fixes depth only through the outline's size: the track settles about 3 %
    # of the height off in depth (as with the joint-angle test alone), not further
    assert centre_error(robot, res[-1].q, qt) < 5.0


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
    tr = Tracker(robot, cams, depth_prior=1.0, **kw)
    tr._anchor = qt[:3] + np.array([0.05, -0.02, 0.3])
    q = robot.random_configuration(np.random.default_rng(4), 20)
    nv = robot.model.nv
    A, g = np.eye(nv), np.zeros(nv)
    pin.forwardKinematics(robot.model, robot.data, q)
    k = 0.7
    e0 = tr._depth_spring(A, g, robot.data, k)
    n = tr._anchor - cams[0].centre
    n /= np.linalg.norm(n)

    def energy(dv):
        p = pin.integrate(robot.model, q, dv)[:3]
        return 0.5 * k * float(n @ (p - tr._anchor)) ** 2

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
    np.testing.assert_allclose(pin.XYZQUATToSE3(robot.q_rest[:7]).rotation @ tr._up_root, up, atol=1e-12)
    nv = robot.model.nv
    k = 1.3

    def energy(q):
        R = pin.XYZQUATToSE3(q[:7]).rotation
        return 0.5 * k * float(np.sum((R @ tr._up_root - up) ** 2))

    eps = 1e-6
    for seed in range(3):
        rng = np.random.default_rng(seed)
        q = robot.random_configuration(rng, 20)
        q[3:7] = pin.Quaternion(pin.exp3(rng.uniform(-1.0, 1.0, 3))).coeffs()  # a tilted root
        A, g = np.eye(nv), np.zeros(nv)
        pin.forwardKinematics(robot.model, robot.data, q)
        assert tr._upright_spring(A, g, robot.data, k) == pytest.approx(energy(q), rel=1e-12)
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
    tr._upright_spring(A, g, robot.data, k)
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
    nv, k = robot.model.nv, 0.7
    angles = [robot.model.joints[j].idx_q for j in range(2, robot.model.njoints)]  # every joint but the root

    def energy(q):
        return 0.5 * k * float(np.sum((q[angles] - robot.q_rest[angles]) ** 2))

    rng = np.random.default_rng(3)
    q = robot.random_configuration(rng, 30)
    A, g = np.zeros((nv, nv)), np.zeros(nv)
    assert tr._rest_spring(A, g, q, k) == pytest.approx(energy(q), rel=1e-12)
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

    for prior in (0.0, 0.05):
        tr = Tracker(robot, _cams(robot, 1), rest_prior=prior, stiffness_floor=0.0, static_iterations=60,
                     calibrate_sizes=False)
        q = tr._static_update_full(q_t.copy(), [BodyFit(P, h.copy(), 0.0, 0.0) for P, h in zip(targets, H)])
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
    tilt = [np.arccos(np.clip(pin.XYZQUATToSE3(r.q[:7]).rotation @ tr._up_root @ tr.up, -1, 1)) for r in res]
    assert np.degrees(max(tilt)) < 5.0
    # the truth's heading turns by 180 degrees over the segment; the track's ends with it
    Ra, Rb = (pin.XYZQUATToSE3(x[:7]).rotation for x in (res[-1].q, seg[-1]))
    assert np.degrees(np.linalg.norm(pin.log3(Ra.T @ Rb))) < 10.0


def test_limbs_are_the_chains_off_the_root_and_the_branching_bodies():
    fullbody = load(DIR / "fullbody.kms", root="free")
    assert limb_joints(fullbody) == [
        "leftThigh_hip", "rightThigh_hip", "trunk_waist", "leftUpperArm_shoulder", "rightUpperArm_shoulder",
    ]
    hand = _robot("jplhand")  # the palm's wrist hangs off the free root, the fingers off the palm
    assert limb_joints(hand) == ["palm_wrist", "lowFinger1_lowerJoint", "lowFinger2_lowerJoint", "lowThumb_lowerJoint"]
    # on the spec's root the wrist is on the world: the root is not a limb
    assert "palm_wrist" not in limb_joints(load(DIR / "jplhand.kms"))
    assert Tracker(fullbody, _cams(fullbody, 1)).limb_search
    assert Tracker(fullbody, _cams(fullbody, 2)).limb_search
    assert not Tracker(fullbody, _cams(fullbody, 2), limb_search=False).limb_search


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
    q, fit, limb = tr.swing_limbs(q0, masks)
    assert limb == "leftUpperArm_shoulder"
    assert fit > fit_ecm + 0.03
    assert joint_errors(robot, q, qt).max() < 3.0
    assert centre_error(robot, q, qt) < 0.5
    np.testing.assert_array_equal(tr.q, qt)  # the tracker is left as it was
    # from the truth there is nothing to swing
    q, fit, limb = tr.swing_limbs(qt, masks)
    assert limb == "" and joint_errors(robot, q, qt).max() < 3.0


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
    pairs, tr._limb_pairs = tr._limb_pairs, []  # the single limbs' swings alone do not help
    assert tr.swing_limbs(q0, masks)[2] == ""
    tr._limb_pairs = pairs
    q, fit, limb = tr.swing_limbs(q0, masks)
    assert limb == "leftUpperArm_shoulder and rightUpperArm_shoulder"
    assert fit > fit_ecm + 0.005
    assert joint_errors(robot, q, qt).max() < 3.0
    assert centre_error(robot, q, qt) < 0.5


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
    q, fit, limb = tr.swing_limbs(q0, masks)
    assert limb == "lowFinger1_lowerJoint reset"
    assert fit > fit_ecm + 0.05
    assert np.degrees(np.abs(q[[mid, tip]] - qt[[mid, tip]])).max() < 5.0
    # one view fixes the rest only so far (the thumb's lower joint, the hand's distance)
    assert joint_errors(robot, q, qt).max() < 10.0 and centre_error(robot, q, qt) < 1.0


def _folded_finger_frame(cams, finger, off_deg, search, **options):
    """The hand's random motion (seed 0) tracked from the truth on clean silhouettes for
    frames 34-39 (the search on a falling fit waits until the running fit has settled,
    five frames), then frame 40 started with ``finger``'s middle and tip joints
    ``off_deg`` off; returns the tracker (``options`` passed on), frame 40's result, the
    true configuration and the tip's q index."""
    robot = _robot("jplhand")
    motion = make_motion(robot, "random", 300, np.random.default_rng(0))
    m = robot.model
    mid, tip = (m.joints[m.getJointId(n)].idx_q for n in (f"midFinger{finger}_lowerJoint", f"tip{finger}_joint"))
    tr = Tracker(robot, cams, q0=motion[34], prediction="previous", calibrate_sizes=False, limb_search=search, **options)
    for f in range(34, 40):
        assert not tr.step(render(robot, motion[f], cams)).flags
    tr.q[mid] += np.radians(off_deg[0])
    tr.q[tip] += np.radians(off_deg[1])
    return tr, tr.step(render(robot, motion[40], cams)), motion[40], tip


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
    real = tr._exchange_crossed_limbs
    monkeypatch.setattr(tr, "_exchange_crossed_limbs", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(tr, "_swing_limbs", lambda q, fit, *a, **k: searches.append((tr.frame, k)) or (q, fit, ""))
    for f in range(3):
        tr.step(render(robot, walk[f], cams))
    assert tr.limb_search and len(calls) == (2 if n_cams == 1 else 0)
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
    v, m = tr._velocity(), tr.robot.model
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
        qa, last, score, fa = tr._alts["limb"]
        assert fa > r.fit + 0.003 and score > tr._score  # it fit this frame better
        assert np.degrees(abs(qa[tip] - qt[tip])) < 6.0 and last[tip] == qa[tip]  # measured 4.8 deg
    else:
        assert not tr._alts
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
    assert Tracker(robot, [Camera.default()]).limb_hypothesis
    assert not Tracker(robot, _cams(robot, 2)).limb_hypothesis
    assert not Tracker(robot, [Camera.default()], limb_search=False, limb_hypothesis=True).limb_hypothesis


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
        out[search] = r, tr._velocity()[[j.idx_v for j in arms]]
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
        monkeypatch.setattr(tr, "_swing_limbs", lambda q, fit, *a: (q, fit, " and ".join(arms)))
        monkeypatch.setattr(tr, "_exchange_crossed_limbs", lambda q, fit, *a, p=second: (q, fit, " and ".join(p)))
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
            assert tr._velocity()[iv] == 0.0
    assert "swung 'leftUpperArm_shoulder' the other way" in flags[True]
    assert not any("swung" in x for x in flags[False])


def test_e_step_scratch_image_leaves_nothing_behind():
    """The E-step reuses a per-camera union image, re-zeroed over the bodies' boxes: an
    E-step after others at different poses gives exactly a fresh tracker's views."""
    robot = _robot("fullbody")
    cams = _cams(robot)
    rng = np.random.default_rng(12)
    qs = [robot.random_configuration(rng, 40) for _ in range(3)]
    masks = render(robot, qs[2], cams)
    used = Tracker(robot, cams)
    for q in qs[:2]:
        used.e_step(q, masks, 1.0)
    assert all(not buf.any() for buf in used._scratch.values()) and len(used._scratch) == len(cams)
    _, views = used.e_step(qs[2], masks, 0.7)
    _, fresh = Tracker(robot, cams).e_step(qs[2], masks, 0.7)
    for va, vb in zip(views, fresh):
        assert len(va) == len(vb)
        for a, b in zip(va, vb):
            np.testing.assert_array_equal(a.o, b.o)
            np.testing.assert_array_equal(a.y, b.y)


@pytest.mark.parametrize("shape", [(240, 320), (7, 9), (1, 5)])
def test_bin_mask_gives_each_blocks_set_fraction(shape):
    from kms2pin.ecm.tracker import bin_mask

    rng = np.random.default_rng(shape[0])
    mask = rng.random(shape) < 0.4
    h, w = shape[0] // 2, shape[1] // 2
    out = bin_mask(mask)
    assert out.shape == (h, w) and out.dtype == np.float64
    blocks = mask[: 2 * h, : 2 * w].reshape(h, 2, w, 2).sum(axis=(1, 3)) / 4.0
    np.testing.assert_array_equal(out, blocks)


def test_wide_edge_iterations_run_on_binned_masks_and_the_pose_is_recovered(monkeypatch):
    """coarse_delta_px: the iterations whose edge is at least that wide see each camera
    binned 2x2 (half the edge width in binned pixels, the masks' block fractions);
    the narrow-edge ones full resolution.  Both schedules recover the pose."""
    robot = _robot("lowerbody")
    rng = np.random.default_rng(21)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    masks = render(robot, qt, cams)
    seen = []
    real = Tracker.iterate

    def spy(self, q, m, delta, timings, cameras=None):
        cams_used = self.cameras if cameras is None else cameras
        seen.append((delta, [c.shape for c in cams_used], [x.dtype for x in m]))
        if cameras is not None:  # each binned mask is its block fractions of the mask
            for full, binned in zip(masks, m):
                np.testing.assert_array_equal(binned, full.reshape(120, 2, 160, 2).mean(axis=(1, 3)))
        return real(self, q, m, delta, timings, cameras)

    monkeypatch.setattr(Tracker, "iterate", spy)
    errs = {}
    for coarse in (1.4, None):
        seen.clear()
        tr = Tracker(robot, cams, q0=q0, max_iterations=10, calibrate_sizes=False, coarse_delta_px=coarse)
        r = tr.step(masks)
        errs[coarse] = centre_error(robot, r.q, qt)
        assert r.fit > 0.97
        if coarse is None:
            assert all(shapes == [(240, 320)] * 2 and delta <= 2.8 for delta, shapes, _ in seen)
        else:  # 2.8 and 1.4 px binned (1.4 and 0.7 binned pixels), then 0.7 px at full size
            assert [(d, s) for d, s, _ in seen[:3]] == [(1.4, [(120, 160)] * 2), (0.7, [(120, 160)] * 2),
                                                         (0.7, [(240, 320)] * 2)]
            assert all(dt == np.float64 for _, _, dts in seen[:2] for dt in dts)
            assert all(s == [(240, 320)] * 2 for _, s, _ in seen[2:])
    before = centre_error(robot, q0, qt)
    assert max(errs.values()) < 0.5 and max(errs.values()) < 0.2 * before
    for bad in (0.0, 0.7, -1.0, float("nan")):  # the final, narrow-edge iterations stay at full size
        with pytest.raises(ValueError, match="coarse_delta_px"):
            Tracker(robot, cams, coarse_delta_px=bad)


def test_the_one_call_e_step_gives_the_per_body_kernels_views():
    """Tracker.e_step runs a camera in one C call (estep_camera) unless a body needs the
    per-body path; both give the same views to the last bit, and leave the scratch
    image zeroed."""
    require_kernels()
    robot = _robot("fullbody")
    cams = _cams(robot)
    rng = np.random.default_rng(5)
    q = robot.random_configuration(rng, 30)
    masks = render(robot, robot.random_configuration(rng, 30), cams)
    from kms2pin.ecm.tracker import bin_mask

    for ms, cs, delta in ((masks, None, 0.7), ([bin_mask(m) for m in masks], [c.binned(2) for c in cams], 1.4)):
        one = Tracker(robot, cams)
        calls = []
        real = one._e_step_fused
        one._e_step_fused = lambda *a: calls.append(1) or real(*a)
        _, fused = one.e_step(q, ms, delta, cs)
        assert len(calls) == 2 and all(not b.any() for b in one._scratch.values())
        per_body = Tracker(robot, cams)
        per_body._e_step_fused = lambda *a: None
        _, ref = per_body.e_step(q, ms, delta, cs)
        assert sum(len(v) for v in ref) > len(robot.bodies)
        for va, vb in zip(fused, ref):
            assert len(va) == len(vb)
            for a, b in zip(va, vb):
                assert a.image.box == b.image.box and a.image.delta == b.image.delta
                for x, y in ((a.y, b.y), (a.o, b.o), (a.image.s, b.image.s), (a.image.dirs, b.image.dirs)):
                    np.testing.assert_array_equal(x, y)


def test_refine_fits_one_frame_from_a_given_pose_and_leaves_the_tracker_as_it_was():
    robot = _robot("lowerbody")
    rng = np.random.default_rng(23)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    masks = render(robot, qt, cams)
    tr = Tracker(robot, cams, calibrate_sizes=False)
    tr.step(render(robot, robot.q_rest, cams))
    state = (tr.q.copy(), tr._prev.copy(), tr.frame)
    q0 = _perturbed(robot, qt, rng)
    q, fit = tr.refine(q0, masks)
    assert fit > 0.97 and fit == pytest.approx(tr._iou(q, tr._masks(masks, "x")))
    assert centre_error(robot, q, qt) < 0.5 < centre_error(robot, q0, qt)
    np.testing.assert_array_equal(tr.q, state[0])
    np.testing.assert_array_equal(tr._prev, state[1])
    assert tr.frame == state[2] and tr.cameras == cams


def test_fit_is_the_iou_of_the_model_silhouettes_and_what_a_step_reports():
    """Tracker.fit: at the pose the masks were ray cast from (the spec's sizes) the model
    overlaps them almost exactly; with a knee bent 20° further it fits worse, by the IoU
    of that pose's own ray-cast masks with them; after a step it gives the frame's fit."""
    robot = _robot("lowerbody")
    cams = _cams(robot)
    masks = render(robot, robot.q_rest, cams)
    tr = Tracker(robot, cams, calibrate_sizes=False)
    at_truth = tr.fit(robot.q_rest, masks)
    assert at_truth > 0.97
    q = robot.q_rest.copy()
    q[robot.model.joints[robot.model.getJointId("leftShin_knee")].idx_q] += np.radians(20)
    bent = render(robot, q, cams)
    direct = sum(np.count_nonzero(a & b) for a, b in zip(bent, masks)) / sum(
        np.count_nonzero(a | b) for a, b in zip(bent, masks))
    assert tr.fit(q, masks) == pytest.approx(direct, abs=0.02)
    assert tr.fit(q, masks) < at_truth - 0.02
    res = tr.step(masks)
    assert res.fit == pytest.approx(tr.fit(res.q, masks), abs=1e-12)
    with pytest.raises(ValueError, match="nq"):
        tr.fit(robot.q_rest[:5], masks)


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
    monkeypatch.setattr(tr, "_swing_limbs", lambda q, fit, *a: frames.append(tr.frame) or (q, fit, ""))
    for f in range(8):
        tr.step(render(robot, walk[f], cams))
    assert frames == [5, 6, 7]


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(max_iterations=0), "max_iterations must be >= 1, not 0"),
        (dict(max_iterations=8.0), "max_iterations must be a whole number, not 8.0"),
        (dict(min_iterations=10, max_iterations=2), "min_iterations (10) must not exceed max_iterations (2)"),
        (dict(delta_start=-1.0), "delta_start must be > 0.0, not -1.0"),
        (dict(delta_start=0.5, delta_final=0.7), "delta_start (0.5) must not be below delta_final (0.7)"),
        (dict(damping=float("nan")), "damping must be >= 0.0, not nan"),
        (dict(tol_deg=-1.0), "tol_deg must be >= 0.0, not -1.0"),
        (dict(size_every=-1), "size_every must be >= 0, not -1"),
        (dict(limb_search_drop="0.03"), "limb_search_drop must be a number, not '0.03'"),
        (dict(poor_fit=1.5), "poor_fit must be >= 0.0 and <= 1.0, not 1.5"),
        (dict(hypothesis_smoothing=0.0), "hypothesis_smoothing must be > 0.0 and <= 1.0, not 0.0"),
        (dict(upright=-1.0), "upright must be >= 0.0, not -1.0"),
        (dict(mirror_hypothesis=True, tol_px=0.0), "tol_px must be > 0.0 or None, not 0.0"),
    ],
)
def test_an_option_out_of_range_is_an_option_error_naming_it(options, message):
    robot = _robot("lowerbody")
    with pytest.raises(OptionError) as err:
        Tracker(robot, Camera.default(), **options)
    assert str(err.value) == message
    assert isinstance(err.value, ValueError)  # what Python code catching bad arguments expects


def test_a_misspelt_option_suggests_the_right_one_and_a_nan_start_is_refused():
    robot = _robot("lowerbody")
    with pytest.raises(TypeError, match=r"unknown option 'uprigth' \(did you mean 'upright'\?\)"):
        Tracker(robot, Camera.default(), uprigth=0.1)
    with pytest.raises(InputDataError, match="initial pose is not finite"):
        Tracker(robot, Camera.default(), q0=np.full(robot.nq, np.nan))
