"""``kms2pin export --format mjcf``: every spec, with either root, compiles in MuJoCo as
written and puts every body where Pinocchio puts it (joints mapped by name)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
from _interop import EXPORT_CASES, SPECS, body_frame, mujoco_kinematics, mujoco_qpos, random_q

import kms2pin
from kms2pin.cli import main

CASES = EXPORT_CASES
TOL = 1e-9


class MjcfExport:
    """One ``export --format mjcf``: the file, MuJoCo's compiled model and kms2pin's robot."""

    def __init__(self, spec: Path, root: str, out: Path):
        assert main(["export", str(spec), "--format", "mjcf", "-o", str(out), "--root", root]) == 0
        self.robot = kms2pin.load(spec, root=root)
        self.path = out / f"{self.robot.system.name}.xml"
        self.model = mujoco.MjModel.from_xml_path(str(self.path))


@pytest.fixture(scope="module", params=CASES, ids=[f"{p.parent.name}/{p.stem}-{r}" for p, r in CASES])
def export(request, tmp_path_factory) -> MjcfExport:
    spec, root = request.param
    return MjcfExport(spec, root, tmp_path_factory.mktemp("mjcf"))


def test_body_frames_and_centre_sites_equal_pinocchios_at_random_configurations(export):
    robot, m = export.robot, export.model
    assert [m.body(i).name for i in range(1, m.nbody)] == list(robot.bodies)  # no body fused away
    rng = np.random.default_rng(2)
    for q in [robot.q_rest, *(random_q(robot, rng) for _ in range(8))]:
        d = mujoco_kinematics(m, mujoco_qpos(m, robot, q))
        robot.forward(q)
        for body in robot.bodies:
            M = body_frame(robot, body)
            np.testing.assert_allclose(d.body(body).xpos, M.translation, atol=TOL, err_msg=body)
            np.testing.assert_allclose(d.body(body).xmat.reshape(3, 3), M.rotation, atol=TOL, err_msg=body)
            C = robot.data.oMf[robot.model.getFrameId(f"{body}_centre")]
            np.testing.assert_allclose(d.site(f"{body}_centre").xpos, C.translation, atol=TOL, err_msg=body)
            np.testing.assert_allclose(d.site(f"{body}_centre").xmat.reshape(3, 3), C.rotation, atol=TOL)


def test_the_rest_keyframe_is_the_specs_rest_pose(export):
    robot, m = export.robot, export.model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("rest").id)
    np.testing.assert_allclose(d.qpos, mujoco_qpos(m, robot, robot.q_rest), atol=1e-14)
    if robot.root == "free":  # a free root's body sits at its rest placement, so qpos0 is rest too
        np.testing.assert_allclose(m.qpos0[:7], d.qpos[:7], atol=1e-14)


def test_joints_hinge_slide_or_ball_as_the_spec_moves_with_ranges_only_where_it_limits(export):
    """Revolute joints are hinges, prismatic ones slides, spherical ones balls (MuJoCo's
    tree order may differ from Pinocchio's: the joints are matched by name)."""
    robot, m = export.robot, export.model
    spec_joints = {j.name: j for j in robot.system.joints}
    assert sorted(m.joint(i).name for i in range(m.njnt)) == sorted(robot.joint_names)
    kinds = {"revolute": mujoco.mjtJoint.mjJNT_HINGE, "prismatic": mujoco.mjtJoint.mjJNT_SLIDE,
             "spherical": mujoco.mjtJoint.mjJNT_BALL}
    for i in range(m.njnt):
        name = m.joint(i).name
        if name == "root_joint":
            assert robot.root == "free" and m.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE
            continue
        joint = spec_joints[name]
        assert m.jnt_type[i] == kinds[joint.kind], name
        limits = None if joint.kind == "spherical" else joint.limits
        assert bool(m.jnt_limited[i]) == (limits is not None), name
        if limits is not None:
            expected = np.radians(limits) if joint.kind == "revolute" else np.asarray(limits)
            np.testing.assert_allclose(m.jnt_range[i], expected, atol=1e-14)


def test_inner_ellipsoids_collide_and_carry_a_solid_ellipsoids_mass_and_outer_ones_are_drawn_only(export):
    robot, m = export.robot, export.model
    for body in robot.bodies:
        inner, outer = m.geom(f"{body}_inner"), m.geom(f"{body}_outer")
        assert inner.type[0] == outer.type[0] == mujoco.mjtGeom.mjGEOM_ELLIPSOID
        np.testing.assert_allclose(inner.size, robot.inner(body), rtol=1e-15)
        np.testing.assert_allclose(outer.size, robot.outer(body), rtol=1e-15)
        assert (inner.contype[0], inner.conaffinity[0]) == (1, 1)
        assert (outer.contype[0], outer.conaffinity[0]) == (0, 0) and outer.group[0] != inner.group[0]
        a, b, c = robot.inner(body)  # a solid ellipsoid of density 1000 (kg/m^3)
        mass = 1000.0 * 4.0 / 3.0 * math.pi * a * b * c
        principal = mass / 5.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        k = m.body(body).id
        assert m.body_mass[k] == pytest.approx(mass, rel=1e-12)
        assert sorted(m.body_inertia[k]) == pytest.approx(sorted(principal), rel=1e-9)
        np.testing.assert_allclose(m.body_ipos[k], -np.asarray(robot.system.joint_of(body).child_bvec.pos), atol=1e-12)


def test_contact_exclusions_are_the_srdfs_and_gravity_points_down_y(export):
    robot, m = export.robot, export.model
    srdf = ET.fromstring(robot.srdf)
    expected = {frozenset((e.get("link1"), e.get("link2"))) for e in srdf.iter("disable_collisions")}
    excluded = {frozenset((m.body(int(p >> 16)).name, m.body(int(p & 0xFFFF)).name)) for p in m.exclude_signature}
    assert excluded == expected
    np.testing.assert_allclose(m.opt.gravity, [0.0, -9.81, 0.0])


def test_the_model_simulates(export):
    m = export.model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("rest").id)
    for _ in range(50):
        mujoco.mj_step(m, d)
    assert np.isfinite(d.qpos).all() and d.time == pytest.approx(50 * m.opt.timestep)


def test_export_mjcf_writes_only_the_xml_and_urdf_stays_the_default(tmp_path, capsys):
    spec = SPECS / "puma600.kms"
    assert main(["export", str(spec), "--format", "mjcf", "-o", str(tmp_path / "m")]) == 0
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["puma600.xml"]
    assert capsys.readouterr().out.split() == [str(tmp_path / "m" / "puma600.xml")]
    assert main(["export", str(spec), "-o", str(tmp_path / "u")]) == 0
    assert sorted(p.name for p in (tmp_path / "u").iterdir()) == ["meshes", "puma600.srdf", "puma600.urdf"]
    with pytest.raises(SystemExit) as exit_:
        main(["export", str(spec), "--format", "sdf", "-o", str(tmp_path / "s")])
    assert exit_.value.code == 2 and "invalid choice: 'sdf'" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_a_system_fixed_to_the_world_has_an_empty_rest_keyframe(tmp_path, capsys):
    spec = tmp_path / "still.kms"
    spec.write_text("""
        bvec o { pos(0, 1, 0); orient(0, 1, 0); }
        rigidBodySystem still {
            ellipsoidBody a { innerLam(0.1, 0.2, 0.3); outerLam(0.2, 0.3, 0.4);
                              bvec j { pos(0, 0, 0.1); orient(0, 1, 0); } }
        }
        constraint fixed(still.a.j, o);
    """)
    assert main(["export", str(spec), "--format", "mjcf", "-o", str(tmp_path)]) == 0
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "still.xml"))
    assert (m.nq, m.nkey) == (0, 1)
    d = mujoco_kinematics(m, np.zeros(0))
    np.testing.assert_allclose(d.site("a_centre").xpos, [0.0, 1.0, -0.1], atol=1e-15)
