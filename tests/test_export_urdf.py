"""The exported URDF/SRDF of every spec, with either root, as other tools read them:
urdfdom's check_urdf, Pinocchio's own URDF and SRDF parsers (no kms2pin in between) and
MuJoCo's URDF importer, each compared with kms2pin's model at random configurations."""

from __future__ import annotations

import math
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from _interop import (
    ALL_SPECS,
    body_frame,
    check_urdf_exe,
    mujoco_kinematics,
    mujoco_qpos,
    pinocchio_q,
    random_q,
)

import kms2pin
from kms2pin.cli import main
from kms2pin.urdf import OUTER_RGBA

CASES = [(p, root) for p in ALL_SPECS for root in ("spec", "free")]
TOL = 1e-9


class Export:
    """One export: the folder, its URDF and SRDF, and kms2pin's robot of the same spec."""

    def __init__(self, spec: Path, root: str, out: Path):
        assert main(["export", str(spec), "-o", str(out), "--root", root]) == 0
        self.out = out
        self.robot = kms2pin.load(spec, root=root)
        self.urdf = out / f"{self.robot.system.name}.urdf"
        self.srdf = self.urdf.with_suffix(".srdf")
        self.xml = ET.parse(self.urdf).getroot()


def srdf_rest(srdf: Path, robot) -> np.ndarray:
    """The SRDF's rest state as a configuration of kms2pin's ``robot``, read by this test: one
    angle per revolute joint, x y z qx qy qz qw for a free root (Pinocchio 4.1's own reader
    refuses one angle for a continuous joint whose axis is not x, y or z)."""
    q = np.full(robot.nq, np.nan)
    state = ET.parse(srdf).getroot().find("group_state[@name='rest']")
    for joint in state.iter("joint"):
        j = robot.model.joints[robot.model.getJointId(joint.get("name"))]
        q[j.idx_q : j.idx_q + j.nq] = np.array(joint.get("value").split(), dtype=float)
    return q


@pytest.fixture(scope="module", params=CASES, ids=[f"{p.parent.name}/{p.stem}-{r}" for p, r in CASES])
def export(request, tmp_path_factory) -> Export:
    spec, root = request.param
    return Export(spec, root, tmp_path_factory.mktemp("export"))


def test_check_urdf_accepts_every_export(export):
    out = subprocess.run([check_urdf_exe(), str(export.urdf)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Successfully Parsed XML" in out.stdout
    assert (export.out / "meshes" / "unit_sphere.obj").exists()


def test_movable_joints_have_placeholder_effort_and_velocity_and_only_the_specs_ranges(export):
    spec_joints = {j.name: j for j in export.robot.system.joints}
    for joint in export.xml.iter("joint"):
        name, kind, limit = joint.get("name"), joint.get("type"), joint.find("limit")
        if kind == "fixed":
            assert limit is None, name
            continue
        if kind == "floating":
            assert name == "root_joint" and export.robot.root == "free" and limit is None
            continue
        effort, velocity = float(limit.get("effort")), float(limit.get("velocity"))
        assert math.isfinite(effort) and effort > 0 and math.isfinite(velocity) and velocity > 0, name
        spec_limits = spec_joints[name].limits
        if spec_limits is None:
            assert kind == "continuous" and limit.get("lower") is None and limit.get("upper") is None, name
        else:
            assert kind == "revolute", name
            lower, upper = float(limit.get("lower")), float(limit.get("upper"))
            assert (lower, upper) == pytest.approx(tuple(math.radians(a) for a in spec_limits), abs=1e-13)


def test_geometry_names_are_distinct_and_the_collision_comes_first(export):
    names = []
    for link in export.xml.iter("link"):
        tags = [e.tag for e in link if e.tag in ("collision", "visual")]
        if not tags:
            continue
        assert tags == ["collision", "visual", "visual"], link.get("name")
        assert all(v.get("name") is None for v in link.iter("visual"))  # urdf_parser_py warns of names there
        names += [c.get("name") for c in link.iter("collision")]
    assert len(names) == len(set(names)) == len(export.robot.bodies)


def test_pinocchio_alone_loads_the_export_with_the_same_joints_and_poses(export):
    robot = export.robot
    model = pin.buildModelFromUrdf(str(export.urdf))  # what a user does: no free flyer passed
    assert tuple(model.names[1:]) == robot.joint_names
    for jid in range(1, model.njoints):
        ours = robot.model.joints[jid]
        if model.names[jid] == "root_joint":
            assert model.joints[jid].shortname() == "JointModelFreeFlyer"
        else:  # continuous: (cos, sin) in Pinocchio's parser, one angle in kms2pin's model
            limited = np.isfinite(robot.lower_limits[ours.idx_q])
            assert model.joints[jid].nq == (1 if limited else 2)
    data = model.createData()
    rng = np.random.default_rng(0)
    for q in [srdf_rest(export.srdf, robot), *(random_q(robot, rng) for _ in range(5))]:
        pin.framesForwardKinematics(model, data, pinocchio_q(model, robot, q))
        robot.forward(q)
        for body in robot.bodies:
            theirs = data.oMf[model.getFrameId(body, pin.FrameType.BODY)]
            np.testing.assert_allclose(theirs.homogeneous, body_frame(robot, body).homogeneous, atol=TOL, err_msg=body)
    # the SRDF's rest state, free root included, is kms2pin's rest pose
    np.testing.assert_allclose(srdf_rest(export.srdf, robot), robot.q_rest, atol=1e-14)
    visuals = pin.buildGeomFromUrdf(model, str(export.urdf), pin.GeometryType.VISUAL, package_dirs=[str(export.out)])
    collisions = pin.buildGeomFromUrdf(model, str(export.urdf), pin.GeometryType.COLLISION,
                                       package_dirs=[str(export.out)])
    assert (visuals.ngeoms, collisions.ngeoms) == (2 * len(robot.bodies), len(robot.bodies))


def test_mujoco_loads_the_export_with_the_same_joints_and_poses(export):
    robot = export.robot
    m = mujoco.MjModel.from_xml_path(str(export.urdf))
    names = [m.joint(i).name for i in range(m.njnt)]
    assert names == list(robot.joint_names)
    spec_joints = {j.name: j for j in robot.system.joints}
    for i, name in enumerate(names):
        if name == "root_joint":  # the floating root is free, not welded
            assert m.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE
            continue
        assert m.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE
        limits = spec_joints[name].limits
        assert bool(m.jnt_limited[i]) == (limits is not None), name  # no nominal +-pi any more
        if limits is not None:
            np.testing.assert_allclose(m.jnt_range[i], np.radians(limits), atol=1e-12)
    geoms = {m.geom(i).name: i for i in range(m.ngeom)}
    assert sorted(geoms) == sorted(f"{b}_collision" for b in robot.bodies)  # distinct names, visuals dropped
    for i in geoms.values():  # not the outer ellipsoid's translucent colour
        assert m.geom_rgba[i][3] == 1.0 and tuple(m.geom_rgba[i]) != pytest.approx(OUTER_RGBA)
    kept = [b for b in robot.bodies if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) >= 0]
    assert robot.bodies[0] in kept  # bodies on fixed joints may be fused into their parents
    rng = np.random.default_rng(1)
    for q in [robot.q_rest, *(random_q(robot, rng) for _ in range(5))]:
        d = mujoco_kinematics(m, mujoco_qpos(m, robot, q))
        robot.forward(q)
        for body in kept:
            M = body_frame(robot, body)
            np.testing.assert_allclose(d.body(body).xpos, M.translation, atol=TOL, err_msg=body)
            np.testing.assert_allclose(d.body(body).xmat.reshape(3, 3), M.rotation, atol=TOL, err_msg=body)
        for body, pose in zip(robot.bodies, robot.body_poses(q)):
            # MuJoCo moves a mesh geom to the mesh's centroid: that of the unit sphere's OBJ, 0 to its 9 digits
            np.testing.assert_allclose(d.geom(f"{body}_collision").xpos, pose.translation, atol=1e-7, err_msg=body)


def test_a_free_root_is_a_floating_joint_from_world_and_a_virtual_joint_with_its_rest_placement(tmp_path):
    spec = ALL_SPECS[0]
    export = Export(spec, "free", tmp_path)
    floating = [j for j in export.xml.iter("joint") if j.get("type") == "floating"]
    assert len(floating) == 1 and floating[0].get("name") == "root_joint"
    assert floating[0].find("parent").get("link") == "world"
    assert floating[0].find("child").get("link") == export.robot.bodies[0]
    srdf = ET.parse(export.srdf).getroot()
    (virtual,) = srdf.iter("virtual_joint")
    assert virtual.attrib == {"name": "root_joint", "type": "floating", "parent_frame": "world",
                              "child_link": export.robot.bodies[0]}
    rest = {j.get("name"): j.get("value") for j in srdf.find("group_state[@name='rest']")}
    placement = np.array(rest["root_joint"].split(), dtype=float)  # x y z qx qy qz qw
    M = pin.XYZQUATToSE3(placement)
    spec_robot = kms2pin.load(spec)  # the spec's own root joint at rest places the root link there
    spec_robot.forward(spec_robot.q_rest)
    np.testing.assert_allclose(M.homogeneous, body_frame(spec_robot, export.robot.bodies[0]).homogeneous, atol=1e-13)


def test_a_joint_already_called_root_joint_is_refused_with_a_free_root(tmp_path, capsys):
    """Body 'root' with bound vector 'joint' makes a joint 'root_joint', the free root's name:
    two joints of one name would be an ill-formed URDF and an ambiguous SRDF rest state."""
    spec = tmp_path / "rj.kms"
    spec.write_text("""
        bvec o { pos(0, 0, 0); orient(1, 0, 0); }
        rigidBodySystem s {
            ellipsoidBody a { innerLam(0.1, 0.1, 0.3); outerLam(0.2, 0.2, 0.4);
                              bvec top { pos(0, 0, 0.3); orient(1, 0, 0); }
                              bvec tip { pos(0, 0, -0.3); orient(1, 0, 0); } }
            ellipsoidBody root { innerLam(0.1, 0.1, 0.3); outerLam(0.2, 0.2, 0.4);
                                 bvec joint { pos(0, 0, 0.3); orient(1, 0, 0); } }
            constraint revolute(a.tip, root.joint, 10);
        }
        constraint revolute(s.a.top, o);
    """)
    for fmt in ("urdf", "mjcf"):
        assert main(["export", str(spec), "-o", str(tmp_path / fmt), "--root", "free", "--format", fmt]) == 1
        assert "'s' has a joint called 'root_joint' (body 'root')" in capsys.readouterr().err
        assert not (tmp_path / fmt).exists()
    assert main(["export", str(spec), "-o", str(tmp_path / "spec")]) == 0
