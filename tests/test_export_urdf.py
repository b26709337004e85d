"""The exported URDF/SRDF of every spec, with either root, as other tools read them:
urdfdom's check_urdf, Pinocchio's own URDF and SRDF parsers (no kms2pin in between) and
MuJoCo's URDF importer, each compared with kms2pin's model at random configurations; a
spherical joint's three URDF joints against an independent X-Y-Z decomposition."""

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
    EXPORT_CASES,
    body_frame,
    check_urdf_exe,
    mujoco_kinematics,
    mujoco_qpos,
    pinocchio_q,
    random_q,
    urdf_joint_names,
)
from conftest import MIXED_JOINTS, SPECS

import kms2pin
from kms2pin.cli import main
from kms2pin.urdf import OUTER_RGBA

CASES = EXPORT_CASES
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
    angle per revolute joint (a spherical joint's three), an offset per prismatic joint, x y
    z qx qy qz qw for a free root (Pinocchio 4.1's own reader refuses one angle for a
    continuous joint whose axis is not x, y or z)."""
    state = ET.parse(srdf).getroot().find("group_state[@name='rest']")
    values = {j.get("name"): np.array(j.get("value").split(), dtype=float) for j in state.iter("joint")}
    q = pin.neutral(robot.model)
    if "root_joint" in values:
        q[:7] = values.pop("root_joint")
    kinds = {n: j.kind for j in robot.joints for n in j.names}
    coords = {n: float(v[0]) if kinds[n] == "prismatic" else math.degrees(float(v[0])) for n, v in values.items()}
    assert set(coords) == {n for n in robot.coordinate_names if kinds[n] != "free"}
    return robot.with_coordinates(q, coords)


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
    spec_joints |= {n: j for j in export.robot.joints if j.kind == "spherical" for n in j.names}
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
        if spec_joints[name].kind == "spherical":  # one of its three: unlimited
            assert kind == "continuous" and limit.get("lower") is None, name
            continue
        spec_limits = spec_joints[name].limits
        if spec_joints[name].kind == "prismatic":  # URDF wants a range: the spec's or nominal
            lower, upper = float(limit.get("lower")), float(limit.get("upper"))
            assert kind == "prismatic" and (lower, upper) == ((-1e6, 1e6) if spec_limits is None else spec_limits), name
            continue
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
    assert list(model.names[1:]) == urdf_joint_names(robot)
    types = {j.get("name"): j.get("type") for j in export.xml.iter("joint")}
    for jid in range(1, model.njoints):
        if model.names[jid] == "root_joint":
            assert model.joints[jid].shortname() == "JointModelFreeFlyer"
        else:  # continuous: (cos, sin) in Pinocchio's parser, one angle in kms2pin's model
            assert model.joints[jid].nq == (2 if types[model.names[jid]] == "continuous" else 1)
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
    assert sorted(names) == sorted(urdf_joint_names(robot))  # MuJoCo's tree order: matched by name
    spec_joints = {j.name: j for j in robot.system.joints}
    spherical = {n for j in robot.joints if j.kind == "spherical" for n in j.names}
    for i, name in enumerate(names):
        if name == "root_joint":  # the floating root is free, not welded
            assert m.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE
            continue
        if name in spherical:
            assert m.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE and not m.jnt_limited[i]
            continue
        if spec_joints[name].kind == "prismatic":
            assert m.jnt_type[i] == mujoco.mjtJoint.mjJNT_SLIDE and m.jnt_limited[i]
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
    # bodies on fixed joints may be fused into their parents (the gantry's rail into the world)
    assert robot.bodies[0] in kept or robot.system.joints[0].kind == "fixed"
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
        err = capsys.readouterr().err
        line = 1 + spec.read_text().splitlines().index("            constraint revolute(a.tip, root.joint, 10);")
        assert f"{spec}:{line}:13: error: this joint of 's' is called 'root_joint' (body 'root'), the name a " \
               "free root's joint takes; rename the body or its bound vector, or keep the spec's root" in err
        assert not (tmp_path / fmt).exists()
    assert main(["export", str(spec), "-o", str(tmp_path / "spec")]) == 0


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
            for axis, angle in zip("xyz", angles):  # continuous joints: (cos, sin)
                u = urdf_model.joints[urdf_model.getJointId(f"{name}_{axis}")]
                out[u.idx_q : u.idx_q + 2] = [np.cos(angle), np.sin(angle)]
        else:
            u = urdf_model.joints[urdf_model.getJointId(name)]
            out[u.idx_q : u.idx_q + u.nq] = block if u.nq == len(block) else [np.cos(block[0]), np.sin(block[0])]
    return out


@pytest.mark.parametrize("root", ["spec", "free"])
@pytest.mark.parametrize("name", ["human", "gantry", "mixed"])
def test_urdf_and_pinocchio_models_place_every_body_alike(name, root):
    """A spherical joint's three URDF continuous joints (Exp(r) = Rx Ry Rz) and the prismatic
    joints give the bodies the poses of the Pinocchio model kms2pin builds, at random
    configurations away from the gimbal singularity."""
    robot = kms2pin.load(kms2pin.parse(MIXED_JOINTS) if name == "mixed" else SPECS / f"{name}.kms", root=root)
    urdf_model = pin.buildModelFromXML(robot.urdf)  # a free root is the URDF's floating joint
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
