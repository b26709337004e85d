"""kms2pin.ecm.temporal: a track refit over time, judged against the true motion the masks
were rendered from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import kms2pin
from kms2pin.ecm import Camera, Tracker, make_motion, synthesize
from kms2pin.ecm.loop import new_timings
from kms2pin.ecm.priors import RestPrior
from kms2pin.ecm.temporal import SPANS, SWEEPS, WEIGHT, midpoints, span, targets, temporal

DIR = Path(__file__).resolve().parents[2] / "specs"


@pytest.fixture(scope="module")
def walk():
    """The lower body walking, seen by one camera (which hardly sees the distance along its
    rays), and the tracker that measured its sizes on the first frame."""
    robot = kms2pin.load(DIR / "lowerbody.kms", root="free")
    rng = np.random.default_rng(7)
    motion = make_motion(robot, "walk", 14, rng)
    cams = [Camera.default()]
    masks = [m for _, m in synthesize(robot, motion, cams, noise=0.02, rng=rng)]
    tracker = Tracker(robot, cams, q0=motion[0])
    tracker.calibrate(masks[0])
    return robot, cams, motion, masks, tracker


def _along_ray(robot, cam: Camera, q: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(frames,) the root's distance from the truth along the camera's ray through it (m)."""
    ray = truth[:, :3] - cam.centre
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    return np.abs(np.sum((q[:, :3] - truth[:, :3]) * ray, axis=1))


def _centres(robot, q: np.ndarray, truth: np.ndarray) -> float:
    """The mean body-centre distance from the truth over the frames (m)."""
    return float(np.mean([np.mean([np.linalg.norm(a.translation - b.translation) for a, b in
                                   zip(robot.body_poses(x), robot.body_poses(t))]) for x, t in zip(q, truth)]))


def test_depth_noise_follows_the_frames_beside(walk):
    """The truth with the root moved along the camera's ray by noise (3 % of the height, one
    standard deviation, each frame its own): one view's ECM alone, as many sweeps, takes off
    less than half of it along the ray and leaves the body 3/5 of it off; the spring towards
    the frames beside leaves half of what ECM alone leaves, along the ray and in all."""
    robot, cams, truth, masks, tracker = walk
    ray = truth[:, :3] - cams[0].centre
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    noisy = truth.copy()
    noisy[:, :3] += 0.03 * robot.height * np.random.default_rng(1).standard_normal(len(truth))[:, None] * ray
    start = _along_ray(robot, cams[0], noisy, truth).mean()
    alone = temporal(tracker, masks, noisy, weight=0.0, sweeps=SWEEPS, starts=("pose",), sizes_every=0)
    held = temporal(tracker, masks, noisy, weight=0.3, sweeps=SWEEPS, starts=("pose",), sizes_every=0)
    along_alone, along_held = (_along_ray(robot, cams[0], x.q, truth).mean() for x in (alone, held))
    assert along_alone > 0.3 * start  # the masks alone hardly see it (0.41 of it left)
    assert along_held < 0.5 * along_alone  # (0.40 of what ECM alone leaves)
    assert _centres(robot, held.q, truth) < 0.6 * _centres(robot, alone.q, truth)  # (0.48)
    assert held.fit.shape == (len(truth),) and (held.fit > 0.5).all()
    assert np.allclose(held.fit, [tracker.fit(x, m) for x, m in zip(held.q, masks)])


def test_a_stiff_spring_does_not_swing_a_jitter_from_frame_to_frame(walk):
    """The root moved along the ray on every other frame only: a sweep towards the
    neighbours' midpoint alone would move those frames to the truth and the others off by as
    much (and back on the next sweep); the frame's own pose in the target (1/4, 1/2, 1/4)
    brings both sets of frames towards each other, each sweep."""
    robot, cams, truth, masks, tracker = walk
    ray = truth[:, :3] - cams[0].centre
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    odd, even = np.arange(1, len(truth), 2), np.arange(0, len(truth), 2)
    jittered = truth.copy()
    jittered[odd, :3] += 0.04 * robot.height * ray[odd]
    start = _along_ray(robot, cams[0], jittered, truth)[odd].mean()
    gaps = []
    for sweeps in (1, 2, 3):
        q = temporal(tracker, masks, jittered, weight=3.0, sweeps=sweeps, spans=()).q
        off = _along_ray(robot, cams[0], q, truth)
        assert off[odd].mean() < 0.6 * start
        gaps.append(abs(off[odd].mean() - off[even].mean()))
    assert gaps[0] < 0.2 * start and gaps[2] <= gaps[0]
    mid = targets(robot.model, jittered)
    assert np.allclose(mid[odd[1:-1], :3], jittered[odd[1:-1], :3] - 0.5 * 0.04 * robot.height * ray[odd[1:-1]],
                       atol=0.002 * robot.height)  # halfway between the frame and its neighbours


def test_one_sweep_without_the_spring_is_each_frames_ecm(walk):
    robot, _, truth, masks, tracker = walk
    start = truth.copy()
    start[:, 0] += 0.01
    out = temporal(tracker, masks, start, weight=0.0, sweeps=1, starts=("pose",))
    for k in (0, 5, len(truth) - 1):
        q, fit = tracker.refine(start[k], masks[k])
        assert np.array_equal(out.q[k], q) and out.fit[k] == fit
    same = temporal(tracker, masks, start, sweeps=0)
    assert np.array_equal(same.q, start)
    assert np.allclose(same.fit, [tracker.fit(x, m) for x, m in zip(start, masks)])


def test_each_frame_is_held_towards_its_neighbours_midpoint(walk):
    """The spring of one sweep is the rest prior at the frame's target, halfway from its pose
    to the midpoint of the frames on either side (the ends: of themselves and their
    neighbour), as refine runs it."""
    robot, _, truth, masks, tracker = walk
    start = truth.copy()
    start[3, 7] += 0.3  # a joint off on one frame
    middle = midpoints(robot.model, start)
    # the midpoint, written out: the joints' mean, the root halfway along the screw between
    for t, (a, b) in {0: (0, 1), 3: (2, 4), len(start) - 1: (len(start) - 2, len(start) - 1)}.items():
        assert np.allclose(middle[t][7:], 0.5 * (start[a][7:] + start[b][7:]))
        # the root halfway along SE(3)'s screw from one frame's placement to the other's
        A, B = (pin.XYZQUATToSE3(start[k][:7]) for k in (a, b))
        M = A * pin.exp6(0.5 * pin.log6(A.inverse() * B))
        got = pin.XYZQUATToSE3(middle[t][:7])
        assert np.allclose(got.translation, M.translation, atol=1e-9)
        assert np.allclose(got.rotation, M.rotation, atol=1e-9)
    out = temporal(tracker, masks, start, weight=0.5, sweeps=1, starts=("pose",), spans=())
    assert np.allclose(targets(robot.model, start)[3][7:], 0.25 * start[2][7:] + 0.5 * start[3][7:] + 0.25 * start[4][7:])
    prior = RestPrior(0.5, robot.model, targets(robot.model, start)[3], np.arange(robot.model.nv))
    q, fit = tracker.refine(start[3], masks[3], priors=(prior,))
    assert np.array_equal(out.q[3], q) and out.fit[3] == fit


def test_each_frame_keeps_the_best_fitting_of_its_starts(walk):
    """With several starts each frame's ECM runs from each (the frame's pose, its target,
    its neighbours' midpoint), towards the same target, and the end that fits best is kept;
    in two processes the same to the last bit."""
    robot, _, truth, masks, tracker = walk
    start = truth.copy()
    start[1::2, 7] += 0.4  # a joint off on every other frame: the target and the neighbours' midpoint lie nearer
    starts = ("pose", "target", "neighbours")
    out = temporal(tracker, masks, start, weight=0.2, sweeps=1, starts=starts, spans=())
    goal, beside = targets(robot.model, start), midpoints(robot.model, start)
    kept = []
    for k in range(len(start)):
        prior = (RestPrior(0.2, robot.model, goal[k], np.arange(robot.model.nv)),)
        ends = [tracker.refine(x, masks[k], priors=prior) for x in (start[k], goal[k], beside[k])]
        best = int(np.argmax([f for _, f in ends]))
        kept.append(best)
        assert np.array_equal(out.q[k], ends[best][0]) and out.fit[k] == ends[best][1]
    assert len(set(kept)) > 1  # not the same start on every frame
    assert np.abs(out.q[1::2, 7] - truth[1::2, 7]).mean() < 0.5 * 0.4
    both = temporal(tracker, masks, start, weight=0.2, sweeps=2, starts=starts, jobs=2)
    one = temporal(tracker, masks, start, weight=0.2, sweeps=2, starts=starts, jobs=1)
    assert np.array_equal(both.q, one.q) and np.array_equal(both.fit, one.fit)


def test_the_first_sweeps_take_the_frames_beside_farther_away(walk):
    """Coarse to fine in time: sweep k's frames beside are ``spans[k]`` frames away (fewer
    near the ends, where there are fewer; 1 past the spans), written out on the joints'
    mean; two sweeps are the first at its span, then one at 1 from its poses."""
    robot, _, truth, masks, tracker = walk
    start = truth.copy()
    start[:, 7] += np.random.default_rng(3).normal(0, 0.2, len(start))  # a joint off by a different amount each frame
    n = len(start)
    far = midpoints(robot.model, start, 3)
    for t, (a, b) in {0: (0, 1), 1: (0, 2), 2: (0, 4), 5: (2, 8), n - 2: (n - 3, n - 1), n - 1: (n - 2, n - 1)}.items():
        assert np.allclose(far[t][7:], 0.5 * (start[a][7:] + start[b][7:]))
    assert np.allclose(targets(robot.model, start, 3)[5][7:], 0.25 * start[2][7:] + 0.5 * start[5][7:] + 0.25 * start[8][7:])
    assert [span((3, 2), k) for k in range(4)] == [3, 2, 1, 1] and span((), 0) == 1
    kw = dict(weight=0.5, starts=("pose",), sizes_every=0, searches=())
    one = temporal(tracker, masks, start, sweeps=1, spans=(3,), **kw)
    prior = RestPrior(0.5, robot.model, targets(robot.model, start, 3)[5], np.arange(robot.model.nv))
    q, fit = tracker.refine(start[5], masks[5], priors=(prior,))
    assert np.array_equal(one.q[5], q) and one.fit[5] == fit
    two = temporal(tracker, masks, start, sweeps=2, spans=(3,), **kw)
    then = temporal(tracker, masks, one.q, sweeps=1, spans=(), **kw)
    assert np.array_equal(two.q, then.q) and np.array_equal(two.fit, then.fit)
    assert SPANS and all(h >= 1 for h in SPANS)


def test_a_pull_spreads_farther_in_a_sweep_with_the_frames_beside_farther_away(walk):
    """The root moved along the one camera's ray on a stretch of eight frames, the same on
    each (what the masks hardly see, wrong for a while): frames beside one frame away pull
    only the stretch's ends, frames four away its inside too, so two sweeps at span 4 leave
    less of it than two at span 1."""
    robot, cams, truth, masks, tracker = walk
    ray = truth[:, :3] - cams[0].centre
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    stretch = np.arange(3, 11)
    moved = truth.copy()
    moved[stretch, :3] += 0.04 * robot.height * ray[stretch]
    left = {}
    for spans in ((), (4, 4)):
        q = temporal(tracker, masks, moved, weight=0.3, sweeps=2, starts=("pose",), sizes_every=0, spans=spans).q
        left[spans] = _along_ray(robot, cams[0], q, truth)[stretch].mean()
    assert left[(4, 4)] < 0.8 * left[()], left  # (measured: 0.059 against 0.111 m, of 0.155)


def test_the_body_sizes_are_measured_again_at_the_refits_poses(walk):
    """A tracker 20 % too large on every semi-axis (the masks are of the spec's sizes): the
    refit measures them again at its poses, every sizes_every sweeps, and ends nearer the
    spec's (1) on the bodies it sees, its fits at those sizes; the tracker keeps its own;
    without the measuring, its own throughout; in two processes the same to the last bit."""
    robot, cams, truth, masks, _ = walk
    big = np.full((len(robot.bodies), 3), 1.2)
    tracker = Tracker(robot, cams, q0=truth[0], scales=big, calibrate_sizes=False)
    out = temporal(tracker, masks, truth, weight=WEIGHT, sweeps=3, sizes_every=1, starts=("pose",))
    assert np.array_equal(tracker.scales, big)
    assert np.median(np.abs(np.log(out.scales))) < 0.5 * np.log(1.2)
    sized = Tracker(robot, cams, q0=truth[0], scales=out.scales, calibrate_sizes=False)
    assert np.allclose(out.fit, [sized.fit(x, m) for x, m in zip(out.q, masks)])
    assert out.fit.mean() > np.mean([tracker.fit(x, m) for x, m in zip(truth, masks)])
    kept = temporal(tracker, masks, truth, weight=WEIGHT, sweeps=3, sizes_every=0, starts=("pose",))
    assert np.array_equal(kept.scales, big)
    assert np.allclose(kept.fit, [tracker.fit(x, m) for x, m in zip(kept.q, masks)])
    frames = [(masks[k], truth[k], f"frame {k}") for k in range(0, len(truth), 2)]
    measured = tracker.measure_sizes(frames)
    assert np.allclose(tracker.measure_sizes(frames[::-1]), measured, rtol=1e-9)  # each frame fit from the same sizes
    assert np.array_equal(tracker.scales, big) and np.median(np.abs(np.log(measured))) < 0.5 * np.log(1.2)
    both = temporal(tracker, masks, truth, weight=WEIGHT, sweeps=3, sizes_every=1, starts=("pose",), jobs=2)
    assert np.array_equal(both.q, out.q) and np.array_equal(both.scales, out.scales)
    assert np.array_equal(both.fit, out.fit)


def test_an_empty_frame_keeps_its_pose_and_the_callers_track_is_left_as_it_was(walk):
    robot, _, truth, masks, tracker = walk
    frames = [list(m) for m in masks[:5]]
    frames[2] = [np.zeros_like(m) for m in frames[2]]
    start = truth[:5].copy()
    before = start.copy()
    out = temporal(tracker, frames, start, weight=WEIGHT, sweeps=2)
    assert np.array_equal(start, before)
    assert np.array_equal(out.q[2], start[2]) and out.fit[2] == 0.0
    other = temporal(tracker, frames, start, weight=WEIGHT, sweeps=2, starts=("neighbours", "target", "pose"))
    assert np.array_equal(other.q[2], start[2])  # the tie (0 from every start) to its own pose, in any order given


def test_frames_the_masks_cannot_drive_do_not_measure_the_sizes(walk):
    """An empty frame and a full one among the frames the sizes are measured on: the sizes
    come from the others (a full mask measured would blow every body up to its bound)."""
    robot, _, truth, masks, tracker = walk
    frames = [list(m) for m in masks[:6]]
    frames[2] = [np.zeros_like(m) for m in frames[2]]
    frames[4] = [np.ones_like(m) for m in frames[4]]
    out = temporal(tracker, frames, truth[:6], sweeps=3, sizes_every=1)
    good = [0, 1, 3, 5]
    assert out.fit[2] == 0.0 and out.fit[4] == 0.0
    from kms2pin.ecm.sizes import SCALE_MAX

    assert np.mean(np.isclose(out.scales, SCALE_MAX)) < 0.2  # (measured on the full mask too: 0.37 of them)
    kept = temporal(tracker, frames, truth[:6], sweeps=3, sizes_every=0)
    assert out.fit[good].mean() > kept.fit[good].mean() - 0.01


def test_a_track_of_another_length_or_bad_settings_are_refused(walk):
    robot, _, truth, masks, tracker = walk
    with pytest.raises(ValueError, match="one pose per frame"):
        temporal(tracker, masks, truth[:-1])
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="weight"):
            temporal(tracker, masks, truth, weight=bad)
    for bad in (-1, 1.5):
        with pytest.raises(ValueError, match="sweeps"):
            temporal(tracker, masks, truth, sweeps=bad)
    for bad in ((), ("pose", "pose"), ("the truth",)):
        with pytest.raises(ValueError, match="starts"):
            temporal(tracker, masks, truth, starts=bad)
    for bad in (-1, 1.5):
        with pytest.raises(ValueError, match="sizes_every"):
            temporal(tracker, masks, truth, sizes_every=bad)
    for bad in (0, 1.5):
        with pytest.raises(ValueError, match="jobs"):
            temporal(tracker, masks, truth, jobs=bad)


def test_a_refits_springs_are_for_that_run_only(walk):
    """A frame refit with a stiff spring leaves the tracker as it was: the same frame's
    ECM without it, and one iteration from the tracker, are what they were before."""
    robot, _, truth, masks, tracker = walk
    start = truth[4].copy()
    start[7] += 0.2
    before = tracker.refine(start, masks[4])
    step = tracker.ecm.iterate(start, tracker_views(tracker, masks[4]), 1.0, new_timings())
    pulled = tracker.refine(start, masks[4], priors=(RestPrior(10.0, robot.model, truth[0], np.arange(robot.model.nv)),))
    assert not np.allclose(pulled[0], before[0])
    assert np.array_equal(tracker.ecm.iterate(start, tracker_views(tracker, masks[4]), 1.0, new_timings()), step)
    again = tracker.refine(start, masks[4])
    assert np.array_equal(again[0], before[0]) and again[1] == before[1]


def tracker_views(tracker, masks):
    from kms2pin.ecm.masks import Views

    return Views.of(tracker.cameras, [np.asarray(m, dtype=bool) for m in masks])


def test_the_limbs_are_searched_again_before_the_chosen_sweeps(walk):
    """A foot turned far off on one frame (its image left unexplained) is a basin the frame's
    ECM does not leave; with ``searches`` the reach search re-aims it before the sweep and
    the frame ends near the truth, as the tracker's own :meth:`Tracker.reach_limbs` does
    from that pose.  Without the reach search the option does nothing."""
    robot, cams, truth, masks, _ = walk
    tracker = Tracker(robot, cams, q0=truth[0], reach_search=True)
    tracker.calibrate(masks[0])
    joint = next(j for j in robot.joints if j.name == "leftFoot_ankle")
    start = truth[:6].copy()
    start[3, joint.idx_q] += 1.4
    kept = temporal(tracker, masks[:6], start, weight=0.0, sweeps=1, starts=("pose",), sizes_every=0, searches=())
    searched = temporal(tracker, masks[:6], start, weight=0.0, sweeps=1, starts=("pose",), sizes_every=0,
                        searches=(0,))
    off = [abs(q[3, joint.idx_q] - truth[3, joint.idx_q]) for q in (kept.q, searched.q)]
    assert off[0] > 1.0 and off[1] < 0.3, off  # (measured: 2.40 rad kept, 0.007 searched)
    assert searched.fit[3] > kept.fit[3]
    alone, fit, moves = tracker.reach_limbs(start[3], masks[3])
    assert moves >= 1 and fit > tracker.fit(start[3], masks[3])
    plain = Tracker(robot, cams, q0=truth[0])
    plain.calibrate(masks[0])
    assert plain.reach_limbs(start[3], masks[3])[2] == 0
    none = temporal(plain, masks[:6], start, weight=0.0, sweeps=1, starts=("pose",), sizes_every=0, searches=(0,))
    same = temporal(plain, masks[:6], start, weight=0.0, sweeps=1, starts=("pose",), sizes_every=0, searches=())
    assert np.array_equal(none.q, same.q)


def test_bad_spans_are_refused(walk):
    _, _, truth, masks, tracker = walk
    for bad in ((0,), (4, -1), (1.5,), (True,), ("x",), (None,), (float("nan"),)):
        with pytest.raises(ValueError, match="spans"):
            temporal(tracker, masks, truth, spans=bad)


def test_bad_searches_are_refused(walk):
    _, _, truth, masks, tracker = walk
    for bad in ((-1,), (1.5,), (True,), ("x",), (None,), ([4],), (float("nan"),)):
        with pytest.raises(ValueError, match="searches"):
            temporal(tracker, masks, truth, searches=bad)
