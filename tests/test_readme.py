"""The README's examples run as written."""

from __future__ import annotations

import re
import runpy
from pathlib import Path

import kms2pin

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_readme_language_example_compiles():
    block = re.findall(r"```c\n(.*?)```", README, re.S)[0]
    robot = kms2pin.load(block)
    assert robot.bodies == ("thigh", "shin")
    assert robot.nq == 2


def test_the_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    block = re.findall(r"```python\n(.*?)```", README, re.S)[0]
    script = tmp_path / "readme_example.py"
    script.write_text(block)
    monkeypatch.chdir(ROOT)
    runpy.run_path(str(script), run_name="__main__")
    assert capsys.readouterr().out.startswith("True ")


def test_the_readme_quick_start_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    commands = re.findall(r"```bash\n(.*?)```", README, re.S)[0].strip().splitlines()
    assert len(commands) == 2
    for command in commands:
        assert command in ci
