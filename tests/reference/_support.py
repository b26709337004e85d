"""Helpers shared by the reference-implementation tests."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

import kms2pin
from kms2pin.reference import forward_kinematics

SPECS = Path(__file__).resolve().parents[2] / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")
ROOTS = ("spec", "free")


@cache
def load_system(name: str) -> kms2pin.System:
    return kms2pin.parse(SPECS / f"{name}.kms").system()


def revolute_names(system, root: str = "spec") -> list[str]:
    return [j.name for j in system.joints if j.kind == "revolute" and not (root == "free" and j.parent is None)]


def random_unit_quaternion(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def random_angles(system, rng: np.random.Generator, root: str = "spec", spread: float = np.pi) -> dict[str, float]:
    return {name: float(rng.uniform(-spread, spread)) for name in revolute_names(system, root)}


def random_configuration(system, rng: np.random.Generator, root: str = "spec"):
    """(q (n, 7), angles, root_pose) of a random valid configuration."""
    angles = random_angles(system, rng, root)
    pose = (rng.normal(size=3), random_unit_quaternion(rng)) if root == "free" else None
    return forward_kinematics(system, angles, pose, root=root), angles, pose
