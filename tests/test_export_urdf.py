"""The URDF of every spec passes urdfdom's check_urdf, loads in Pinocchio, and places the
bodies as the Pinocchio model kms2pin builds does."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import MIXED_JOINTS, SPECS

import kms2pin
from kms2pin.cli import main


def _check_urdf() -> str:
    exe = Path(sys.executable).with_name("check_urdf")
    return str(exe) if exe.exists() else (shutil.which("check_urdf") or "check_urdf")


def test_every_spec_exports_a_urdf_that_check_urdf_accepts(spec_path, tmp_path):
    assert main(["export", str(spec_path), "-o", str(tmp_path)]) == 0
    urdfs = list(tmp_path.glob("*.urdf"))
    assert len(urdfs) == 1
    out = subprocess.run([_check_urdf(), str(urdfs[0])], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Successfully Parsed XML" in out.stdout
    assert (tmp_path / "meshes" / "unit_sphere.obj").exists()


def test_exported_files_load_with_pinocchio_urdf_and_geometry_parsers(spec_path, tmp_path):
    main(["export", str(spec_path), "-o", str(tmp_path)])
    urdf = next(tmp_path.glob("*.urdf"))
    model = pin.buildModelFromUrdf(str(urdf))
    robot = kms2pin.load(spec_path)
    assert model.nv == robot.model.nv
    geom = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=[str(tmp_path)])
    assert geom.ngeoms == 2 * len(robot.bodies)
    srdf = urdf.with_suffix(".srdf")
    pin.loadReferenceConfigurations(model, str(srdf), False)
    rest = model.referenceConfigurations["rest"]
    if model.nq == robot.nq:  # no spherical joint: the same coordinates
        assert (rest == robot.q_rest).all()
    # the SRDF's rest state puts every body where kms2pin's rest pose does
    data = model.createData()
    pin.framesForwardKinematics(model, data, rest)
    for name, M in zip(robot.bodies, robot.body_poses(robot.q_rest)):
        link = data.oMf[model.getFrameId(name, pin.FrameType.BODY)]
        centre = link * pin.SE3(np.eye(3), -np.asarray(robot.system.joint_of(name).child_bvec.pos))
        np.testing.assert_allclose(centre.homogeneous, M.homogeneous, atol=1e-12, err_msg=name)


def xyz_angles(R: np.ndarray) -> tuple[float, float, float]:
    """(a, b, c) with Rx(a) Ry(b) Rz(c) = R, |b| < 90 deg (R[0, 2] = sin b,
    R[1, 2] = -sin a cos b, R[2, 2] = cos a cos b, R[0, 1] = -cos b sin c, R[0, 0] = cos b cos c)."""
    return math.atan2(-R[1, 2], R[2, 2]), math.asin(R[0, 2]), math.atan2(-R[0, 1], R[0, 0])


def urdf_configuration(robot, urdf_model, q) -> np.ndarray | None:
    """The URDF model's q for kms2pin's ``q``: revolute and prismatic joints and a free root
    as they are, a spherical joint's quaternion (x, y, z, w) as its three URDF angles; None
    near the X-Y-Z decomposition's gimbal singularity (|b| > 80 deg)."""
    out = pin.neutral(urdf_model)
    kinds = {j.name: j.kind for j in robot.system.joints}
    for jid in range(1, robot.model.njoints):
        name, jm = robot.model.names[jid], robot.model.joints[jid]
        block = q[jm.idx_q : jm.idx_q + jm.nq]
        if kinds.get(name) == "spherical":
            x, y, z, w = block / np.linalg.norm(block)
            R = np.array([
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ])  # fmt: skip
            angles = xyz_angles(R)
            if abs(angles[1]) > math.radians(80):
                return None
            for axis, angle in zip("xyz", angles):
                out[urdf_model.joints[urdf_model.getJointId(f"{name}_{axis}")].idx_q] = angle
        else:
            u = urdf_model.joints[urdf_model.getJointId(name)]
            out[u.idx_q : u.idx_q + u.nq] = block
    return out


@pytest.mark.parametrize("root", ["spec", "free"])
@pytest.mark.parametrize("name", ["human", "gantry", "mixed"])
def test_urdf_and_pinocchio_models_place_every_body_alike(name, root):
    """A spherical joint's three URDF revolute joints (Exp(r) = Rx Ry Rz) and the prismatic
    joints give the bodies the poses of the Pinocchio model kms2pin builds, at random
    configurations away from the gimbal singularity."""
    robot = kms2pin.load(kms2pin.parse(MIXED_JOINTS) if name == "mixed" else SPECS / f"{name}.kms", root=root)
    urdf_model = (pin.buildModelFromXML(robot.urdf, pin.JointModelFreeFlyer()) if root == "free"
                  else pin.buildModelFromXML(robot.urdf))
    data = urdf_model.createData()
    rng = np.random.default_rng(7)
    compared = 0
    while compared < 20:
        q = robot.random_configuration(rng, 150)
        if root == "free":
            q[:3] += rng.normal(size=3)
            q[3:7] = rng.normal(size=4)
            q[3:7] /= np.linalg.norm(q[3:7])
        q_urdf = urdf_configuration(robot, urdf_model, q)
        if q_urdf is None:
            continue
        pin.framesForwardKinematics(urdf_model, data, q_urdf)
        robot.forward(q)
        for body in robot.bodies:
            ours = robot.data.oMf[robot.model.getFrameId(body, pin.FrameType.BODY)]
            theirs = data.oMf[urdf_model.getFrameId(body, pin.FrameType.BODY)]
            np.testing.assert_allclose(theirs.homogeneous, ours.homogeneous, atol=1e-10, err_msg=body)
        compared += 1
