"""Tracker options: ranges, types, misspelt names, presets."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm.camera import Camera
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
