"""kms2pin.ecm.stretches: a finished recording's tracks beside, each stretch from the track
that fits it best, judged on masks rendered from a known motion."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm.bothways import SWITCH, TOLERANCE, apart, apart_tracks
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.silhouette import silhouette_iou
from kms2pin.ecm.stretches import stretches, track_poses
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker

from ._tracking import _robot


@pytest.fixture(scope="module")
def scene():
    robot = _robot("lowerbody")
    qs = make_motion(robot, "walk", 40)[10:30]
    cams = [Camera.look_at(position=qs[0][:3] + [0.0, 0.5, 6.0], target=qs[0][:3], width=160, height=120),
            Camera.look_at(position=qs[0][:3] + [5.0, 2.0, 3.0], target=qs[0][:3], width=160, height=120)]
    return robot, qs, cams


def _shifted(qs: np.ndarray, frames, metres: float) -> np.ndarray:
    """``qs`` with the root moved ``metres`` sideways on ``frames``: a track lost there."""
    lost = qs.copy()
    lost[frames, 0] += metres
    return lost


def test_a_lost_track_that_fits_best_on_one_frame_is_not_taken_there(scene):
    """Track 0 is the truth; track 1 is lost (the root 0.8 m off) on frames 5-14, and frame 9's
    masks are rendered with the root 0.5 m off, nearer the lost pose, so there it fits better:
    taken frame by frame that is a jump there and back, which the two changes of track cost
    more than the frame gains."""
    robot, qs, cams = scene
    lost = _shifted(qs, slice(5, 15), 0.8)
    masks = [render(robot, q, cams) for q in qs]
    masks[9] = render(robot, _shifted(qs, [9], 0.5)[9], cams)
    tracker = Tracker(robot, cams, q0=qs[0])
    st = stretches(tracker, masks, np.stack([qs, lost], axis=1), sweeps=0)  # frame 9 alone: not from the frames beside
    # the fits are each pose's IoU at the tracker's sizes, computed here from the silhouettes
    for k in (0, 9, 12):
        for t, q in enumerate((qs[k], lost[k])):
            assert st.fits[k, t] == pytest.approx(silhouette_iou(robot.body_poses(q), tracker.inner, cams, masks[k]),
                                                  abs=1e-12)
    assert st.fits[9, 1] > st.fits[9, 0] + 0.01  # frame by frame, frame 9 would be the lost track's
    # the cost of the jump: two changes at the frames beside, where the tracks are 0.8 m apart
    far = apart(robot, qs, lost)
    assert 2 * SWITCH * (far[8] - TOLERANCE) > st.fits[9, 1] - st.fits[9, 0]
    assert not st.track.any()
    np.testing.assert_array_equal(st.q, qs)
    np.testing.assert_allclose(st.fit, st.fits[:, 0])
    assert (st.parts == -1).all() and not st.beside.any()  # the lost track differs in its root alone


def test_a_limb_one_track_lost_is_taken_from_another_track_that_holds_it(scene):
    """Track 0 has a knee bent far off on frames 4-8 and is kept (track 1 is lost, its root
    0.8 m off, on frames 2-15); the knee is taken from track 1, whose knee is right there."""
    robot, qs, cams = scene
    knee = next(j for j in robot.joints if j.kind == "revolute")
    bent = qs.copy()
    bent[4:9, knee.idx_q] += 1.2
    lost = _shifted(qs, slice(2, 16), 0.8)
    masks = [render(robot, q, cams) for q in qs]
    tracker = Tracker(robot, cams, q0=qs[0])
    st = stretches(tracker, masks, np.stack([bent, lost], axis=1), sweeps=0)
    assert not st.track.any()
    h = st.part_names.index(knee.name)
    assert (st.parts[4:9, h] == 1).all() and (st.parts[9:16] == -1).all()
    np.testing.assert_allclose(st.q[4:9, knee.idx_q], qs[4:9, knee.idx_q], atol=1e-12)
    np.testing.assert_array_equal(np.delete(st.q[4:9], knee.idx_q, axis=1), np.delete(bent[4:9], knee.idx_q, axis=1))
    assert (st.fit[4:9] > st.fits[4:9, 0]).all()


def test_a_stretch_one_track_lost_is_taken_from_the_other_whichever_comes_first(scene):
    robot, qs, cams = scene
    lost = _shifted(qs, slice(6, 13), 0.3)
    masks = [render(robot, q, cams) for q in qs]
    tracker = Tracker(robot, cams, q0=qs[0])
    for order in ((lost, qs, lost), (qs, lost, lost)):
        st = stretches(tracker, masks, np.stack(order, axis=1))
        true_track = 0 if order[0] is qs else 1
        assert (st.track[6:13] == true_track).all()  # the lost stretch from the held track
        np.testing.assert_array_equal(st.q[6:13], qs[6:13])
        np.testing.assert_array_equal(st.q, qs)  # elsewhere the tracks are the same poses
        assert (st.fit >= st.fits.max(axis=1) - 1e-12).all()


def test_apart_tracks_is_apart_for_each_pair(scene):
    robot, qs, cams = scene
    lost = _shifted(qs, slice(3, 8), 0.2)
    far = apart_tracks(robot, np.stack([qs, lost, qs], axis=1))
    assert far.shape == (len(qs), 3, 3)
    # the mean body-centre distance, frame by frame, from the body poses here
    centres = [np.mean([np.linalg.norm(a.translation - b.translation) for a, b in zip(robot.body_poses(x),
                                                                                      robot.body_poses(y))])
               for x, y in zip(qs, lost)]
    np.testing.assert_allclose(far[:, 0, 1], np.array(centres) / robot.height, atol=1e-12)
    np.testing.assert_array_equal(apart(robot, qs, lost), far[:, 0, 1])
    np.testing.assert_allclose(far[:, 1, 0], far[:, 0, 1], atol=1e-12)
    np.testing.assert_allclose(far[:, 0, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(far[3:8, 0, 1], 0.2 / robot.height, atol=1e-9)  # every body moved 0.2 m


def test_each_track_goes_on_by_itself_and_its_poses_are_the_tracks_alone(scene):
    """``track_poses`` after each frame is each track's own pose: that of the same track run
    alone, to the last bit; stretches of them keep a track's pose on each frame."""
    robot, qs, cams = scene
    masks = [render(robot, q, cams) for q in qs[:8]]
    weak = {"max_iterations": 1, "min_iterations": 1, "limb_search": False}
    alone = [Tracker(robot, cams, q0=qs[0], **weak), Tracker(robot, cams, q0=qs[0], **{**weak, "max_iterations": 6})]
    both = Tracker(robot, cams, q0=qs[0], **weak, second_track="max_iterations=6")
    assert len(both.tracks_beside) == 1 and not Tracker(robot, cams, q0=qs[0]).tracks_beside
    poses = []
    for m in masks:
        for t in alone:
            t.step(m)
        both.step(m)
        poses.append(track_poses(both))
        np.testing.assert_array_equal(poses[-1], [t.q for t in alone])
    tracks = np.array(poses)
    st = stretches(both, masks, tracks)
    frames = np.arange(len(masks))
    whole = (st.parts == -1).all(axis=1) & ~st.beside.any(axis=1)  # no part taken: the kept track's pose
    assert whole.any()
    np.testing.assert_array_equal(st.q[whole], tracks[frames, st.track][whole])
    assert (st.fit >= st.fits[frames, st.track] - 1e-12).all()  # a part is taken only where it fits better


def test_the_tracks_must_have_a_pose_per_frame(scene):
    robot, qs, cams = scene
    tracker = Tracker(robot, cams, q0=qs[0])
    masks = [render(robot, q, cams) for q in qs[:3]]
    for bad in (qs[:3], np.stack([qs[:2], qs[:2]], axis=1), np.zeros((3, 0, robot.nq)), np.stack([qs[:3], qs[:3]])):
        with pytest.raises(ValueError, match="each track's pose on each frame"):
            stretches(tracker, masks, bad)
