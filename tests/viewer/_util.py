"""Helpers shared by the viewer tests."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from conftest import page_commands  # noqa: F401 - the viewer tests' import

import kms2pin

SPECS = Path(__file__).resolve().parents[2] / "specs"


def load(name: str, root: str = "spec") -> kms2pin.Robot:
    return kms2pin.load(SPECS / f"{name}.kms", root=root)


def joint_q(robot: kms2pin.Robot, name: str) -> int:
    return robot.model.joints[robot.model.getJointId(name)].idx_q


@dataclass
class FakeResult:
    """Same fields as kms2pin.static_update's StaticUpdateResult."""

    q: np.ndarray
    converged: bool = True
    iterations: int = 5
    residual: float = 0.0
    energy: float = 0.0
    forces: np.ndarray | None = None


def without_uuids(obj):
    """A decoded command with every uuid (and uuid reference) replaced by a placeholder."""
    uuid = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$")
    if isinstance(obj, dict):
        return {k: without_uuids(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [without_uuids(v) for v in obj]
    if isinstance(obj, str) and uuid.match(obj):
        return "<uuid>"
    return obj
