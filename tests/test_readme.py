"""The README's examples run as written."""

from __future__ import annotations

import re
import runpy
import shlex
from pathlib import Path

import numpy as np
import pytest

import kms2pin
from kms2pin.cli import main
from kms2pin.ecm import Trajectory, evaluate, make_motion

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_readme_language_example_compiles():
    block = re.findall(r"```c\n(.*?)```", README, re.S)[0]
    robot = kms2pin.load(block)
    assert robot.bodies == ("thigh", "shin")
    assert robot.nq == 2


def _run_block(k: int, tmp_path: Path, monkeypatch) -> None:
    block = re.findall(r"```python\n(.*?)```", README, re.S)[k]
    script = tmp_path / f"readme_example_{k}.py"
    script.write_text(block)
    monkeypatch.chdir(ROOT)
    runpy.run_path(str(script), run_name="__main__")


def test_the_readme_pose_example_runs(tmp_path, monkeypatch, capsys):
    _run_block(0, tmp_path, monkeypatch)
    robot = kms2pin.load(ROOT / "specs" / "fullbody.kms")
    expected = robot.body_pose(robot.q_rest, "leftShin").translation.round(3)
    assert capsys.readouterr().out.strip() == f"{list(robot.joint_names[:3])} {expected}"


def test_the_readme_static_update_example_runs(tmp_path, monkeypatch, capsys):
    """The example prints an equilibrium: converged, and the energy it prints is the springs'
    energy (eq. 2.33) recomputed from the maximal coordinates at the pose, where the energy's
    finite-difference gradient vanishes and which is below the start's."""
    from test_static_update import energy, fd_gradient

    from kms2pin.virtual_work import perturbed_targets

    _run_block(1, tmp_path, monkeypatch)
    converged, iterations, printed_energy, residual = capsys.readouterr().out.split()
    robot = kms2pin.load(ROOT / "specs" / "fullbody.kms")
    targets = perturbed_targets(robot, robot.q_rest, np.random.default_rng(0))
    result = kms2pin.static_update(robot, robot.q_rest, targets, stiffness=1.0)  # the pose it printed about
    assert (converged, int(iterations)) == ("True", result.iterations) and float(residual) < 1e-9
    e = energy(robot, result.q, targets)
    assert float(printed_energy) == pytest.approx(e, rel=1e-12)
    assert e < energy(robot, robot.q_rest, targets)
    grad = fd_gradient(robot, result.q, lambda q: energy(robot, q, targets))
    assert np.abs(grad).max() < 1e-6 * max(1.0, e)


def test_the_readme_tracking_example_runs_and_tracks(tmp_path, monkeypatch, capsys):
    """The tracking example, run in a scratch folder: it writes its CSV there and the
    figures it prints are what the evaluation of that CSV against the truth gives."""
    block = re.findall(r"```python\n(.*?)```", README, re.S)[2]
    (tmp_path / "specs").symlink_to(ROOT / "specs")
    script = tmp_path / "readme_tracking.py"
    script.write_text(block)
    monkeypatch.chdir(tmp_path)
    runpy.run_path(str(script), run_name="__main__")
    out = capsys.readouterr().out
    pct, deg = re.fullmatch(r"(\S+) % of the height, (\S+) deg\n", out).groups()
    robot = kms2pin.load(ROOT / "specs" / "lowerbody.kms", root="free")
    tracked = Trajectory.from_csv(robot, tmp_path / "trajectory.csv")
    report = evaluate(robot, tracked, Trajectory(robot, make_motion(robot, "walk", 30)))
    assert len(tracked) == 30
    assert float(pct) == round(report["mean_centre_error_pct"], 2)
    assert float(deg) == round(report["revolute_rmse_deg"], 1)
    assert float(pct) < 2.0 and float(deg) < 5.0  # the two-camera targets


def test_the_readme_is_short_and_its_links_resolve():
    assert len(README) <= 10_000
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target


def test_the_readme_quick_start_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    commands = re.findall(r"```bash\n(.*?)```", README, re.S)[0].strip().splitlines()
    assert len(commands) == 2
    for command in commands:
        assert command in ci
    # nothing a new user's machine has may be skipped in CI (tests/conftest.py: skip_or_fail_in_ci)
    assert re.search(r"^export CI=1$", ci, re.M)


def test_the_export_guides_other_tools_example_runs_and_agrees_with_kms2pin(tmp_path, monkeypatch, capsys):
    """The export commands and the Pinocchio/MuJoCo example of docs/export.md's 'Using the
    exports in other tools', run in a scratch folder: the joint count and the head's rest
    position it prints are kms2pin's own."""
    guide = (ROOT / "docs" / "export.md").read_text()
    section = guide[guide.index("## Using the exports in other tools") :]
    commands = re.findall(r"```bash\n(.*?)```", section, re.S)[0].strip().splitlines()
    block = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    (tmp_path / "specs").symlink_to(ROOT / "specs")
    monkeypatch.chdir(tmp_path)
    for command in commands:
        argv = shlex.split(command, comments=True)
        assert argv[0] == "kms2pin" and main(argv[1:]) == 0
    capsys.readouterr()
    (tmp_path / "example.py").write_text(block)
    runpy.run_path(str(tmp_path / "example.py"), run_name="__main__")
    names, head = capsys.readouterr().out.splitlines()
    robot = kms2pin.load(ROOT / "specs" / "fullbody.kms", root="free")
    continuous = sum(1 for j in robot.system.joints[1:] if j.kind == "revolute" and j.limits is None)
    assert names.split() == ["root_joint", str(7 + 2 * continuous), str(robot.nv)]
    np.testing.assert_allclose(np.array(head.strip("[]").split(), dtype=float),
                               robot.body_pose(robot.q_rest, "head").translation, atol=1e-3)  # numpy's printed digits
