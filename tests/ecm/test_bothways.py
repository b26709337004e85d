"""kms2pin.ecm.bothways: a stretch the forward track lost is taken from the backward track,
judged against the true motion the masks were rendered from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import kms2pin
from kms2pin.ecm import Camera, make_motion, synthesize
from kms2pin.ecm.bothways import MARGIN, both_ways

DIR = Path(__file__).resolve().parents[2] / "specs"


@pytest.fixture(scope="module")
def walk():
    robot = kms2pin.load(DIR / "lowerbody.kms", root="free")
    rng = np.random.default_rng(4)
    motion = make_motion(robot, "walk", 16, rng)
    cams = [Camera.default(), Camera.look_at(position=[8, 3, 8], target=robot.q_rest[:3])]
    masks = [m for _, m in synthesize(robot, motion, cams, noise=0.02, rng=rng)]
    return robot, cams, motion, masks


def _centre_error(robot, q, truth) -> np.ndarray:
    """(frames,) mean body-centre distance from the truth."""
    return np.array([np.mean([np.linalg.norm(a.translation - b.translation)
                              for a, b in zip(robot.body_poses(x), robot.body_poses(t))]) for x, t in zip(q, truth)])


def test_a_stretch_the_forward_track_lost_is_taken_from_the_backward_track(walk):
    robot, cams, truth, masks = walk
    forward = truth.copy()
    lost = slice(4, 9)  # the forward "track" is the truth but for a knee bent far off on frames 4-8
    knee = next(j for j in robot.joints if j.kind == "revolute")
    forward[lost, knee.idx_q] += 1.2
    bw = both_ways(robot, cams, masks, forward)
    assert bw.q.shape == truth.shape and len(bw.results) == len(masks)
    assert bw.backward[lost].all()  # tracked back from the true last pose, those frames fit better
    assert (bw.fit_backward[lost] > bw.fit_forward[lost] + MARGIN).all()
    err_forward, err_kept = _centre_error(robot, forward, truth), _centre_error(robot, bw.q, truth)
    assert err_kept[lost].max() < 0.25 * err_forward[lost].min()
    # elsewhere the forward poses are the truth: kept unless the backward pose fits better by the margin
    assert np.array_equal(bw.q[~bw.backward], forward[~bw.backward])
    assert np.allclose(bw.fit, np.where(bw.backward, bw.fit_backward, bw.fit_forward))


def test_the_forward_track_must_have_a_pose_per_frame(walk):
    robot, cams, truth, masks = walk
    with pytest.raises(ValueError, match=r"one pose per frame"):
        both_ways(robot, cams, masks, truth[:-1])


def test_frames_are_named_in_errors(walk):
    robot, cams, truth, masks = walk
    bad = list(masks)
    bad[2] = [m[:-1] for m in bad[2]]  # wrong size in frame 2
    with pytest.raises(kms2pin.Kms2pinError, match="clip.avi: frame 2"):
        both_ways(robot, cams, bad, truth, sources=[f"clip.avi: frame {k}" for k in range(len(bad))])
