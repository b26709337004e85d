"""Helpers shared by the reference-implementation tests."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

import kms2pin
from kms2pin.reference import forward_kinematics

SPECS = Path(__file__).resolve().parents[2] / "specs"
# the thesis's four models, ours with spherical and prismatic joints, and conftest's MIXED_JOINTS
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry", "mixed")
ROOTS = ("spec", "free")
JOINT_DOF = {"fixed": 0, "revolute": 1, "prismatic": 1, "spherical": 3}


@cache
def load_system(name: str) -> kms2pin.System:
    if name == "mixed":
        from conftest import MIXED_JOINTS

        return kms2pin.parse(MIXED_JOINTS).system()
    return kms2pin.parse(SPECS / f"{name}.kms").system()


def moving_joints(system, root: str = "spec") -> list:
    """The joints with a value (revolute, spherical, prismatic), less a free root's."""
    return [j for j in system.joints if j.kind != "fixed" and not (root == "free" and j.parent is None)]


def revolute_names(system, root: str = "spec") -> list[str]:
    return [j.name for j in moving_joints(system, root) if j.kind == "revolute"]


def random_unit_quaternion(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def random_angles(system, rng: np.random.Generator, root: str = "spec", spread: float = np.pi) -> dict[str, object]:
    """Random joint values: revolute angles within +-spread, spherical rotation vectors of
    length up to spread, prismatic offsets within +-0.5 (their limits where tighter)."""
    out: dict[str, object] = {}
    for j in moving_joints(system, root):
        if j.kind == "revolute":
            out[j.name] = float(rng.uniform(-spread, spread))
        elif j.kind == "spherical":
            axis = rng.normal(size=3)
            out[j.name] = axis / np.linalg.norm(axis) * rng.uniform(0, spread)
        else:
            lo, hi = j.limits if j.limits is not None else (-0.5, 0.5)
            out[j.name] = float(rng.uniform(max(lo, -0.5), min(hi, 0.5)))
    return out


def random_configuration(system, rng: np.random.Generator, root: str = "spec"):
    """(q (n, 7), angles, root_pose) of a random valid configuration."""
    angles = random_angles(system, rng, root)
    pose = (rng.normal(size=3), random_unit_quaternion(rng)) if root == "free" else None
    return forward_kinematics(system, angles, pose, root=root), angles, pose
