"""The second track (``second_track``): the frames tracked twice, each frame's better pose."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from kms2pin.cli import build_parser
from kms2pin.commands._tracking import tracker_options
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.options import second_changes, track_changes
from kms2pin.ecm.secondtrack import FLAG, better, flag, track_name
from kms2pin.ecm.silhouette import silhouette_iou
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.errors import OptionError, UsageError

from ._tracking import _robot

#: a first track that stops after one ECM iteration a frame, a second that runs on
WEAK, CHANGES = {"max_iterations": 1, "min_iterations": 1, "limb_search": False}, "max_iterations=8,min_iterations=3"


def _scene(frames=12):
    robot = _robot("lowerbody")
    qs = make_motion(robot, "walk", 40)[10 : 10 + frames]
    cams = [Camera.look_at(position=qs[0][:3] + [0.0, 0.5, 6.0], target=qs[0][:3], width=160, height=120),
            Camera.look_at(position=qs[0][:3] + [5.0, 2.0, 3.0], target=qs[0][:3], width=160, height=120)]
    return robot, qs, cams, [render(robot, q, cams) for q in qs]


def _check_frame(robot, r, runs, cams, m, inner) -> int:
    """Check frame result ``r`` of tracks ``runs`` (each track's own result) on masks ``m``:
    the whole pose is the best-fitting track's (IoU computed here; ties the earlier), then
    each part flagged ``'<joint>' taken from <track>`` brings that track's joint
    coordinates, with those below it, in the order the flags give; the fit is the pose's
    and no lower than the best track's.  Returns the track chosen."""
    fits = [silhouette_iou(robot.body_poses(x.q), inner, cams, m) for x in runs]
    k = int(np.argmax(fits))
    names = {track_name(t): t for t in range(len(runs))}
    taken = [re.fullmatch(r"'(.+)' taken from (.+)", f) for f in r.flags]
    taken = [(x[1], names[x[2]]) for x in taken if x]
    pm = robot.model
    np.testing.assert_array_equal(r.q[:7], runs[k].q[:7])  # the root is no part: the chosen track's
    for j in robot.joints:
        if j.kind == "free":
            continue
        jid = pm.getJointId(j.name)
        source = k
        for name, t in taken:  # the last part taken over j, in the order taken
            if jid in pm.subtrees[pm.getJointId(name)]:
                source = t
        sl = slice(pm.idx_qs[jid], pm.idx_qs[jid] + pm.nqs[jid])
        np.testing.assert_array_equal(r.q[sl], runs[source].q[sl], err_msg=j.name)
    assert all(t != k for _, t in taken)  # never from the chosen track itself
    for a, (name, _) in enumerate(taken):  # a part taken again, or under one taken later: one flag, the last
        assert not any(pm.getJointId(name) in pm.subtrees[pm.getJointId(later)] for later, _ in taken[a + 1:]), r.flags
    fit = silhouette_iou(robot.body_poses(r.q), inner, cams, m)
    assert r.fit == pytest.approx(fit, abs=1e-12) and fit >= fits[k] - 1e-12
    assert (fit > fits[k]) == bool(taken)
    assert (flag(k - 1) in r.flags) if k else not any(f.startswith("from the") for f in r.flags)
    return k


@pytest.mark.parametrize("weak_first", [True, False])
def test_each_frame_reports_the_better_fitting_of_two_tracks_that_go_on_by_themselves(weak_first):
    """With ``second_track`` every frame is the pose, of two tracks made apart (the options,
    and the options with the changes), that fits the masks better (IoU at the first track's
    sizes, computed here from the silhouettes), with that fit; each track goes on from its
    own poses, so both are those tracks to the last bit.  The second's frames are flagged;
    a frame with no mask to fit is the first track's.  A weak track (one ECM iteration a
    frame) beside a full one: the full one's frames are taken, whichever it is."""
    robot, qs, cams, masks = _scene()
    masks.insert(6, [np.zeros_like(m) for m in masks[0]])  # the subject gone for a frame
    strong = {"max_iterations": 8, "min_iterations": 3}
    one, other = (WEAK, strong) if weak_first else (strong, WEAK)
    changes = ",".join(f"{k}={v}" for k, v in other.items())
    first = Tracker(robot, cams, q0=qs[0], **one)
    second = Tracker(robot, cams, q0=qs[0], **{**one, **other})
    both = Tracker(robot, cams, q0=qs[0], **one, second_track=changes)
    chosen, parts = [], 0
    for m in masks:
        a, b, r = first.step(m), second.step(m), both.step(m)
        if not any(x.any() for x in m):
            assert "empty mask" in r.flags and FLAG not in r.flags
            np.testing.assert_array_equal(r.q, a.q)
            continue
        chosen.append(_check_frame(robot, r, [a, b], cams, m, both.inner))
        parts += any("' taken from" in f for f in r.flags)
        np.testing.assert_array_equal(both.q, a.q)  # the first track goes on from its own pose
        np.testing.assert_array_equal(both.tracks_beside[0].q, b.q)
        assert set(r.timings) == set(a.timings)
    # the full track's frames are the better ones (after the first, where both start alike)
    assert sum(chosen) >= len(chosen) - 2 if weak_first else sum(chosen) <= 2
    assert parts  # and the weak one's parts fit better now and then


def test_each_part_is_taken_from_the_track_that_holds_it():
    """Two tracks, each with one knee off (the other's right): the frame reported is the
    true pose, the chosen track's with the other's leg, flagged with the part taken."""
    robot, qs, cams, masks = _scene(2)
    tracker = Tracker(robot, cams, q0=qs[0])
    tracker.step(masks[0])
    res = tracker.step(masks[1])
    pm = robot.model
    offs = []
    for knee in ("leftShin_knee", "rightShin_knee"):
        q = qs[1].copy()
        q[pm.idx_qs[pm.getJointId(knee)]] += 0.6
        offs.append(dataclasses.replace(res, q=q, flags=()))
    out = better(tracker, offs[0], [offs[1]], masks[1], "frame 1")
    _check_frame(robot, out, offs, cams, masks[1], tracker.inner)
    np.testing.assert_array_equal(out.q, qs[1])
    assert len([f for f in out.flags if "' taken from" in f]) == 1


def test_a_second_track_is_written_as_option_changes_and_refused_with_a_reason():
    assert second_changes("midline=1, reach_always=limbs,reach_skip=false,ground_height=none") == {
        "midline": 1, "reach_always": "limbs", "reach_skip": False, "ground_height": None}
    assert second_changes("") == {}
    robot = _robot("lowerbody")
    for text, message in (("midlin=1", "second_track: unknown option 'midlin' (did you mean 'midline'?)"),
                          ("midline", "second_track: 'midline' is not NAME=VALUE"),
                          ("midline=-1", "second_track: midline must be >= 0.0 and <= 1000000.0, not -1"),
                          ("second_track=a", "second_track: the second track has no second track of its own"),
                          ("upright=high", "second_track: upright must be a number, not 'high'"),
                          (3, "second_track must be text such as 'midline=1', not 3"),
                          ("up=0,1,0", "second_track: up is a vector, which NAME=VALUE cannot write; give it to "
                                       "both tracks instead")):
        with pytest.raises(OptionError) as err:
            Tracker(robot, Camera.default(), second_track=text)
        assert str(err.value) == message
    # the changes are checked with the options they change, not the defaults
    Tracker(robot, Camera.default(), min_iterations=1, second_track="max_iterations=2")
    with pytest.raises(OptionError, match="^second_track: static='diagonal'"):
        Tracker(robot, Camera.default(), upright=0.1, second_track="static=diagonal")
    # the second tracker decides its automatic options for itself (one camera: the alternatives' iterations)
    t = Tracker(robot, Camera.default(), max_iterations=1, min_iterations=1, second_track="max_iterations=8")
    assert t.options.hypotheses.hypothesis_iterations == 1
    assert t.tracks_beside[0].options.hypotheses.hypothesis_iterations == 8


def test_the_track_command_takes_a_second_track():
    parser = build_parser()
    args = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--preset", "people",
                              "--second-track", "midline=1"])
    opts = tracker_options(args)
    assert opts.hypotheses.second_track == "midline=1" and opts.limbs.reach_search is True
    bad = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--second-track", "midline=x"])
    with pytest.raises(UsageError, match="--second-track: second_track: midline must be a number"):
        tracker_options(bad)
    # two tracks beside; a flag whose check is across options (--midline-legs needs --midline)
    # is checked with the other flags given, whatever their order
    three = "midline=1; midline=1,midline_legs=0.1"
    for order in (["--midline-legs", "0.1", "--midline", "1"], ["--midline", "1", "--midline-legs", "0.1"]):
        opts = tracker_options(parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--second-track",
                                                  three, *order]))
        assert opts.hypotheses.second_track == three and (opts.priors.midline, opts.priors.midline_legs) == (1, 0.1)
    alone = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--midline-legs", "0.1"])
    with pytest.raises(UsageError, match="^--midline-legs: midline_legs .* set midline above 0"):
        tracker_options(alone)


@pytest.mark.parametrize("poor_fit", [0.0, 0.99])
def test_a_frame_from_the_second_track_is_judged_poor_by_the_first_tracks_threshold(poor_fit):
    """The second track flags ``poor fit`` by its own sizes and running state; the frame
    reported is judged again by the first tracker's ``poor_fit`` at the fit it reports
    (the silhouettes' IoU at the first tracker's sizes, computed here)."""
    robot, qs, cams, masks = _scene(2)
    tracker = Tracker(robot, cams, q0=qs[0], poor_fit=poor_fit)
    tracker.step(masks[0])
    res = tracker.step(masks[1])
    off = qs[1].copy()
    off[:3] += [0.15, 0.0, 0.0]  # the first track's pose 15 cm off (its joints the truth's); the second's the truth
    second = dataclasses.replace(res, q=qs[1], flags=("poor fit (0.01)", "swung 'x' the other way"))
    out = better(tracker, dataclasses.replace(res, q=off), [second], masks[1], "frame 1")
    fit = silhouette_iou(robot.body_poses(qs[1]), tracker.inner, cams, masks[1])
    assert 0.5 < fit < 0.99 and out.fit == pytest.approx(fit, abs=1e-12)
    judged = (f"poor fit ({fit:.2f})",) if poor_fit else ()
    assert out.flags == ("swung 'x' the other way", *judged, FLAG)
    np.testing.assert_array_equal(out.q, qs[1])


def test_several_tracks_beside_each_frame_the_best_fitting_of_them():
    """``second_track`` with tracks separated by ';': each a tracker of its own with its
    changes to the options as given; each frame is the pose of the three that fits the
    masks best (ties to the earlier track), flagged by the track it came from."""
    robot, qs, cams, masks = _scene(8)
    two = {"max_iterations": 2, "min_iterations": 1, "limb_search": False}
    strong = {"max_iterations": 8, "min_iterations": 3}
    alone = [Tracker(robot, cams, q0=qs[0], **WEAK), Tracker(robot, cams, q0=qs[0], **{**WEAK, **two}),
             Tracker(robot, cams, q0=qs[0], **{**WEAK, **strong})]
    both = Tracker(robot, cams, q0=qs[0], **WEAK, second_track="max_iterations=2; max_iterations=8,min_iterations=3")
    assert [len(t.tracks_beside) for t in (both, *both.tracks_beside)] == [2, 0, 0]
    assert both.tracks_beside[1].options.iteration.min_iterations == 3
    assert both.tracks_beside[0].options.iteration.min_iterations == 1  # each track's changes to the options as given
    chosen = []
    for m in masks:
        runs, r = [t.step(m) for t in alone], both.step(m)
        chosen.append(_check_frame(robot, r, runs, cams, m, both.inner))
        for t, other in zip(both.tracks_beside, alone[1:]):
            np.testing.assert_array_equal(t.q, other.q)
    assert {1, 2} <= set(chosen) and chosen.count(0) <= 1  # both tracks beside chosen, the weak one hardly
    assert flag(0) == FLAG and flag(1) == "from the third track" and flag(5) == "from track 7"


def test_tracks_beside_are_separated_by_semicolons_and_none_is_empty():
    assert track_changes("midline=1; reach_rest=2,midline=1") == ({"midline": 1}, {"reach_rest": 2, "midline": 1})
    assert track_changes("") == () and track_changes("midline=1") == ({"midline": 1},)
    robot = _robot("lowerbody")
    for text, message in (("midline=1;", "second_track: a track between ';' changes nothing in 'midline=1;'"),
                          ("midline=1;;reach_rest=2", "second_track: a track between ';' changes nothing"),
                          ("midline=1; midlin=2", "second_track: unknown option 'midlin'"),
                          ("midline=1; midline=-1", "second_track: midline must be >= 0.0 and <= 1000000.0, not -1")):
        with pytest.raises(OptionError, match=f"^{message}"):
            Tracker(robot, Camera.default(), second_track=text)


def test_the_flags_of_a_track_and_of_a_part_taken_from_one_are_told_apart_from_the_others():
    from kms2pin.ecm.secondtrack import is_track_flag, part_flag

    assert part_flag("leftShin_knee", 0) == "'leftShin_knee' taken from the first track"
    assert part_flag("a", 9) == "'a' taken from track 10"
    for f in (FLAG, flag(1), flag(8), part_flag("leftShin_knee", 2), part_flag("x y", 12)):
        assert is_track_flag(f), f
    for f in ("'x' taken from the frames beside it", "poor fit (0.40)", "from the second track!",
              "kept from the backward track", "'x' taken from the backward track"):
        assert not is_track_flag(f), f
