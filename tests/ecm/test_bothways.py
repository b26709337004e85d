"""kms2pin.ecm.bothways: a stretch the forward track lost is taken from the backward track,
judged against the true motion the masks were rendered from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import kms2pin
from kms2pin.ecm import Camera, Tracker, make_motion, synthesize
from kms2pin.ecm.bothways import (
    MARGIN,
    SWEEPS,
    SWITCH,
    TOLERANCE,
    apart,
    beside,
    both_ways,
    branching,
    choose,
    choose_tracks,
    hinges,
    parts,
    take_beside,
    take_parts,
)

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
    # elsewhere the forward poses are the truth: kept unless the backward pose fits better by
    # the margin, or one of its limbs' parts fits better, from the other track or from the
    # frames beside (then the fit is the kept pose's own)
    assert bw.beside.shape == bw.parts.shape
    moved = bw.parts.any(axis=1) | bw.beside.any(axis=1)
    plain = ~bw.backward & ~moved
    assert np.array_equal(bw.q[plain], forward[plain])
    held = np.ones(len(truth), dtype=bool)
    held[lost] = False  # where the forward track is the truth, a part taken moves it by noise only
    assert err_kept[held].max() < 1e-3 * robot.height
    whole = ~moved
    assert np.allclose(bw.fit[whole], np.where(bw.backward, bw.fit_backward, bw.fit_forward)[whole])
    assert (bw.fit >= np.where(bw.backward, bw.fit_backward, bw.fit_forward)).all()
    assert bw.part_names == parts(robot) == tuple(j.name for j in robot.joints if j.kind == "revolute")


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


def _brute_force(gain: np.ndarray, step: np.ndarray) -> float:
    """The least cost over every choice of track per frame (independent of the Viterbi pass)."""
    best = np.inf
    n = len(gain)
    for code in range(2**n):
        back = np.array([(code >> k) & 1 for k in range(n)], dtype=bool)
        cost = -gain[back].sum() + step[back[:-1] != back[1:]].sum()
        best = min(best, cost)
    return best


@pytest.mark.parametrize("seed", range(40))
def test_the_choice_is_the_least_cost_of_every_choice(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 11))
    fit_f, fit_b = rng.uniform(0.5, 0.7, n), rng.uniform(0.5, 0.7, n)
    far = rng.uniform(0.0, 0.3, n) * (rng.random(n) < 0.7)  # the tracks agree on some frames
    switch, margin, tol = float(rng.uniform(0.05, 1.0)), 0.005, float(rng.choice([0.0, TOLERANCE, 0.1]))
    back = choose(fit_f, fit_b, far, margin, switch, tol)
    gain, step = fit_b - fit_f - margin, switch * np.clip(np.minimum(far[:-1], far[1:]) - tol, 0.0, None)
    cost = -gain[back].sum() + step[back[:-1] != back[1:]].sum()
    assert cost == pytest.approx(_brute_force(gain, step), abs=1e-12)


@pytest.mark.parametrize("seed", range(30))
def test_the_choice_among_tracks_is_the_least_cost_of_every_choice(seed):
    # three or four tracks of up to 6 frames: every one of the T**n choices enumerated
    import itertools

    rng = np.random.default_rng(100 + seed)
    n, t = int(rng.integers(1, 7)), int(rng.integers(3, 5))
    fits = rng.uniform(0.5, 0.7, (n, t))
    if seed % 2:  # on a coarse grid: ties between tracks and between paths
        fits = np.round(fits * 20) / 20
    far = rng.uniform(0.0, 0.3, (n, t, t)) * (rng.random((n, t, t)) < 0.7)
    far = np.triu(far, 1) + np.transpose(np.triu(far, 1), (0, 2, 1))  # symmetric, 0 on the diagonal
    switch, tol = float(rng.uniform(0.05, 1.0)), float(rng.choice([0.0, TOLERANCE, 0.1]))
    margins = rng.uniform(0.0, 0.01, t)

    def cost(path) -> float:
        total = -sum(fits[k, path[k]] - margins[path[k]] for k in range(n))
        return total + sum(switch * max(min(far[k, path[k], path[k + 1]], far[k + 1, path[k], path[k + 1]]) - tol, 0.0)
                           for k in range(n - 1))

    kept = choose_tracks(fits, far, switch, tol, margins)
    assert kept.shape == (n,) and kept.dtype.kind == "i"
    assert cost(kept) == pytest.approx(min(cost(p) for p in itertools.product(range(t), repeat=n)), abs=1e-12)


def _two_track_viterbi(fit_f, fit_b, far, margin, switch, tol) -> np.ndarray:
    """The two-track choice as it was written before ``choose_tracks`` (the thirteenth to
    twenty-second sessions' ``choose``), kept here as the reference it must equal."""
    gain = fit_b - fit_f - margin
    n = len(gain)
    if switch == 0.0 or n == 0:
        return gain > 0.0
    step = switch * np.maximum(np.minimum(far[:-1], far[1:]) - tol, 0.0)
    cost = [0.0, -gain[0]]
    came = np.zeros((n, 2), dtype=bool)
    for k in range(1, n):
        f_stay, f_move = cost[0], cost[1] + step[k - 1]
        b_stay, b_move = cost[1], cost[0] + step[k - 1]
        came[k] = (f_move < f_stay, b_move < b_stay)
        cost = [min(f_stay, f_move), min(b_stay, b_move) - gain[k]]
    back = np.zeros(n, dtype=bool)
    s = 1 if cost[1] < cost[0] else 0
    for k in range(n - 1, -1, -1):
        back[k] = s == 1
        s = 1 - s if came[k, s] else s
    return back


@pytest.mark.parametrize("seed", range(20))
def test_the_two_track_choice_is_the_one_written_before_to_the_last_bit(seed):
    # fits on a coarse grid, so that many frames and many paths tie
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(0, 60))
    fit_f, fit_b = np.round(rng.uniform(0.5, 0.7, (2, n)) * 40) / 40
    far = np.round(rng.uniform(0.0, 0.1, n) * (rng.random(n) < 0.6) * 50) / 50
    for margin, switch, tol in ((MARGIN, SWITCH, TOLERANCE), (0.0, SWITCH, 0.0), (0.0, 0.0, 0.0), (MARGIN, 0.3, 0.02)):
        assert np.array_equal(choose(fit_f, fit_b, far, margin, switch, tol),
                              _two_track_viterbi(fit_f, fit_b, far, margin, switch, tol))


def test_without_a_switch_cost_each_frame_takes_its_best_track_the_first_on_a_tie():
    fits = np.array([[0.5, 0.6, 0.6], [0.7, 0.7, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.51]])
    assert choose_tracks(fits, np.zeros((4, 3, 3)), 0.0).tolist() == [1, 0, 0, 2]
    # a margin on a track counts against it
    assert choose_tracks(fits, np.zeros((4, 3, 3)), 0.0, margins=(0.0, 0.0, 0.02)).tolist() == [1, 0, 0, 0]


def test_the_choice_among_tracks_refuses_mismatched_shapes():
    with pytest.raises(ValueError, match="apart"):
        choose_tracks(np.zeros((5, 3)), np.zeros((5, 2, 2)))
    with pytest.raises(ValueError, match="margins"):
        choose_tracks(np.zeros((5, 3)), np.zeros((5, 3, 3)), margins=(0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        choose_tracks(np.array([[0.5, np.nan]]), np.zeros((1, 2, 2)))
    with pytest.raises(ValueError, match="0 or more"):
        choose_tracks(np.zeros((5, 3)), np.zeros((5, 3, 3)), switch=-1.0)


def test_without_a_switch_cost_each_frame_is_chosen_on_its_own():
    rng = np.random.default_rng(1)
    fit_f, fit_b, far = rng.uniform(0.5, 0.7, 200), rng.uniform(0.5, 0.7, 200), rng.uniform(0, 0.3, 200)
    assert np.array_equal(choose(fit_f, fit_b, far, 0.005, 0.0), fit_b > fit_f + 0.005)


def test_a_change_where_the_tracks_agree_within_the_tolerance_is_free():
    rng = np.random.default_rng(2)
    fit_f, fit_b = rng.uniform(0.5, 0.7, 200), rng.uniform(0.5, 0.7, 200)
    far = rng.uniform(0, TOLERANCE, 200)  # the tracks agree everywhere: each frame on its own
    assert np.array_equal(choose(fit_f, fit_b, far, 0.005, SWITCH, TOLERANCE), fit_b > fit_f + 0.005)
    # without the tolerance the same changes cost: fewer of them are made
    strict = choose(fit_f, fit_b, far, 0.005, SWITCH, 0.0)
    assert np.sum(strict[1:] != strict[:-1]) < np.sum((fit_b > fit_f + 0.005)[1:] != (fit_b > fit_f + 0.005)[:-1])


def test_a_lost_stretch_that_fits_better_on_a_few_frames_is_not_taken():
    # the backward track is lost (far from the forward one) on frames 10-29 and fits better
    # on three of them by 0.01: frame by frame those would be taken, each a jump there and back
    n = 40
    fit_f, fit_b = np.full(n, 0.60), np.full(n, 0.58)
    fit_b[[12, 20, 27]] = 0.61
    far = np.full(n, 0.002)
    far[10:30] = 0.15
    frame_by_frame = choose(fit_f, fit_b, far, MARGIN, 0.0)
    assert frame_by_frame.sum() == 3
    assert not choose(fit_f, fit_b, far, MARGIN, SWITCH).any()
    # a stretch the forward track lost, where the backward one fits better throughout, is taken
    # whole, entered and left where the two agree
    fit_b[10:30] = 0.62
    back = choose(fit_f, fit_b, far, MARGIN, SWITCH)
    assert back[10:30].all() and not back[:10].any() and not back[30:].any()


def test_apart_is_the_mean_body_centre_distance_in_heights(walk):
    robot, _, truth, _ = walk
    moved = truth.copy()
    moved[:, 0] += 0.3  # the root slid 0.3 along x: every centre moves by 0.3
    assert np.allclose(apart(robot, truth, moved), 0.3 / robot.height)
    assert np.array_equal(apart(robot, truth, truth), np.zeros(len(truth)))


def _below(robot, name: str) -> np.ndarray:
    """The q columns of the joint ``name`` and every joint whose chain to the root passes
    through it (by walking each joint's parents, not Pinocchio's subtrees)."""
    pm = robot.model
    top, cols = pm.getJointId(name), []
    for j in range(1, pm.njoints):
        k = j
        while k > 0 and k != top:
            k = pm.parents[k]
        if k == top:
            cols += range(pm.idx_qs[j], pm.idx_qs[j] + pm.nqs[j])
    return np.array(sorted(cols))


def test_each_hinge_is_taken_with_the_joints_below_it_where_that_fits_better(walk):
    robot, cams, truth, masks = walk
    names = parts(robot)
    assert names == hinges(robot) == tuple(j.name for j in robot.joints if j.kind == "revolute")  # the thesis's
    knees = [names.index(n) for n in names if "knee" in n]
    kept = truth.copy()
    left, right = _below(robot, names[knees[0]]), _below(robot, names[knees[1]])
    kept[3:7, left[0]] += 0.9  # a knee bent off on frames 3-6 of the kept track, the other right
    kept[9:12, right] += 0.4  # the other knee and the ankle below it off on frames 9-11
    rng = np.random.default_rng(0)
    other = truth.copy()
    other[:, :3] += 0.01 * rng.standard_normal((len(truth), 3))  # the other track's root a little off

    def fit(k, q):  # an independent score: the negative distance from the truth's coordinates
        return -float(np.abs(q - truth[k]).sum())

    fits = np.array([fit(k, q) for k, q in enumerate(kept)])
    q, fit_q, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept, other, fits)
    frames = np.arange(len(truth))
    for knee, off in ((knees[0], range(3, 7)), (knees[1], range(9, 12))):
        # taken by the knee or by a hinge above it (the thesis's hips are hinges too), with
        # everything below, on exactly the frames it was off
        above = [h for h, n in enumerate(names) if _below(robot, names[knee])[0] in _below(robot, n)]
        assert np.array_equal(taken[:, above].any(axis=1), np.isin(frames, off))
    # a hinge below a knee (an ankle) is not tried again: taken with the knee, it is the other track's
    below = [h for h, n in enumerate(names) if h not in knees and np.isin(_below(robot, n)[0], np.r_[left, right])]
    assert below and not taken[:, below].any()
    assert np.array_equal(q[3:7, left], truth[3:7, left]) and np.array_equal(q[9:12, right], truth[9:12, right])
    for k in frames:  # what a taken hinge carries is its own columns and those below it, from the other track
        cols = np.unique(np.concatenate([_below(robot, n) for n, t in zip(names, taken[k]) if t] or [np.array([], int)]))
        assert np.array_equal(q[k, cols], other[k, cols])
        rest = np.setdiff1d(np.arange(robot.nq), cols)
        assert np.array_equal(q[k, rest], kept[k, rest])
    assert np.array_equal(fit_q, [fit(k, x) for k, x in enumerate(q)]) and (fit_q >= fits).all()


_FIVE_BAR = """  // two cranks on a floating ground link, two couplers joined at their tips
double width = 0.025;
bvec pivot { pos(-0.4, -0.3, 3); orient(0, 0, 1); }
ellipsoidBody Link(double length) {
    innerLam(length/2 + width, width, width);
    outerLam(1.2*(length/2 + width), 1.2*width, 1.2*width);
    bvec base { pos(-length/2, 0, 0); orient(0, 0, 1); }
    bvec tip { pos(length/2, 0, 0); orient(0, 0, 1); }
}
rigidBodySystem fivebar {
    Link groundLink(0.8); Link leftCrank(0.3); Link rightCrank(0.3); Link leftCoupler(0.5); Link rightCoupler(0.5);
    constraint revolute(groundLink.base, leftCrank.base, 90);
    constraint revolute(groundLink.tip, rightCrank.base, 90);
    constraint revolute(leftCrank.tip, leftCoupler.base, -53.130102354155978);
    constraint revolute(rightCrank.tip, rightCoupler.base, 53.130102354155978);
    constraint revolute(leftCoupler.tip, rightCoupler.tip);
}
constraint revolute(pivot, fivebar.groundLink.base);
"""


@pytest.mark.parametrize("mechanism", ["four-bar", "floating five-bar"])
def test_a_hinge_in_a_loop_is_taken_only_with_the_loop_closed(mechanism, tmp_path):
    """A crank taken from the other track, the loop closed again with the crank held.  The
    five-bar has two degrees of freedom and a free root (each joint's q index one past its
    velocity index): the crank stays where the other track has it only if the velocity
    column held is the crank's (holding the next one, the coupler's, moves the crank)."""
    if mechanism == "four-bar":
        robot = kms2pin.load(DIR / "fourbar.kms")
    else:
        (tmp_path / "fivebar.kms").write_text(_FIVE_BAR)
        robot = kms2pin.load(tmp_path / "fivebar.kms", root="free")
        jm = robot.model.joints[robot.model.getJointId(hinges(robot)[0])]
        assert jm.idx_q == jm.idx_v + 1
    crank = hinges(robot)[0]
    col = _below(robot, crank)[0]
    qs = []
    for a in (0.0, 0.3, 0.6):
        q = robot.q_rest.copy()
        q[col] += a
        qs.append(robot.project(q, hold=[robot.model.joints[robot.model.getJointId(crank)].idx_v]))
    kept, other = np.array([qs[0], qs[0]]), np.array([qs[1], qs[2]])

    def fit(k, q):  # prefers the other track's crank
        return -abs(float(q[col] - other[k, col]))

    q, _, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept, other,
                             np.array([fit(k, x) for k, x in enumerate(kept)]))
    assert taken[:, 0].all()
    assert np.allclose(q[:, col], other[:, col], atol=1e-6)
    assert max(robot.closure_residual(x).max() for x in q) < 1e-9


def test_a_part_whose_loop_cannot_be_closed_is_skipped():
    """The four-bar's rocker 2 rad off in the other track: with the rocker held, no crank and
    coupler close the loop (the projection's RobotError), so the rocker is not taken, though
    the score would prefer it; the crank, which closes, still is."""
    robot = kms2pin.load(DIR / "fourbar.kms")
    crank, rocker = hinges(robot)[0], hinges(robot)[-1]
    c, r = _below(robot, crank)[0], robot.model.idx_qs[robot.model.getJointId(rocker)]
    held = [robot.model.joints[robot.model.getJointId(crank)].idx_v]
    kept = robot.q_rest.copy()
    q_crank = kept.copy()
    q_crank[c] += 0.3
    other = robot.project(q_crank, hold=held)
    other[r] = kept[r] + 2.0  # the other track's rocker where the loop cannot reach
    trial = kept.copy()
    trial[r] = other[r]
    with pytest.raises(kms2pin.errors.RobotError):
        robot.project(trial, hold=[robot.model.joints[robot.model.getJointId(rocker)].idx_v])

    def fit(k, q):  # prefers the other track's crank and rocker alike
        return -abs(float(q[c] - other[c])) - abs(float(q[r] - other[r]))

    q, fit_q, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept[None], other[None],
                                 np.array([fit(0, kept)]))
    names = list(parts(robot))
    assert taken[0, names.index(crank)] and not taken[0, names.index(rocker)]
    assert q[0, c] == pytest.approx(other[c], abs=1e-6)
    assert abs(q[0, r] - other[r]) > 1.0
    assert robot.closure_residual(q[0]).max() < 1e-9 and fit_q[0] > fit(0, kept)


@pytest.mark.parametrize("placement", ["as specified", "turned"])
def test_a_ball_joint_above_a_hinge_takes_the_other_tracks_world_orientation(placement):
    """A hip (a ball joint with the knee hanging from it) taken from a track whose pelvis is
    turned elsewhere: the thigh points in the world as the other track has it, from this
    track's hip; the knee below is the other track's; nothing above moves.  Also with the
    hip's joint frame turned in the pelvis (human.kms's is not)."""
    robot = kms2pin.load(DIR / "human.kms", root="free")
    if placement == "turned":
        jid = robot.model.getJointId("leftThigh_hip")
        old = robot.model.jointPlacements[jid]
        robot.model.jointPlacements[jid] = pin.SE3(pin.exp3(np.array([0.4, -0.3, 0.8])), old.translation)
        assert not np.allclose(robot.model.jointPlacements[jid].rotation, np.eye(3))
    assert parts(robot)[:3] == ("leftThigh_hip", "leftShin_knee", "leftFoot_ankle")
    rng = np.random.default_rng(3)
    cols = {j.name: slice(j.idx_q, j.idx_q + j.nq) for j in robot.joints}
    kept, other = robot.q_rest.copy(), robot.q_rest.copy()
    other[3:7] = pin.Quaternion(pin.exp3(np.array([0.2, 0.7, -0.1]))).coeffs()  # the pelvis turned
    other[cols["leftThigh_hip"]] = pin.Quaternion(pin.exp3(rng.normal(0, 0.5, 3))).coeffs()
    other[cols["leftShin_knee"]] = 0.9
    thigh, shin = robot.bodies.index("leftThigh"), robot.bodies.index("leftShin")
    target = robot.body_poses(other)[thigh].rotation

    def fit(k, q):  # an independent score: how near the thigh's world orientation is the other's
        return -float(np.linalg.norm(pin.log3(robot.body_poses(q)[thigh].rotation.T @ target)))

    q, fit_q, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept[None], other[None],
                                  np.array([fit(0, kept)]))
    assert taken[0, 0]
    poses, kept_poses, other_poses = robot.body_poses(q[0]), robot.body_poses(kept), robot.body_poses(other)
    assert np.allclose(poses[thigh].rotation, target, atol=1e-9)
    # the thigh hangs from this track's hip: nothing above or beside the leg moves
    leg = np.r_[_below(robot, "leftThigh_hip")]
    assert np.array_equal(np.delete(q[0], leg), np.delete(kept, leg))
    assert not np.allclose(poses[thigh].translation, kept_poses[thigh].translation)  # turned about the hip
    assert q[0, cols["leftShin_knee"]] == pytest.approx(0.9)
    assert np.allclose(poses[shin].rotation, other_poses[shin].rotation, atol=1e-9)  # the shin too, the knee's angle kept
    assert not np.allclose(poses[thigh].translation, other_poses[thigh].translation)  # not the other track's place
    assert fit_q[0] == pytest.approx(0.0, abs=1e-9)


def _linear_knee(robot, frames: int = 16, step: float = 0.02):
    """A track whose first knee bends at a constant rate (the rest of the pose at rest): the
    halfway pose between two frames is the frame between them.  Returns (truth, its knee's
    q column)."""
    knee = next(n for n in parts(robot) if "knee" in n.lower())
    col = _below(robot, knee)[0]
    truth = np.repeat(robot.q_rest[None], frames, axis=0)
    truth[:, col] += step * np.arange(frames)
    return truth, col


def _distance_from(truth):
    """An independent score: the negative distance from the truth's coordinates, per frame."""
    return lambda k: lambda q: -float(np.abs(q - truth[k]).sum())


def test_a_part_off_on_one_frame_is_taken_from_the_frames_beside_it(walk):
    robot = walk[0]
    truth, col = _linear_knee(robot)
    kept = truth.copy()
    kept[5, col] += 0.8  # the knee off on frame 5 alone
    kept[0, col] -= 0.5  # and on the first frame, which has frames on one side only
    score = _distance_from(truth)
    q, fit_q, taken = take_beside(robot, score, kept, [score(k)(x) for k, x in enumerate(kept)])
    assert q[5, col] == pytest.approx(truth[5, col], abs=1e-12)  # halfway between frames 4 and 6: the truth
    assert abs(q[0, col] - truth[0, col]) <= 0.02 + 1e-12  # frame 1's angle, one step off
    others = np.setdiff1d(np.arange(len(truth)), [0, 5])
    assert np.array_equal(q[others], truth[others]) and not taken[others].any()
    assert taken[[0, 5]].any(axis=1).all()
    assert np.array_equal(fit_q, [score(k)(x) for k, x in enumerate(q)])


def test_a_stretch_of_frames_is_mended_from_both_ends_and_sweeps_0_leaves_it(walk):
    robot = walk[0]
    truth, col = _linear_knee(robot)
    kept = truth.copy()
    stretch = np.arange(7, 12)
    kept[stretch, col] += 0.8  # the knee off on five frames together
    score = _distance_from(truth)
    fits = np.array([score(k)(x) for k, x in enumerate(kept)])
    before = kept.copy()
    same, _, none = take_beside(robot, score, kept, fits, sweeps=0)
    assert np.array_equal(same, kept) and not none.any()
    q, fit_q, taken = take_beside(robot, score, kept, fits)
    assert np.array_equal(kept, before)  # the caller's track is left as it was
    assert SWEEPS == 2 and taken[stretch].any(axis=1).all()
    # a forward sweep brings each frame of the stretch to its mended neighbour's angle, a frame's
    # motion off; the backward sweep then takes the frame after's, which the forward sweep left
    # one frame's motion off the other way, and the halfway pose: one sweep, two forward sweeps or
    # no halfway pose leave 0.04-0.06 rad
    assert np.abs(q[stretch, col] - truth[stretch, col]).max() < 0.025
    assert (fit_q >= fits).all() and (fit_q[stretch] > fits[stretch]).all()
    with pytest.raises(ValueError, match="sweeps"):
        take_beside(robot, score, kept, fits, sweeps=-1)
    with pytest.raises(ValueError, match="one fit per frame"):
        take_beside(robot, score, kept, fits[:-1])


def test_a_frame_two_away_is_tried_when_both_neighbours_are_off(walk):
    """Frames 4 and 6 are the truth but far from frame 5's (the truth itself jumps there), and
    frame 5 is off: its halfway pose and its neighbours leave it 0.78 rad off at best; frames 3
    and 7, two away, bring it within two frames' motion."""
    robot = walk[0]
    truth, col = _linear_knee(robot)
    truth[[4, 6], col] += 0.8
    kept = truth.copy()
    kept[5, col] += 0.8
    score = _distance_from(truth)
    q, _, taken = take_beside(robot, score, kept, [score(k)(x) for k, x in enumerate(kept)])
    assert abs(q[5, col] - truth[5, col]) == pytest.approx(0.04, abs=1e-12)
    assert taken[5].any() and np.array_equal(np.delete(q, 5, axis=0), np.delete(truth, 5, axis=0))


def test_a_ball_joint_is_taken_from_the_frames_beside_it_as_a_unit_rotation():
    """A hip (a spherical joint) turning at a constant rate about a fixed axis, off on one
    frame: the halfway pose (``pin.interpolate``: the quaternions' geodesic) is the truth, so
    the thigh comes back to the true world orientation, its quaternion of unit length."""
    robot = kms2pin.load(DIR / "human.kms", root="free")
    hip = parts(robot)[0]
    jm = robot.model.joints[robot.model.getJointId(hip)]
    own = slice(jm.idx_q, jm.idx_q + 4)
    truth = np.repeat(robot.q_rest[None], 9, axis=0)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for k in range(9):
        truth[k, own] = pin.Quaternion(pin.exp3(0.05 * k * axis)).coeffs()
    kept = truth.copy()
    kept[4, own] = pin.Quaternion(pin.exp3(np.array([0.9, 0.2, -0.4]))).coeffs()
    thigh = robot.bodies.index("leftThigh")

    def score(k):  # how near the thigh's world orientation is the truth's
        target = robot.body_poses(truth[k])[thigh].rotation
        return lambda q: -float(np.linalg.norm(pin.log3(robot.body_poses(q)[thigh].rotation.T @ target)))

    q, fit_q, taken = take_beside(robot, score, kept, [score(k)(x) for k, x in enumerate(kept)])
    assert taken[4, 0]
    assert np.linalg.norm(q[4, own]) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(robot.body_poses(q[4])[thigh].rotation, robot.body_poses(truth[4])[thigh].rotation, atol=1e-9)


def test_a_part_from_the_frames_beside_closes_the_loop():
    """The four-bar's crank turning at a constant rate, off on one frame: the halfway pose of
    two closed configurations is not closed, and the part is taken only closed again."""
    robot = kms2pin.load(DIR / "fourbar.kms")
    crank = hinges(robot)[0]
    col = _below(robot, crank)[0]
    held = [robot.model.joints[robot.model.getJointId(crank)].idx_v]

    def closed(a):
        q = robot.q_rest.copy()
        q[col] += a
        return robot.project(q, hold=held)

    truth = np.array([closed(0.05 * k) for k in range(7)])
    kept = truth.copy()
    kept[3] = closed(0.6)
    score = _distance_from(truth)
    q, _, taken = take_beside(robot, score, kept, [score(k)(x) for k, x in enumerate(kept)])
    assert taken[3].any() and abs(q[3, col] - truth[3, col]) < 1e-6
    assert max(robot.closure_residual(x).max() for x in q) < 1e-9


def test_one_track_takes_a_part_from_the_frames_beside_without_a_backward_pass(walk):
    """:func:`beside` on a forward "track" that is the truth but for a knee bent far off on
    frame 5: the frame is mended from its neighbours, judged by the body centres against the
    motion the masks were rendered from; the other frames move by the masks' noise at most."""
    robot, cams, truth, masks = walk
    track = truth.copy()
    knee = next(j for j in robot.joints if j.kind == "revolute")
    track[5, knee.idx_q] += 1.2
    tracker = Tracker(robot, cams)
    bs = beside(tracker, masks, track)
    assert bs.q.shape == truth.shape and bs.taken.shape == (len(truth), len(parts(robot)))
    assert bs.part_names == parts(robot) and bs.taken[5].any()
    err_track, err = _centre_error(robot, track, truth), _centre_error(robot, bs.q, truth)
    assert err[5] < 0.05 * err_track[5]
    assert np.delete(err, 5).max() < 1e-3 * robot.height
    assert np.array_equal(bs.q[~bs.taken.any(axis=1)], track[~bs.taken.any(axis=1)])
    # each frame's fit is its pose's, at the tracker's sizes, and never below the track's
    assert np.array_equal(bs.fit, [tracker.fit(x, m) for x, m in zip(bs.q, masks)])  # the same counts, to the pixel
    assert (bs.fit >= [tracker.fit(x, m) for x, m in zip(track, masks)]).all()
    none = beside(tracker, masks, track, sweeps=0)
    assert np.array_equal(none.q, track) and not none.taken.any()
    # the fits counted from the moved bodies (rebased on each pose kept) take what the
    # whole silhouettes' fits take: a scorer without ``rebase``
    def whole(k):
        return lambda pose: tracker.fit(pose, masks[k])

    fit0 = [tracker.fit(x, m) for x, m in zip(track, masks)]
    q, fit, taken = take_beside(robot, whole, track, fit0)
    assert np.array_equal(q, bs.q) and np.array_equal(fit, bs.fit) and np.array_equal(taken, bs.taken)
    # and each pose kept becomes the base the next trials are counted from
    bases = {}

    class Spy:
        def __init__(self, k):
            self.k, self.fit = k, tracker.part_fit(masks[k])

        def __call__(self, pose):
            return self.fit(pose)

        def rebase(self, pose):
            bases.setdefault(self.k, []).append(pose.copy())
            return self.fit.rebase(pose)

    q, _, taken = take_beside(robot, Spy, track, fit0)
    for k in np.flatnonzero(taken.any(axis=1)):
        assert any(np.array_equal(b, q[k]) for b in bases[k])


def test_one_track_beside_checks_its_poses_and_names_frames_in_errors(walk):
    robot, cams, truth, masks = walk
    tracker = Tracker(robot, cams)
    with pytest.raises(ValueError, match=r"one pose per frame"):
        beside(tracker, masks, truth[:-1])
    bad = list(masks)
    bad[3] = [m[:-1] for m in bad[3]]
    with pytest.raises(kms2pin.Kms2pinError, match="clip.avi: frame 3"):
        beside(tracker, bad, truth, sources=[f"clip.avi: frame {k}" for k in range(len(bad))])


def test_the_parts_are_every_joint_but_a_free_root():
    """On a person: the spine and the neck, which no hinge hangs from, are parts too; on a
    gantry (sliders on the world) every joint.  Read from Pinocchio's own joint list."""
    human = kms2pin.load(DIR / "human.kms", root="free")
    pm = human.model
    assert parts(human) == tuple(pm.names[j] for j in range(2, pm.njoints))  # 1 is the free root
    assert {"torso_waist", "head_neck"} <= set(parts(human))
    gantry = kms2pin.load(DIR / "gantry.kms")
    assert parts(gantry) == tuple(gantry.model.names[j] for j in range(1, gantry.model.njoints))


def test_a_ball_joint_no_hinge_hangs_from_takes_the_other_tracks_world_orientation():
    """The head taken from a track whose torso is turned too: with a score that wants the
    other track's head but this track's torso, the waist (tried first, carrying the torso) is
    not taken, the neck is, and the head then looks as the other track's does."""
    robot = kms2pin.load(DIR / "human.kms", root="free")
    cols = {j.name: slice(j.idx_q, j.idx_q + j.nq) for j in robot.joints}
    kept, other = robot.q_rest.copy(), robot.q_rest.copy()
    other[cols["torso_waist"]] = pin.Quaternion(pin.exp3(np.array([0.0, 0.6, 0.2]))).coeffs()
    other[cols["head_neck"]] = pin.Quaternion(pin.exp3(np.array([0.3, -0.2, 0.1]))).coeffs()
    torso, head = robot.bodies.index("torso"), robot.bodies.index("head")
    want_head, want_torso = robot.body_poses(other)[head].rotation, robot.body_poses(kept)[torso].rotation

    def fit(k, q):  # independent: the head's world orientation against the other's, the torso against this track's
        poses = robot.body_poses(q)
        return -float(np.linalg.norm(pin.log3(poses[head].rotation.T @ want_head))
                      + np.linalg.norm(pin.log3(poses[torso].rotation.T @ want_torso)))

    q, fit_q, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept[None], other[None],
                                 np.array([fit(0, kept)]))
    names = list(parts(robot))
    assert taken[0, names.index("head_neck")] and not taken[0, names.index("torso_waist")]
    assert np.allclose(robot.body_poses(q[0])[head].rotation, want_head, atol=1e-9)
    neck = cols["head_neck"]
    assert np.array_equal(np.delete(q[0], np.r_[neck]), np.delete(kept, np.r_[neck]))
    assert fit_q[0] == pytest.approx(0.0, abs=1e-9)


def test_a_slider_is_taken_at_the_other_tracks_coordinate():
    """A gantry's quill (a prismatic joint, one coordinate) taken as a hinge is: the other
    track's offset, with the wrist below it; the bridge and carriage above stay."""
    robot = kms2pin.load(DIR / "gantry.kms")
    kept = robot.q_rest.copy()
    other = kept + np.array([0.05, -0.04, 0.03, 0.4])
    quill = robot.model.idx_qs[robot.model.getJointId("quill_top")]

    def fit(k, q):  # prefers the other track's quill and wrist, this track's bridge and carriage far more
        return -float(np.abs(q[quill:] - other[quill:]).sum() + 100 * np.abs(q[:quill] - kept[:quill]).sum())

    q, _, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept[None], other[None],
                             np.array([fit(0, kept)]))
    names = list(parts(robot))
    assert taken[0, names.index("quill_top")] and not taken[0, :names.index("quill_top")].any()
    assert np.array_equal(q[0, quill:], other[quill:]) and np.array_equal(q[0, :quill], kept[:quill])


def test_a_part_that_carries_a_branch_is_taken_from_the_frames_beside_not_from_the_other_track():
    """The waist carries both arms and the head (two or more joints hang from the torso):
    taken from the other track it would change the whole upper body's track on one frame,
    so take_parts leaves it even where the score prefers it; take_beside, from the same
    track's neighbouring frames, takes it."""
    robot = kms2pin.load(DIR / "human.kms", root="free")
    assert branching(robot) == ("torso_waist",)
    assert branching(kms2pin.load(DIR / "lowerbody.kms", root="free")) == ()  # the legs hang from the free root
    cols = {j.name: slice(j.idx_q, j.idx_q + j.nq) for j in robot.joints}
    kept, other = robot.q_rest.copy(), robot.q_rest.copy()
    other[cols["torso_waist"]] = pin.Quaternion(pin.exp3(np.array([0.0, 0.5, 0.2]))).coeffs()

    def fit(k, q):  # independent: the torso's world orientation against the other track's
        return -float(np.linalg.norm(pin.log3(robot.body_poses(q)[1].rotation.T @ robot.body_poses(other)[1].rotation)))

    q, _, taken = take_parts(robot, lambda k: lambda x: fit(k, x), kept[None], other[None], np.array([fit(0, kept)]))
    assert not taken.any() and np.array_equal(q[0], kept)
    track = np.array([other, kept, other])  # the middle frame's torso off, its neighbours right
    q, _, taken = take_beside(robot, lambda k: lambda x: fit(k, x), track, np.array([fit(k, x) for k, x in enumerate(track)]))
    assert taken[1, list(parts(robot)).index("torso_waist")]
    assert fit(1, q[1]) == pytest.approx(0.0, abs=1e-9)
