"""Shared helpers of the tracker tests: models, cameras, error measures, scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from kms2pin.bvh import ImportOptions, import_bvh, read_bvh
from kms2pin.ecm.camera import Camera
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker
from kms2pin.lang import parse_text
from kms2pin.robot import Robot, load

SPECS = ("puma600", "lowerbody", "fullbody", "jplhand")
DIR = Path(__file__).resolve().parents[2] / "specs"


#: 240 frames of CMU subject 131's walk (tests/data/README.md)
CMU_WALK = Path(__file__).resolve().parents[1] / "data" / "cmu_131_01_walk.bvh"


def cmu_walker(path=CMU_WALK):
    """CMU's subject 131 imported from a BVH file (default: its walk in tests/data; rest:
    the T-pose), a free root, and its configurations at 30 frames/s."""
    imp = import_bvh(read_bvh(path), ImportOptions(scale=0.05644, fps=30.0, name="walker"))
    spec = parse_text(imp.text, "walker.kms")
    return Robot(spec, spec.system(), "free"), imp.q


def _robot(name):
    return load(DIR / f"{name}.kms", root="free")


def _cams(robot, n=2):
    return [Camera.default(), Camera.look_at(position=[8, 0, 8], target=robot.q_rest[:3])][:n]


def centre_error(robot, q, qt) -> float:
    """Mean body-centre error, % of the model height."""
    a = robot.maximal_coordinates(q)[:, :3]
    b = robot.maximal_coordinates(qt)[:, :3]
    return float(np.linalg.norm(a - b, axis=1).mean() / robot.height * 100)


def joint_errors(robot, q, qt) -> np.ndarray:
    """Revolute joint errors (degrees)."""
    return np.degrees(np.abs(pin.difference(robot.model, q, qt)))[6:]


def _perturbed(robot, qt, rng, deg=8.0):
    q0 = qt.copy()
    q0[7:] += np.radians(rng.uniform(-deg, deg, robot.nq - 7))
    q0[:3] += rng.uniform(-1, 1, 3) * 0.01 * robot.height
    return q0



def _anatomical():
    return load(DIR / "anatomical" / "lowerbody.kms", root="free")


def _root_angle_deg(a, b) -> float:
    Ra, Rb = pin.XYZQUATToSE3(a[:7]).rotation, pin.XYZQUATToSE3(b[:7]).rotation
    return float(np.degrees(np.linalg.norm(pin.log3(Ra.T @ Rb))))



def _still_subject():
    """The lower body at a random pose seen by one camera, its clean masks, and tracker
    options starting from that pose with nothing else on."""
    robot = _robot("lowerbody")
    cams = _cams(robot, 1)
    qt = robot.q_rest.copy()
    qt[7:] += np.radians(np.random.default_rng(3).uniform(-15, 15, robot.nq - 7))
    kw = dict(q0=qt, mirror_hypothesis=False, swap_hypothesis=False, calibrate_sizes=False)
    return robot, cams, qt, render(robot, qt, cams), kw



def _folded_finger_frame(cams, finger, off_deg, search, **options):
    """The hand's random motion (seed 0) tracked from the truth on clean silhouettes for
    frames 34-39 (the search on a falling fit waits until the running fit has settled,
    five frames), then frame 40 started with ``finger``'s middle and tip joints
    ``off_deg`` off; returns the tracker (``options`` passed on), frame 40's result, the
    true configuration and the tip's q index."""
    robot = _robot("jplhand")
    motion = make_motion(robot, "random", 300, np.random.default_rng(0))
    m = robot.model
    mid, tip = (m.joints[m.getJointId(n)].idx_q for n in (f"midFinger{finger}_lowerJoint", f"tip{finger}_joint"))
    tr = Tracker(robot, cams, q0=motion[34], prediction="previous", calibrate_sizes=False, limb_search=search, **options)
    for f in range(34, 40):
        assert not tr.step(render(robot, motion[f], cams)).flags
    tr.q[mid] += np.radians(off_deg[0])
    tr.q[tip] += np.radians(off_deg[1])
    return tr, tr.step(render(robot, motion[40], cams)), motion[40], tip

