"""Tracker options: ranges, types, misspelt names, presets."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from kms2pin.cli import build_parser
from kms2pin.commands._tracking import tracker_options
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.options import (
    GROUPS,
    PEOPLE,
    PEOPLE_ONE_CAMERA,
    PEOPLE_TRACKS,
    SEGMENTED_MASKS,
    IterationOptions,
    LimbSearchOptions,
    PriorOptions,
    TrackerOptions,
    cli_fields,
)
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.errors import InputDataError, OptionError

from ._tracking import (
    _robot,
)


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
        (dict(upright=-1.0), "upright must be >= 0.0 and <= 1000000.0, not -1.0"),
        # a weight that would overflow the springs' products (NumPy warnings, a NaN pose) is refused
        (dict(ground=1e308), "ground must be >= 0.0 and <= 1000000.0, not 1e+308"),
        (dict(mirror_hypothesis=True, tol_px=0.0), "tol_px must be > 0.0 or None, not 0.0"),
        (dict(static="diagonal", upright=0.1, midline=1.0),
         "static='diagonal' (the thesis's diagonal springs) has no terms for the priors, but upright=0.1, "
         "midline=1.0 is set: use static='full' (the default) or turn them off"),
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


def test_options_and_keywords_give_the_same_track():
    """Tracker(robot, cams, options=TrackerOptions(...)) and the keyword spelling give the
    same options and the same track, frame for frame; a preset works both ways too."""
    robot = _robot("lowerbody")
    cams = [Camera.default()]
    motion = make_motion(robot, "walk", 8)
    frames = [render(robot, q, cams) for q in motion]
    opts = TrackerOptions(priors=PriorOptions(upright=0.1, rest_prior=0.01, rest_pose="start", ground=0.1),
                          iteration=IterationOptions(max_iterations=6, prediction="learnt"),
                          limbs=LimbSearchOptions(reach_search=True))
    a = Tracker(robot, cams, opts, q0=motion[0])
    b = Tracker(robot, cams, q0=motion[0], upright=0.1, rest_prior=0.01, rest_pose="start", ground=0.1,
                max_iterations=6, prediction="learnt", reach_search=True)
    assert a.options == b.options
    for m in frames:
        ra, rb = a.step(m), b.step(m)
        np.testing.assert_array_equal(ra.q, rb.q)
        assert (ra.fit, ra.flags, ra.iterations) == (rb.fit, rb.flags, rb.iterations)
    c = Tracker(robot, cams, options=PEOPLE_ONE_CAMERA, q0=motion[0], max_iterations=6)
    d = Tracker(robot, cams, q0=motion[0], max_iterations=6, **PEOPLE_ONE_CAMERA)
    assert c.options == d.options == a.options
    assert Tracker(robot, cams, SEGMENTED_MASKS).options.limbs.limb_search_drop == 0.03
    people = Tracker(robot, cams, PEOPLE)  # one camera's preset is this one's, without the twist priors, and the priors
    assert people.reach is not None and people.options.iteration.prediction == "learnt"
    pri = people.options.priors
    assert (pri.spine_twist, pri.twist_prior, pri.twist_free) == (0.05, 1.0, 90.0)
    assert (people.options.limbs.reach_always, people.reach.skip, people.reach.rest) == ("arms", False, 0)
    # one camera keeps the reach search as it was: the arms always re-aimed, and searched on
    # every frame, are measured with two and four cameras only
    twists = ("spine_twist", "twist_prior", "twist_free", "reach_always", "reach_skip", "reach_rest")
    shared = {k: v for k, v in dict(PEOPLE).items() if k not in twists}
    assert shared.items() <= dict(PEOPLE_ONE_CAMERA).items()
    assert not set(twists) & set(dict(PEOPLE_ONE_CAMERA))


def test_people_tracks_is_people_with_three_tracks_beside_each_changed_as_documented():
    """``PEOPLE_TRACKS``: ``PEOPLE``'s options for the first track, and three tracks beside
    it, each ``PEOPLE`` with its own changes (the thighs off the midline; that and the legs'
    midline prior; a shorter motion memory), going on by themselves."""
    robot = _robot("fullbody")
    cams = [Camera.default(), Camera.default()]
    four = Tracker(robot, cams, PEOPLE_TRACKS)
    people = Tracker(robot, cams, PEOPLE)
    assert four.options.replace(second_track="") == people.options
    beside = four.tracks_beside
    assert len(beside) == 3
    changes = [{"midline": 1.0}, {"midline": 1.0, "midline_legs": 0.1}, {"prediction_memory": 3.0}]
    for track, changed in zip(beside, changes):
        assert track.options == people.options.replace(**changed)
        assert track.options.flat().items() >= changed.items()


def test_overrides_go_over_the_options_and_each_option_is_in_one_group():
    opts = TrackerOptions().replace(upright=0.2, size_every=0, limbs=LimbSearchOptions(limb_margin=0.01))
    assert (opts.priors.upright, opts.sizes.size_every, opts.limbs.limb_margin) == (0.2, 0, 0.01)
    flat = opts.flat()
    names = [f.name for g in GROUPS.values() for f in dataclasses.fields(g)]
    assert len(names) == len(set(names)) == len(flat)  # one flat name space
    # every option has help, and asdict is what meta.json records (JSON-ready)
    for cls in GROUPS.values():
        for f in dataclasses.fields(cls):
            assert f.metadata["help"] and f.name in cls.__doc__
    assert json.loads(json.dumps(dataclasses.asdict(opts)))["priors"]["up"] == [0.0, 1.0, 0.0]
    with pytest.raises(OptionError, match="upright must be >= 0.0"):
        opts.replace(upright=-1.0)
    with pytest.raises(OptionError, match="mirror_hypothesis must be True or False or None"):
        TrackerOptions().replace(mirror_hypothesis="yes")
    with pytest.raises(OptionError, match="options must be a TrackerOptions"):
        Tracker(_robot("lowerbody"), Camera.default(), {"upright": 0.1})


def test_the_track_command_has_a_flag_for_each_option_that_declares_one(capsys):
    """kms2pin track's flags come from the option fields: each declared flag is there
    with the option's help, and parses into the option (0 stands for None where
    declared; switches not given stay automatic)."""
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["track", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    for f in cli_fields():
        assert f.metadata["cli"].flag in shown and " ".join(f.metadata["help"].split()) in shown
    args = parser.parse_args(["track", "x.kms", "--masks", "m", "-o", "o", "--tol-px", "0", "--upright", "0.1",
                              "--no-mirror-hypothesis", "--up", "0", "0", "1", "--size-every", "3",
                              "--prediction", "learnt", "--reach-search"])
    opts = tracker_options(args)
    assert opts.iteration.prediction == "learnt" and opts.limbs.reach_search is True
    assert opts.iteration.tol_px is None and opts.priors.upright == 0.1 and opts.sizes.size_every == 3
    assert opts.hypotheses.mirror_hypothesis is False and opts.priors.up == (0.0, 0.0, 1.0)
    assert opts.limbs.limb_search is None and opts.hypotheses.swap_hypothesis is None  # not given: automatic
