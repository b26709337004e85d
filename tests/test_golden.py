"""Golden files: the committed tests/golden/ is exactly what the compiler writes today.

If a change to the compiler is intended, regenerate with
``kms2pin export specs/<name>.kms -o tests/golden`` for each spec and review the diff.
"""

from __future__ import annotations

import difflib
from pathlib import Path

import pytest

import kms2pin
from kms2pin.mesh import MESH_NAME, sphere_obj
from kms2pin.robot import Robot

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden"


def _same(actual: str, golden: Path) -> None:
    expected = golden.read_text()
    if actual != expected:
        diff = "".join(difflib.unified_diff(expected.splitlines(True), actual.splitlines(True), str(golden), "compiler", n=1))
        pytest.fail(f"compiler output drifted from {golden.name}:\n{diff[:4000]}")


@pytest.mark.parametrize("name", ["puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry"])
def test_urdf_and_srdf_match_the_committed_golden_files(name):
    spec = kms2pin.parse(ROOT / "specs" / f"{name}.kms")
    for system in spec.systems:
        robot = Robot(spec, system)
        _same(robot.urdf, GOLDEN / f"{system.name}.urdf")
        _same(robot.srdf, GOLDEN / f"{system.name}.srdf")


def test_the_committed_mesh_is_the_generated_unit_sphere():
    _same(sphere_obj(), GOLDEN / "meshes" / MESH_NAME)
    _same(sphere_obj(), ROOT / "kms2pin" / "data" / "meshes" / MESH_NAME)


def test_a_changed_spec_is_caught_by_the_golden_comparison(tmp_path):
    """Negative control: a one-number change in a spec changes the URDF text."""
    text = (ROOT / "specs" / "puma600.kms").read_text().replace("double fac = 1.25", "double fac = 1.3")
    spec = kms2pin.parse_text(text, "puma600.kms")
    assert Robot(spec, spec.system()).urdf != (GOLDEN / "puma600.urdf").read_text()
