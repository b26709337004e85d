"""The second track (``second_track``): the frames tracked twice, each frame's better pose."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.cli import build_parser
from kms2pin.commands._tracking import tracker_options
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.options import second_changes
from kms2pin.ecm.secondtrack import FLAG
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


def test_each_frame_reports_the_better_fitting_of_two_tracks_that_go_on_by_themselves():
    """With ``second_track`` every frame is the pose, of two tracks made apart (the options,
    and the options with the changes), that fits the masks better (IoU at the first track's
    sizes, computed here from the silhouettes); each track goes on from its own poses, so
    both are those tracks to the last bit.  The second's frames are flagged."""
    robot, qs, cams, masks = _scene()
    first = Tracker(robot, cams, q0=qs[0], **WEAK)
    second = Tracker(robot, cams, q0=qs[0], **{**WEAK, **second_changes(CHANGES)})
    both = Tracker(robot, cams, q0=qs[0], **WEAK, second_track=CHANGES)
    taken = 0
    for m in masks:
        a, b, r = first.step(m), second.step(m), both.step(m)
        fits = [silhouette_iou(robot.body_poses(x.q), both.inner, cams, m) for x in (a, b)]
        if fits[1] > fits[0]:
            taken += 1
            np.testing.assert_array_equal(r.q, b.q)
            assert r.flags == (*b.flags, FLAG) and r.fit == pytest.approx(fits[1], abs=1e-12)
        else:
            np.testing.assert_array_equal(r.q, a.q)
            assert FLAG not in r.flags
        np.testing.assert_array_equal(both.q, a.q)  # the first track goes on from its own pose
        np.testing.assert_array_equal(both._second.q, b.q)
        assert set(r.timings) == set(a.timings)
    assert taken > 0  # the track that runs on fits better somewhere


def test_a_second_track_is_written_as_option_changes_and_refused_with_a_reason():
    assert second_changes("midline=1, reach_always=limbs,reach_skip=false,ground_height=none") == {
        "midline": 1, "reach_always": "limbs", "reach_skip": False, "ground_height": None}
    assert second_changes("") == {}
    robot = _robot("lowerbody")
    for text, message in (("midlin=1", "second_track: unknown option 'midlin' (did you mean 'midline'?)"),
                          ("midline", "second_track: 'midline' is not NAME=VALUE"),
                          ("midline=-1", "second_track: midline must be >= 0.0, not -1"),
                          ("second_track=a", "second_track: the second track has no second track of its own"),
                          ("upright=high", "second_track: upright must be a number, not 'high'")):
        with pytest.raises(OptionError) as err:
            Tracker(robot, Camera.default(), second_track=text)
        assert str(err.value) == message


def test_the_track_command_takes_a_second_track():
    parser = build_parser()
    args = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--preset", "people",
                              "--second-track", "midline=1"])
    opts = tracker_options(args)
    assert opts.hypotheses.second_track == "midline=1" and opts.limbs.reach_search is True
    bad = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--second-track", "midline=x"])
    with pytest.raises(UsageError, match="--second-track: second_track: midline must be a number"):
        tracker_options(bad)
