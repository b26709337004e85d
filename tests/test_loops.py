"""Kinematic loops (issue 33): the spanning-tree rule, the closures as constraints (their
rows, Jacobians and curvature against finite differences taken with ``pin.integrate``),
the projection, the static update on the closed configurations (against the SymPy
reference and SciPy's SLSQP), the exports (URDF side file, MuJoCo's own residual) and the
motions, tracking and viewing of a closed chain."""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from conftest import SPECS, require_kernels
from scipy.optimize import minimize

import kms2pin
from kms2pin import native, reference
from kms2pin.cli import main
from kms2pin.closures import ROWS, column_order
from kms2pin.ecm.motions import make_motion
from kms2pin.mjcf import to_mjcf
from kms2pin.viewer.pose import parse_pose
from kms2pin.virtual_work import perturbed_targets, pose_spring_update, static_update

LOOP_SPECS = ("fourbar", "delta", "stewart")
KINDS = ("spherical", "revolute", "prismatic", "fixed")


def kinds_spec(kind: str) -> str:
    """A triangle a - b, a - c, b - c under a ball joint to the inertial frame: breadth first
    the b - c joint, of type ``kind``, closes the loop.  b and c are alike and hang from the
    same point of a, so at rest they coincide and the closure holds; c's revolute joint
    turns it, and b's ball joint follows."""
    return f"""
ellipsoidBody B() {{ innerLam(0.1, 0.1, 0.3); outerLam(0.12, 0.12, 0.36);
    bvec top {{ pos(0, 0, 0.3); orient(0, 0, 1); }}
    bvec bot {{ pos(0, 0, -0.3); orient(1, 0, 0); }}
    bvec x {{ pos(0.05, 0.1, -0.2); orient(1, 2, 3); }} }}
bvec o {{ pos(0, 0, 3); orient(0, 0, 1); }}
rigidBodySystem s {{
    B a(); B b(); B c();
    constraint spherical(a.bot, b.top);
    constraint revolute(a.bot, c.top);
    constraint {kind}(c.x, b.x);
}}
constraint spherical(o, s.a.top);
"""


def load(name: str, root: str = "spec") -> kms2pin.Robot:
    if name in KINDS:
        return kms2pin.load(kms2pin.parse_text(kinds_spec(name), f"{name}.kms"), root=root)
    return kms2pin.load(SPECS / f"{name}.kms", root=root)


def residual_rows(robot, q, public: bool = True) -> np.ndarray:
    C = robot._closures
    pin.computeJointJacobians(robot.model, robot.data, q)
    return C.residual(robot.model, robot.data) if public else C.system(robot.model, robot.data)[0]


def jacobian(robot, q, public: bool = True) -> np.ndarray:
    C = robot._closures
    pin.computeJointJacobians(robot.model, robot.data, q)
    return C.jacobian(robot.model, robot.data) if public else C.system(robot.model, robot.data, 1)[1]


def tangent_fd(f, robot, q, eps=1e-6) -> np.ndarray:
    """Central differences of ``f`` along each tangent direction (``pin.integrate``), as columns."""
    cols = [(f(pin.integrate(robot.model, q, eps * e)) - f(pin.integrate(robot.model, q, -eps * e))) / (2 * eps)
            for e in np.eye(robot.nv)]
    return np.array(cols).T


# ---------------------------------------------------------------------- the language and the model
TREE_RULE = """
ellipsoidBody B() { innerLam(0.1, 0.1, 0.2); outerLam(0.12, 0.12, 0.24);
    bvec p { pos(0, 0, 0.2); orient(0, 0, 1); } bvec q { pos(0, 0, -0.2); orient(0, 0, 1); } }
bvec o { pos(0, 0, 3); orient(0, 0, 1); }
rigidBodySystem s {
    B a(); B b(); B c();
    constraint revolute(a.q, b.p);
    constraint revolute(b.q, c.p);
    constraint revolute(a.p, c.q);
}
constraint revolute(o, s.a.p);
"""


def test_the_spanning_tree_is_breadth_first_with_each_bodys_joints_in_source_order():
    # depth first, a -> b -> c would be the tree; breadth first, a's two joints come first
    s = kms2pin.parse_text(TREE_RULE).system()
    assert [(j.parent, j.child) for j in s.joints] == [(None, "a"), ("a", "b"), ("a", "c")]
    (closure,) = s.closures
    assert (closure.kind, closure.parent, closure.child) == ("revolute", "b", "c")
    assert (closure.parent_bvec.qualified_name, closure.child_bvec.qualified_name) == ("b.q", "c.p")
    bodies, joints = s.loop(closure)
    assert bodies == ["b", "a", "c"] and [j.child for j in joints] == ["b", "c"]


def test_a_closures_parent_is_the_body_of_its_first_argument():
    swapped = TREE_RULE.replace("constraint revolute(b.q, c.p);", "constraint revolute(c.p, b.q);")
    (closure,) = kms2pin.parse_text(swapped).system().closures
    assert (closure.parent, closure.child) == ("c", "b")
    assert (closure.parent_bvec.qualified_name, closure.child_bvec.qualified_name) == ("c.p", "b.q")


def test_a_joint_to_the_inertial_frame_is_a_tree_joint_the_loop_closes_elsewhere():
    """The inertial frame's joints are taken first: a second anchor makes c a child of the
    inertial frame, and the joint from a to c closes the loop through it."""
    text = TREE_RULE + "bvec o2 { pos(0.3, 0, 2.5); orient(0, 0, 1); }\nconstraint spherical(s.c.q, o2);\n"
    s = kms2pin.parse_text(text).system()
    assert [(j.parent, j.child, j.kind) for j in s.joints] == [(None, "a", "revolute"), ("a", "b", "revolute"),
                                                               (None, "c", "spherical")]
    assert [(j.parent, j.child) for j in s.closures] == [("b", "c"), ("a", "c")]
    assert s.loop(s.closures[1])[0] == ["a", None, "c"]


def test_the_thesis_models_and_ours_have_no_loops():
    for path in SPECS.rglob("*.kms"):
        spec = kms2pin.parse(path)
        assert all(bool(s.closures) == (path.stem in LOOP_SPECS) for s in spec.systems), path


def test_check_prints_the_tree_each_closure_and_its_loop(capsys):
    assert main(["check", str(SPECS / "fourbar.kms")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith("3 bodies, 1 degree of freedom with its 1 loop closed (3 in its tree: 3 revolute, "
                           "0 fixed joints; 1 loop closure)")
    assert out[-2:] == ["loop closures:", "└─ rockerLink_tip  [revolute, couplerLink.tip -> rockerLink.tip] closes "
                        "couplerLink -> crankLink -> inertial frame -> rockerLink -> couplerLink"]
    assert main(["check", "--json", str(SPECS / "delta.kms")]) == 0
    (system,) = json.loads(capsys.readouterr().out)["systems"]
    assert system["mobility"] == 9 and system["dof"] == 24 and len(system["closures"]) == 5
    first = system["closures"][0]
    assert first["loop"] == ["rodB0", "arm0", "rodA0", "platform"] and first["type"] == "spherical"
    assert first["loop_joints"] == ["rodB0_top", "rodA0_top", "platform_ballA0"]


# ---------------------------------------------------------------------- the closures in Pinocchio
@pytest.mark.parametrize("kind", KINDS)
def test_every_joint_type_may_close_a_loop_and_closes_at_rest(kind):
    robot = load(kind)
    (closure,) = robot.closures
    assert closure.kind == kind and closure.name == "b_x" and (closure.parent, closure.child) == ("c", "b")
    assert residual_rows(robot, robot.q_rest).shape == (ROWS[kind],)
    assert robot.closure_residual(robot.q_rest).max() < 1e-12
    fids = [robot.model.getFrameId(f"b_x_{side}") for side in ("parent", "child")]
    robot.forward(robot.q_rest)
    assert robot.data.oMf[fids[0]].isApprox(robot.data.oMf[fids[1]], 1e-12)  # the two frames coincide at rest
    q = pin.integrate(robot.model, robot.q_rest, np.full(robot.nv, 0.1))
    assert robot.closure_residual(q).max() > 1e-3


@pytest.mark.parametrize("root", ["spec", "free"])
@pytest.mark.parametrize("kind", KINDS)
def test_closure_jacobians_match_finite_differences_taken_with_pin_integrate(kind, root):
    robot = load(kind, root)
    rng = np.random.default_rng(KINDS.index(kind))
    q = robot.random_configuration(rng, 30.0)
    if root == "free":
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3.Random())
    if kind != "fixed":  # off the closed configurations; Pinocchio's 6-D Jacobian is -log6's where it holds
        q = pin.integrate(robot.model, q, rng.normal(0, 0.1, robot.nv))
    for public in (True, False):
        J = jacobian(robot, q, public)
        fd = tangent_fd(lambda x: residual_rows(robot, x, public), robot, q)
        np.testing.assert_allclose(J, fd, atol=1e-8)


@pytest.mark.parametrize("kind", ["spherical", "fixed"])
def test_the_kernel_rows_of_spherical_and_fixed_closures_are_pinocchios_where_they_hold(kind):
    robot = load(kind)
    q = robot.random_configuration(np.random.default_rng(3), 40.0)
    assert robot.closure_residual(q).max() < 1e-9
    np.testing.assert_allclose(jacobian(robot, q, False), jacobian(robot, q, True), atol=1e-10)
    off = pin.integrate(robot.model, q, np.random.default_rng(4).normal(0, 0.2, robot.nv))
    if kind == "spherical":  # the gap p1 - p2 everywhere
        np.testing.assert_allclose(residual_rows(robot, off, False), residual_rows(robot, off, True), atol=1e-14)
        np.testing.assert_allclose(jacobian(robot, off, False), jacobian(robot, off, True), atol=1e-12)


@pytest.mark.parametrize("backend", ["c", "numpy"])
@pytest.mark.parametrize("kind", KINDS)
def test_closure_curvature_is_the_symmetrised_derivative_of_the_jacobian(kind, backend):
    """Σ λ ∇²r (the constraints' part of the Lagrangian's Hessian) against central differences
    of λᵀ J along pin.integrate, symmetrised (the tangent chart's Hessian); a fixed closure's
    along the closed configurations only, where its kernel rows agree with -log6."""
    if backend == "c":
        require_kernels()
    robot = load(kind, "free")
    rng = np.random.default_rng(10 + KINDS.index(kind))
    q = robot.random_configuration(rng, 30.0)
    q[:7] = pin.SE3ToXYZQUAT(pin.SE3.Random())
    lam = rng.normal(size=robot._closures.rows)
    with native.use(backend):
        pin.computeJointJacobians(robot.model, robot.data, q)
        H = robot._closures.curvature(robot.model, robot.data, lam, column_order(robot.model))
        fd = tangent_fd(lambda x: lam @ jacobian(robot, x, kind != "fixed"), robot, q).T
    fd = 0.5 * (fd + fd.T)
    if kind == "fixed":
        sig_J = jacobian(robot, q)
        N = np.linalg.svd(sig_J)[2][np.linalg.matrix_rank(sig_J, 1e-9):].T
        H, fd = N.T @ H @ N, N.T @ fd @ N
    np.testing.assert_allclose(H, fd, atol=1e-7)


def test_project_is_the_least_norm_correction_to_first_order():
    """Against SLSQP: min |dq|² with the closures holding at pin.integrate(q, dq)."""
    robot = load("delta")
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = pin.integrate(robot.model, robot.random_configuration(rng, 30.0), rng.normal(0, 1e-3, robot.nv))
        closed = robot.project(q)
        assert robot.closure_residual(closed).max() < 1e-12
        dq = pin.difference(robot.model, q, closed)

        def rows(x, q=q):
            return residual_rows(robot, pin.integrate(robot.model, q, x))

        best = minimize(lambda x: x @ x, np.zeros(robot.nv), jac=lambda x: 2 * x, method="SLSQP",
                        constraints=[{"type": "eq", "fun": rows}], options={"ftol": 1e-16, "maxiter": 200})
        assert np.abs(rows(best.x)).max() < 1e-9
        assert np.linalg.norm(dq - best.x) < 1e-2 * np.linalg.norm(best.x)
        assert dq @ dq <= best.x @ best.x * (1 + 1e-4)


def test_project_holds_the_given_joints_and_refuses_a_pose_it_cannot_close():
    robot = load("fourbar")
    q = robot.with_coordinates(robot.q_rest, {"crankLink_base": 70.0})
    closed = robot.project(q, hold=[0])
    assert closed[0] == q[0] and robot.closure_residual(closed).max() < 1e-12
    assert closed[2] != pytest.approx(robot.q_rest[2])  # the rocker followed
    gantry_like = robot.with_coordinates(robot.q_rest, {"couplerLink_base": 179.0})
    with pytest.raises(kms2pin.RobotError, match="cannot be closed from this configuration"):
        robot.project(gantry_like, hold=[0, 1])


def test_q_rest_is_the_spec_rest_pose_projected():
    text = (SPECS / "fourbar.kms").read_text().replace("double crankAngle = 60;", "double crankAngle = 60;\n"
                                                        "double nudge = 3;").replace(
        "constraint revolute(rockerPivot, fourbar.rockerLink.base, rockerAngle);",
        "constraint revolute(rockerPivot, fourbar.rockerLink.base, rockerAngle + nudge);")
    robot = kms2pin.load(kms2pin.parse_text(text, "fourbar.kms"))
    spec_rest = np.radians([60.0, robot.system.joints[1].default_angle, robot.system.joints[2].default_angle])
    assert robot.closure_residual(robot.q_rest).max() < 1e-12
    assert np.abs(robot.q_rest - spec_rest).max() < np.radians(3)
    np.testing.assert_allclose(robot.q_rest, robot.project(spec_rest), atol=1e-14)
    assert robot.model.referenceConfigurations["rest"] == pytest.approx(robot.q_rest)


def test_the_mechanisms_degrees_of_freedom():
    """The textbook mobilities: a four-bar 1; a Delta robot 3 and each of its six rods' spin
    about its ball-to-ball axis; a Stewart platform 6 and each leg's spin."""
    assert [load(n).mobility for n in LOOP_SPECS] == [1, 3 + 6, 6 + 6]
    assert load("puma600").mobility == load("puma600").nv


@pytest.mark.parametrize("name", LOOP_SPECS)
def test_random_configurations_and_motions_keep_the_closures(name):
    robot = load(name)
    rng = np.random.default_rng(1)
    for _ in range(5):
        assert robot.closure_residual(robot.random_configuration(rng, 90.0)).max() < 1e-9
    q = make_motion(robot, "random", 40, rng)
    assert max(robot.closure_residual(x).max() for x in q) < 1e-9
    steps = [np.abs(pin.difference(robot.model, a, b)).max() for a, b in zip(q[:-1], q[1:])]
    assert 0 < max(steps) < 0.2 and np.abs(pin.difference(robot.model, q[0], q[-1])).max() > 0.05
    np.testing.assert_allclose(q[0], robot.q_rest, atol=1e-12)


# ---------------------------------------------------------------------- the static update
def updates(robot, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q0 = robot.random_configuration(rng, 90.0)
        yield q0, perturbed_targets(robot, q0, rng)


def stewart_without_limits() -> kms2pin.Robot:
    text = (SPECS / "stewart.kms").read_text().replace(", 0.05, 0.45);", ");")
    return kms2pin.load(kms2pin.parse_text(text, "stewart.kms"))


@pytest.mark.parametrize("name", ["fourbar", "delta", "stewart-no-limits"])
def test_fast_path_and_reference_reach_the_same_equilibrium(name):
    """The SymPy reference in maximal coordinates with the closures' rows of eq. 2.13-2.15
    (the thesis's formulation, without joint limits)."""
    robot = stewart_without_limits() if name == "stewart-no-limits" else load(name)
    sym = reference.symbolic_model(robot.system)
    assert sym.dof == robot.mobility
    for q0, t in updates(robot, 2):
        fast = static_update(robot, q0, t)
        ref = reference.solve_equilibrium(robot.system, robot.maximal_coordinates(q0), t, 1.0, model=sym)
        assert fast.converged and ref.converged
        assert robot.closure_residual(fast.q).max() < 1e-9
        assert fast.energy == pytest.approx(ref.energy, rel=1e-9)
        np.testing.assert_allclose(robot.maximal_coordinates(fast.q), ref.q, atol=1e-7)
        assert np.abs(sym.C(robot.maximal_coordinates(fast.q))).max() < 1e-9


def test_codegen_writes_the_closures_rows(tmp_path):
    """The generated C(q) (thesis §3.2.2) has the closure's rows, vanishes where the loop is
    closed and counts the mechanism's degrees of freedom."""
    import importlib.util

    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["codegen", str(SPECS / "fourbar.kms"), "--lang", "python", "-o", str(tmp_path)]) == 0
    spec = importlib.util.spec_from_file_location("fourbar_constraints", tmp_path / "fourbar_constraints.py")
    generated = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generated)
    robot = load("fourbar")
    assert generated.DOF == robot.mobility == 1
    assert [lab for lab in generated.LABELS if lab.startswith("rockerLink_tip")] == [
        f"rockerLink_tip {what} {a}" for what in ("position", "axis") for a in "xyz"]
    q = robot.random_configuration(np.random.default_rng(0), 60.0)
    assert np.abs(generated.kms_constraints(robot.maximal_coordinates(q).ravel())).max() < 1e-12
    opened = robot.with_coordinates(q, {"crankLink_base": math.degrees(q[0]) + 10})
    assert np.abs(generated.kms_constraints(robot.maximal_coordinates(opened).ravel())).max() > 1e-3


def slsqp_energy(robot, q0, targets, start) -> float:
    """An independent constrained optimizer: SciPy's SLSQP on the spring energy over the
    joint coordinates (tangent space at ``start``), the closures' rows as equality
    constraints and the joint limits as bounds; its energy where the closures hold."""
    k = np.ones((len(robot.bodies), 7))

    def energy(x):
        qm = robot.maximal_coordinates(pin.integrate(robot.model, start, x))
        t = targets.copy()
        t[np.sum(t[:, 3:] * qm[:, 3:], axis=1) < 0, 3:] *= -1
        return 0.5 * float(np.sum(k * (qm - t) ** 2))

    lo, hi = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
    for j in robot.joints:
        if j.nq == 1 and np.isfinite(robot.lower_limits[j.idx_q]):
            lo[j.idx_v] = robot.lower_limits[j.idx_q] - start[j.idx_q]
            hi[j.idx_v] = robot.upper_limits[j.idx_q] - start[j.idx_q]
    res = minimize(energy, np.zeros(robot.nv), method="SLSQP", bounds=list(zip(lo, hi)),
                   constraints=[{"type": "eq", "fun": lambda x: residual_rows(robot, pin.integrate(robot.model, start, x))}],
                   options={"ftol": 1e-14, "maxiter": 500})
    q = pin.integrate(robot.model, start, res.x)
    return energy(res.x) if robot.closure_residual(q).max() < 1e-6 else np.inf


@pytest.mark.slow
@pytest.mark.parametrize("name", LOOP_SPECS)
def test_the_equilibrium_is_no_higher_than_slsqps_from_several_starts(name):
    robot = load(name)
    rng = np.random.default_rng(7)
    for q0, t in updates(robot, 2, seed=7):
        fast = static_update(robot, q0, t)
        assert fast.converged and robot.closure_residual(fast.q).max() < 1e-9
        assert np.all(fast.q >= robot.lower_limits - 1e-12) and np.all(fast.q <= robot.upper_limits + 1e-12)
        starts = [q0, robot.q_rest, robot.random_configuration(rng, 30.0)]
        best = min(slsqp_energy(robot, q0, t, s) for s in starts)
        assert np.isfinite(best)
        assert fast.energy <= best + 1e-9 * max(1.0, best)


@pytest.mark.parametrize("name", ["delta", "fourbar"])
def test_c_and_numpy_kernels_give_the_same_closed_update(name):
    require_kernels()
    robot = load(name)
    for q0, t in updates(robot, 2, seed=2):
        with native.use("c"):
            a = static_update(robot, q0, t)
        with native.use("numpy"):
            b = static_update(robot, q0, t)
        assert a.iterations == b.iterations and a.energy == pytest.approx(b.energy, rel=1e-12)
        np.testing.assert_allclose(a.q, b.q, atol=1e-9)


def test_the_stewart_platforms_legs_stay_within_their_stroke():
    robot = load("stewart")
    lo, hi = robot.lower_limits, robot.upper_limits
    held = 0
    for q0, t in updates(robot, 6, seed=3):
        t[-1, :3] += [0.0, 0.4, 0.0]  # the platform pulled far up, hard: legs at their longest
        k = np.ones(len(robot.bodies))
        k[-1] = 100.0
        res = static_update(robot, q0, t, k)
        assert res.converged and robot.closure_residual(res.q).max() < 1e-9
        assert np.all(res.q >= lo - 1e-12) and np.all(res.q <= hi + 1e-12)
        held += int(np.sum(np.isclose(res.q, hi, atol=1e-9) & np.isfinite(hi)))
    assert held > 0


def test_the_trackers_static_update_keeps_the_closures_and_lowers_the_energy():
    robot = load("delta")
    rng = np.random.default_rng(8)
    for _ in range(3):
        truth = robot.random_configuration(rng, 40.0)
        targets = np.array([pin.SE3ToXYZQUAT(M) for M in robot.body_poses(truth)])
        K = np.repeat(np.eye(6)[None], len(targets), axis=0)
        start = pin.integrate(robot.model, truth, rng.normal(0, 0.05, robot.nv))  # near it, the loops open
        assert robot.closure_residual(start).max() > 1e-3
        one = pose_spring_update(robot, start, targets, K, iterations=1)
        q = pose_spring_update(robot, start, targets, K, iterations=20)
        assert robot.closure_residual(one).max() < 1e-9 and robot.closure_residual(q).max() < 1e-9
        projected = robot.project(start)
        errors = [sum(float(np.sum(pin.log6(M.actInv(N)).vector ** 2)) for M, N in
                      zip(robot.body_poses(x), robot.body_poses(truth))) for x in (projected, one, q)]
        assert errors[2] < errors[1] < errors[0]
        np.testing.assert_allclose(robot.body_poses(q)[-1].translation, robot.body_poses(truth)[-1].translation,
                                   atol=1e-9)  # consistent targets: the truth's platform found


# ---------------------------------------------------------------------- export
def closure_frames(doc: dict, model: pin.Model, data: pin.Data) -> list[tuple[dict, pin.SE3, pin.SE3]]:
    """Each closure of the side file and its two frames' world placements in ``data``."""
    out = []
    for c in doc["closures"]:
        ends = []
        for link, frame in ((c["parent_link"], c["parent_frame"]), (c["child_link"], c["child_frame"])):
            placement = pin.SE3(pin.rpy.rpyToMatrix(*frame["rpy"]), np.array(frame["xyz"]))
            ends.append(data.oMf[model.getFrameId(link)] * placement)
        out.append((c, *ends))
    return out


@pytest.mark.parametrize("name", [*LOOP_SPECS, *KINDS])
def test_the_urdf_is_the_spanning_tree_and_the_side_file_closes_at_the_srdfs_rest_state(name, tmp_path):
    """Read back independently: Pinocchio's own URDF parser, the SRDF's rest state, the
    closures' frames from the JSON file, and each closure's condition checked."""
    robot = load(name)
    spec = tmp_path / f"{name}.kms"
    spec.write_text(kinds_spec(name) if name in KINDS else (SPECS / f"{name}.kms").read_text())
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["export", str(spec), "-o", str(tmp_path / "out")]) == 0
    base = tmp_path / "out" / robot.system.name
    urdf, doc = base.with_suffix(".urdf").read_text(), json.loads(base.with_suffix(".closures.json").read_text())
    assert "kinematic loops, which URDF cannot express: this is its spanning tree" in urdf
    assert [c["name"] for c in doc["closures"]] == [j.name for j in robot.closures]
    model = pin.buildModelFromXML(urdf)
    data = model.createData()
    rest = {j.get("name"): float(j.get("value"))
            for j in ET.parse(base.with_suffix(".srdf")).getroot().iter("joint") if j.get("value")}
    q = pin.neutral(model)
    for jid in range(1, model.njoints):
        j, value = model.joints[jid], rest[model.names[jid]]
        q[j.idx_q : j.idx_q + j.nq] = [math.cos(value), math.sin(value)] if j.nq == 2 else [value]
    pin.framesForwardKinematics(model, data, q)
    for c, M1, M2 in closure_frames(doc, model, data):
        axis1, axis2 = M1.rotation @ c["axis"], M2.rotation @ c["axis"]
        gap = M2.translation - M1.translation
        if c["type"] == "prismatic":
            gap -= (gap @ axis1) * axis1
        assert np.linalg.norm(gap) < 1e-9, c["name"]
        if c["type"] == "revolute":
            assert np.linalg.norm(axis1 - axis2) < 1e-9
        if c["type"] in ("fixed", "prismatic"):
            assert np.abs(M1.rotation - M2.rotation).max() < 1e-9


def mujoco_model(robot):
    import mujoco  # a test dependency: a broken install fails here, not skips
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        xml = to_mjcf(robot.system, "x.kms", rest=robot.joint_blocks(robot.q_rest))
    return mujoco, mujoco.MjModel.from_xml_string(xml)


def equality_residual(mujoco, m, d) -> float:
    mujoco.mj_forward(m, d)
    rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    return float(np.abs(d.efc_pos[rows]).max())


@pytest.mark.parametrize("name", [*LOOP_SPECS, "spherical", "revolute", "fixed"])
def test_mujocos_constraint_residual_at_the_rest_keyframe_is_below_1e_6(name):
    from _interop import mujoco_qpos

    robot = load(name)
    mujoco, m = mujoco_model(robot)
    assert m.neq == sum(2 if j.kind == "revolute" else 1 for j in robot.closures)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("rest").id)
    assert equality_residual(mujoco, m, d) < 1e-6
    # and at another closed configuration: the sites coincide, not a pose relative to qpos0
    q = robot.random_configuration(np.random.default_rng(2), 40.0)
    d.qpos[:] = mujoco_qpos(m, robot, q)
    assert equality_residual(mujoco, m, d) < 1e-6
    d.qpos[:] = mujoco_qpos(m, robot, pin.integrate(robot.model, q, np.full(robot.nv, 0.05)))
    assert equality_residual(mujoco, m, d) > 1e-4


def test_a_prismatic_closure_is_left_out_of_the_mjcf_with_a_comment_and_a_warning(tmp_path, capsys):
    robot = load("prismatic")
    with pytest.warns(UserWarning, match="loop closure 'b_x' .c -> b. is prismatic: MuJoCo has no equality"):
        xml = to_mjcf(robot.system, "prismatic.kms", rest=robot.joint_blocks(robot.q_rest))
    assert "<!-- loop closure 'b_x' (c -> b) is prismatic" in xml and "<equality>" not in xml
    spec = tmp_path / "prismatic.kms"
    spec.write_text(kinds_spec("prismatic"))
    assert main(["export", str(spec), "--format", "mjcf", "-o", str(tmp_path / "m")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("kms2pin export: warning: s.xml: loop closure 'b_x' (c -> b) is prismatic")


# ---------------------------------------------------------------------- viewing and tracking
def test_a_slider_moves_its_joint_and_the_closing_joints_follow():
    robot = load("fourbar")
    q = robot.q_rest
    rockers = []
    for crank in range(60, 421, 30):  # a full turn of the driven crank, as a user drags the slider
        q = parse_pose(robot, f"crankLink_base={crank % 360 - (360 if crank % 360 > 180 else 0)}", q)
        assert robot.closure_residual(q).max() < 1e-12
        assert math.degrees(q[0]) == pytest.approx(crank % 360 - (360 if crank % 360 > 180 else 0))
        rockers.append(math.degrees(q[2]))
    assert max(rockers) - min(rockers) > 30  # the rocker swings ...
    assert rockers[-1] == pytest.approx(math.degrees(robot.q_rest[2]), abs=1e-6)  # ... and comes back


@pytest.mark.slow
def test_synth_renders_a_moving_loop_mechanism(tmp_path):
    from PIL import Image

    out = tmp_path / "synth"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["synth", str(SPECS / "fourbar.kms"), "--root", "spec", "--motion", "random", "--frames", "12",
                     "-o", str(out)]) == 0
    masks = sorted(out.rglob("*.png"))
    assert len(masks) >= 12
    first, last = (np.asarray(Image.open(p)) > 0 for p in (masks[0], masks[len(masks) // 2 - 1]))
    assert first.any() and (first != last).any()
    robot = load("fourbar")
    truth = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    coords = np.array([[row[n] for n in robot.coordinate_names] for row in truth])
    assert max(robot.closure_residual(robot.configuration(c)).max() for c in coords) < 1e-6


@pytest.mark.slow
def test_the_tracker_keeps_the_delta_robots_closures_on_every_frame():
    from kms2pin.ecm import Camera, Tracker, synthesize

    robot = load("delta")
    rng = np.random.default_rng(0)
    truth = make_motion(robot, "random", 8, rng)
    target = robot.body_poses(robot.q_rest)[-1].translation
    cams = [Camera.default(), Camera.look_at(position=[1.5, 1.0, 0.5], target=target)]
    frames = [m for _, m in synthesize(robot, truth, cams, noise=0.05, rng=rng)]
    tracker = Tracker(robot, cams)
    for masks in frames:
        res = tracker.step(masks)
        assert robot.closure_residual(res.q).max() < 1e-6
