"""Loop closures (thesis §4.2): the joints that close kinematic loops, as constraints
between two frames of the Pinocchio model.

Each closure joins a frame on its parent body (the first argument's) to a frame on its
child body (the second argument's; the inertial frame for an inertial bvec):

* ``<closure>_parent``: the parent end's point a_ij with the parent body's axes;
* ``<closure>_child``: the child end's point a_ji with the axes R_0j R_alignᵀ (eq. 2.12),

so that a closed fixed joint makes the two frames coincide (eq. 2.13), and a closed
revolute one turns the child frame about the parent end's axis o_ij (eq. 2.16).  With
p, R the two frames' world placements (1 parent, 2 child), the residual rows
(:data:`ROWS` per closure; world axes unless said otherwise):

* spherical, 3: the gap p1 - p2, Pinocchio's ``RigidConstraintModel`` (CONTACT_3D,
  LOCAL_WORLD_ALIGNED);
* fixed, 6: -log6 of the child frame in the parent frame (parent frame axes), Pinocchio's
  ``RigidConstraintModel`` (CONTACT_6D, LOCAL);
* revolute, 5: the gap p1 - p2 and (R1 n_k) . (R2 o_ij) for two unit normals n_1, n_2 of
  o_ij (the axes aligned);
* prismatic, 5: (R1 n_k) . (p2 - p1) (the child's point on the parent's line) and the
  vee of the skew part of R1ᵀ R2 (the orientations equal).

The Jacobians (rows x nv, in Pinocchio's tangent space: ``q' = pin.integrate(q, dq)``)
of the spherical and fixed rows are Pinocchio's (``getConstraintsJacobian``).  Every row
is also written as a sum of dot products of points and vectors fixed in the two frames
(a fixed closure's as R1ᵀ (p1 - p2) and minus the vee above, which agree with -log6 to
first order), from which one kernel call (``closure_terms``, :mod:`kms2pin.native`)
gives the revolute and prismatic rows and their Jacobians from the frames' Jacobians,
and the constraints' curvature Σ λ_r ∇²r_r that Newton's method on the closed
configurations needs (exact along them, where the closures hold).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .model import Joint, ModelSpec, System, alignment_matrix, perpendicular_axis
from .native import kernels

#: Residual rows of a closure, per joint type.
ROWS = {"spherical": 3, "fixed": 6, "revolute": 5, "prismatic": 5}

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_E = np.eye(3)
# the vee of the skew part of M = R1ᵀ R2: w_i = ½ (M[k, j] - M[j, k]), (i, j, k) cyclic
_VEE = ((2, 1), (0, 2), (1, 0))
# a term's sides: a constant vector, a vector fixed in an end's frame, an end's origin
_CONST, _VECTOR, _POINT = 0, 1, 2
_NONE, _NONE3 = np.empty((0, 0)), np.empty((0, 0, 0))  # outputs the kernel is not asked for


@dataclass(frozen=True)
class _Closure:
    """One closure: its joint, rows, the (parent joint, placement) of its two ends, and
    Pinocchio's constraint model where one fits."""

    joint: Joint
    rows: slice
    ends: tuple[tuple[int, pin.SE3], tuple[int, pin.SE3]]
    constraint: pin.RigidConstraintModel | None


def _terms(c: _Closure, e1: int, e2: int) -> list[tuple]:
    """The dot-product terms (row, coef, (kind, end, vector) of x, of y) of closure ``c``
    whose ends are ``e1`` (parent) and ``e2`` (child) (module docstring)."""
    r0, kind = c.rows.start, c.joint.kind
    o = np.asarray(c.joint.parent_bvec.orient, dtype=float)
    n1 = perpendicular_axis(o)
    normals = (n1, np.cross(o, n1))
    out = []

    def gap(row: int, x: tuple, sign: float = 1.0) -> None:  # sign * x . (p1 - p2)
        out.append((row, sign, x, (_POINT, e1, _E[0])))
        out.append((row, -sign, x, (_POINT, e2, _E[0])))

    def vee(row: int, sign: float) -> None:  # sign * the vee of the skew part of R1ᵀ R2
        for i, (j, k) in enumerate(_VEE):
            out.append((row + i, 0.5 * sign, (_VECTOR, e1, _E[k]), (_VECTOR, e2, _E[j])))
            out.append((row + i, -0.5 * sign, (_VECTOR, e1, _E[j]), (_VECTOR, e2, _E[k])))

    if kind in ("spherical", "revolute"):
        for i in range(3):
            gap(r0 + i, (_CONST, e1, _E[i]))
    if kind == "revolute":
        for k, n in enumerate(normals):
            out.append((r0 + 3 + k, 1.0, (_VECTOR, e1, n), (_VECTOR, e2, o)))
    elif kind == "prismatic":
        for k, n in enumerate(normals):
            gap(r0 + k, (_VECTOR, e1, n), -1.0)
        vee(r0 + 2, 1.0)
    elif kind == "fixed":
        for i in range(3):
            gap(r0 + i, (_VECTOR, e1, _E[i]))
        vee(r0 + 3, -1.0)
    return out


class Closures:
    """The loop closures of a system as constraints on a Pinocchio model's configurations.

    Construction adds the two frames of each closure to ``model`` (before any ``Data`` is
    made).  ``links`` maps each body to its BODY frame (its link frame, at its joint to its
    parent); ``centres`` each body to its ellipsoid centre in that frame.
    """

    def __init__(self, model: pin.Model, system: System, links: dict[str, int], centres: dict[str, np.ndarray]):
        self.joints = system.closures
        items, start = [], 0
        for j in self.joints:
            R_align = alignment_matrix(np.asarray(j.parent_bvec.orient), np.asarray(j.child_bvec.orient))
            ends = []
            for side, body, bvec, R in (("parent", j.parent, j.parent_bvec, np.eye(3)),
                                        ("child", j.child, j.child_bvec, R_align.T)):
                pos = np.asarray(bvec.pos, dtype=float)
                link = 0 if body is None else links[body]
                f = model.frames[link]
                placement = f.placement * pin.SE3(R, pos if body is None else pos + centres[body])
                ends.append((f.parentJoint, placement))
                model.addFrame(pin.Frame(f"{j.name}_{side}", f.parentJoint, link, placement, pin.FrameType.OP_FRAME))
            constraint = None
            if j.kind in ("spherical", "fixed"):
                kind, frame = ((pin.ContactType.CONTACT_3D, _LWA) if j.kind == "spherical"
                               else (pin.ContactType.CONTACT_6D, pin.ReferenceFrame.LOCAL))
                constraint = pin.RigidConstraintModel(kind, model, *ends[0], *ends[1], frame)
                constraint.name = j.name
            rows = slice(start, start + ROWS[j.kind])
            start = rows.stop
            items.append(_Closure(j, rows, (ends[0], ends[1]), constraint))
        self._items = tuple(items)
        self.rows = start
        self._starts = np.array([c.rows.start for c in items], dtype=int)
        ends = [e for c in items for e in c.ends]
        # the joints the ends hang on (only their placements are converted), and each end's
        # index among them
        self._end_joints = sorted({jid for jid, _ in ends})
        self._end_joint = np.array([float(self._end_joints.index(jid)) for jid, _ in ends])
        self._end_offset = np.array([pin.SE3ToXYZQUAT(M) for _, M in ends]).reshape(-1, 7)
        self._moving = np.zeros((len(ends), model.nv))  # 1 where column a moves end e
        for e, (jid, _) in enumerate(ends):
            for k in model.supports[jid][1:]:
                jm = model.joints[k]
                self._moving[e, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        terms = [t for i, c in enumerate(items) for t in _terms(c, 2 * i, 2 * i + 1)]
        self._row = np.array([float(t[0]) for t in terms])
        self._coef = np.array([t[1] for t in terms])
        self._kind = np.array([[float(t[2][0]), float(t[3][0])] for t in terms]).reshape(-1, 2)
        self._end = np.array([[float(t[2][1]), float(t[3][1])] for t in terms]).reshape(-1, 2)
        self._vec = np.array([[*t[2][2], *t[3][2]] for t in terms], dtype=float).reshape(-1, 6)
        self._pinocchio = [c for c in items if c.constraint is not None]
        self._fixed = [c for c in self._pinocchio if c.joint.kind == "fixed"]
        self._last = None  # system_at's last (q, what, order, result)

    def __len__(self) -> int:
        return len(self._items)

    def ends(self, data: pin.Data) -> np.ndarray:
        """(2 K, 7) world placements (XYZQUAT) of every closure's two ends (parent, child, ...)
        after a forward pass into ``data``."""
        X = np.empty((len(self._end_joint), 7))
        xyzquat, oMi = pin.SE3ToXYZQUAT, data.oMi.tolist()
        kernels.frame_coordinates([xyzquat(oMi[j]) for j in self._end_joints], self._end_joint, self._end_offset, X)
        return X

    def _datas(self, data: pin.Data) -> pin.StdVec_RigidConstraintData:
        """The constraint models' data, made once per ``data``."""
        cache = getattr(data, "_kms2pin_closures", None)
        if cache is None or cache[0] is not self:
            datas = pin.StdVec_RigidConstraintData()
            for c in self._pinocchio:
                datas.append(c.constraint.createData())
            cache = (self, datas)
            data._kms2pin_closures = cache
        return cache[1]

    def system(self, model: pin.Model, data: pin.Data, what: int = 0,
               order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(residual rows, their Jacobian if ``what >= 1``, each row's curvature ∇²r_r (rows,
        nv, nv) if ``what >= 2``) from the dot-product terms in one kernel call, after a
        forward pass into ``data`` (``pin.computeJointJacobians`` for ``what >= 1``;
        ``order``: :func:`column_order`).  A fixed closure's rows and Jacobian are
        Pinocchio's (-log6); the others equal Pinocchio's (spherical) or are built here
        (revolute, prismatic)."""
        nv = model.nv
        r = np.empty(self.rows)
        Jc = np.empty((self.rows, nv)) if what >= 1 else _NONE
        H = np.empty((self.rows, nv, nv)) if what >= 2 else _NONE3
        kernels.closure_terms(data.J, self.ends(data), self._moving, self._kind, self._end, self._vec, self._row,
                              self._coef, _NONE if order is None else order, r, Jc, H, what)
        if self._fixed:
            self._pinocchio_rows(model, data, r, Jc if what >= 1 else None, self._fixed)
        return r, (Jc if what >= 1 else None), (H if what >= 2 else None)

    def system_at(self, model: pin.Model, data: pin.Data, q: np.ndarray, what: int = 1,
                  order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """:meth:`system` at ``q`` after ``pin.computeJointJacobians`` into ``data`` there, the
        last result kept: asked again at the same ``q`` for no more than it holds, it is
        returned without a new evaluation.  The arrays are shared with that cache: do not
        change them."""
        key = q.tobytes()
        last = self._last
        pin.computeJointJacobians(model, data, q)
        if last is not None and last[0] == key and last[1] >= what and (what < 2 or last[2] is order):
            return last[3]
        out = self.system(model, data, what, order)
        self._last = (key, what, order, out)
        return out

    def _pinocchio_rows(self, model: pin.Model, data: pin.Data, r: np.ndarray, Jc: np.ndarray | None,
                        closures: list[_Closure]) -> None:
        """Overwrite the rows (and Jacobian rows) of ``closures`` (spherical or fixed) by their
        Pinocchio constraint models': p1 - p2, or -log6 of the child frame in the parent's."""
        datas = self._datas(data)
        wanted = pin.StdVec_RigidConstraintModel()
        wanted_data = pin.StdVec_RigidConstraintData()
        for c in closures:
            cd = datas[self._pinocchio.index(c)]
            c.constraint.calc(model, data, cd)
            r[c.rows] = cd.oMc1.translation - cd.oMc2.translation if c.joint.kind == "spherical" \
                else -pin.log6(cd.c1Mc2).vector
            wanted.append(c.constraint)
            wanted_data.append(cd)
        if Jc is not None:
            Jp = pin.getConstraintsJacobian(model, data, wanted, wanted_data)
            k = 0
            for c in closures:
                n = c.rows.stop - c.rows.start
                Jc[c.rows] = Jp[k : k + n]
                k += n

    def residual(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """The residual rows (:data:`ROWS` per closure, in order) after a forward pass into
        ``data``: a spherical or fixed closure's from its Pinocchio constraint model; zero
        where every closure holds."""
        r = self.system(model, data)[0]
        self._pinocchio_rows(model, data, r, None, self._pinocchio)
        return r

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """d residual / dq (rows x nv) after ``pin.computeJointJacobians`` into ``data``; a
        spherical or fixed closure's from its Pinocchio constraint model
        (``getConstraintsJacobian``)."""
        r, Jc, _ = self.system(model, data, 1)
        self._pinocchio_rows(model, data, r, Jc, self._pinocchio)
        return Jc

    def curvature(self, model: pin.Model, data: pin.Data, lam: np.ndarray, order: np.ndarray) -> np.ndarray:
        """Σ_r lam_r ∇²r_r (nv x nv) after ``pin.computeJointJacobians`` (exact along the
        closed configurations; ``order``: :func:`column_order`)."""
        return np.tensordot(lam, self.system(model, data, 2, order)[2], 1)

    def norms(self, r: np.ndarray) -> np.ndarray:
        """Each closure's residual norm, from the stacked rows ``r``."""
        return np.sqrt(np.add.reduceat(r * r, self._starts)) if len(self._starts) else np.zeros(0)

    def gaps(self, data: pin.Data) -> list[tuple[float, float]]:
        """Each closure's (distance between its ends' points, angle in degrees between what
        must align: the axes of a revolute joint, the frames of a fixed or prismatic one; 0
        for a spherical one) after a forward pass; a prismatic joint's distance is the
        child's point's from the parent's line."""
        out = []
        X = self.ends(data)
        for i, c in enumerate(self._items):
            (p1, q1), (p2, q2) = ((X[e, :3], X[e, 3:]) for e in (2 * i, 2 * i + 1))
            R1, R2 = (pin.Quaternion(v[3], v[0], v[1], v[2]).toRotationMatrix() for v in (q1, q2))
            o = np.asarray(c.joint.parent_bvec.orient, dtype=float)
            d = p2 - p1
            if c.joint.kind == "prismatic":
                d = d - (d @ (R1 @ o)) * (R1 @ o)
            angle = 0.0
            if c.joint.kind == "revolute":
                angle = float(np.degrees(np.arccos(np.clip((R1 @ o) @ (R2 @ o), -1.0, 1.0))))
            elif c.joint.kind in ("fixed", "prismatic"):
                angle = float(np.degrees(np.linalg.norm(pin.log3(R1.T @ R2))))
            out.append((float(np.linalg.norm(d)), angle))
        return out


def column_order(model: pin.Model) -> np.ndarray:
    """(nv, nv): 1 where velocity column a belongs to a joint that is a proper ancestor of
    column b's (Pinocchio numbers a parent before its children; a column that moves neither
    end meets a zero Jacobian column), ½ for two columns of one joint, else 0."""
    joint = np.empty(model.nv, dtype=int)
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        joint[jm.idx_v : jm.idx_v + jm.nv] = jid
    same = joint[:, None] == joint[None, :]
    return np.where(same, 0.5, np.triu(np.ones((model.nv, model.nv)), 1))


def least_norm(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The least-norm dq with J dq = -r: dq = Jᵀ y, (J Jᵀ + s I) y = -r (Cholesky; s = 1e-12
    of J Jᵀ's largest diagonal entry, for rows that depend on others), or least squares if
    J Jᵀ is too ill-conditioned for that."""
    JJ = J @ J.T
    y = np.empty(len(r))
    if kernels.solve_shifted(JJ, r, 1e-12 * max(float(JJ.diagonal().max(initial=0.0)), 1e-300), y):
        return J.T @ y
    return -np.linalg.lstsq(J, r, rcond=1e-12)[0]


def project(closures: Closures, model: pin.Model, data: pin.Data, q: np.ndarray, lower: np.ndarray,
            upper: np.ndarray, held: np.ndarray, tol: float = 1e-12, max_iter: int = 50, what: int = 1,
            order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the residual from ``q``: q <- pin.integrate(q, -J⁺ r), J⁺ the
    least-norm pseudo-inverse (so the correction is the least in the tangent-space
    metric, to first order), until max |r| <= ``tol``; a step that does not lower |r| is
    halved (8 times at most, then the projection stops where it is).  Columns where
    ``held`` (nv,) is True do not move; a coordinate clipped into [``lower``, ``upper``]
    is held from then on.  Returns the configuration and its residual rows, with ``data``
    after ``pin.computeJointJacobians`` there.  Every evaluation is :meth:`Closures.system_at` with
    ``what`` and ``order`` (2: the curvature too, so that the caller's next
    ``system_at(q, 2, order)`` at the result costs nothing)."""
    held = held.copy()
    any_held = bool(held.any())
    limited = np.isfinite(lower)
    limits = bool(limited.any())
    clipped = limited
    r, J, _ = closures.system_at(model, data, q, what, order)
    err = float(np.abs(r).max(initial=0.0))
    for _ in range(max_iter):
        if err <= tol:
            break
        if any_held:
            J = J.copy()
            J[:, held] = 0.0
        dq = least_norm(J, r)
        for _ in range(9):
            q_new = pin.integrate(model, q, dq)
            if limits:
                clipped = limited & ((q_new < lower) | (q_new > upper))
                if clipped.any():
                    q_new = np.clip(q_new, lower, upper)
            r_new, J_new, _ = closures.system_at(model, data, q_new, what, order)
            err_new = float(np.abs(r_new).max())
            if err_new < err:
                break
            dq *= 0.5
        else:
            pin.computeJointJacobians(model, data, q)  # data back at q
            break
        q, r, J, err = q_new, r_new, J_new, err_new
        if limits and clipped.any():
            held[_q_to_v(model, np.flatnonzero(clipped))] = True
            any_held = bool(held.any())
    return q, r


def open_loops(closures: Closures, data: pin.Data, norms: np.ndarray, tol: float, system: System,
               spec: ModelSpec) -> list:
    """A diagnostic of ``spec`` at each closure of ``system`` whose residual norm (``norms``,
    after a forward pass into ``data``) is above ``tol``: the loop it closes, how far it
    stays open, and the joints whose rest values could close it."""
    problems = []
    for j, norm, (dist, angle) in zip(system.closures, norms, closures.gaps(data)):
        if norm <= tol:
            continue
        bodies, joints = system.loop(j)
        loop = " -> ".join("inertial frame" if b is None else b for b in [*bodies, bodies[0]])
        what = {"revolute": "axes", "prismatic": "orientations", "fixed": "orientations"}.get(j.kind)
        apart = f"its ends {dist:.3g} apart" + (f" and their {what} {angle:.3g} deg apart" if what else "")
        if j.kind == "prismatic":
            apart = f"the child's point {dist:.3g} from the parent's line and the orientations {angle:.3g} deg apart"
        problems.append(spec.diagnostic(
            j.loc,
            f"this {j.kind} joint closes the loop {loop}, but the loop cannot be closed near the rest pose: "
            f"the nearest configuration found leaves {apart}; change the bound vectors of its bodies or the "
            f"rest values of its joints ({', '.join(t.name for t in joints)})",
        ))
    return problems


def _q_to_v(model: pin.Model, iq: np.ndarray) -> np.ndarray:
    """Velocity indices of one-coordinate joints' q indices ``iq``."""
    out = []
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        if jm.nq == 1 and jm.idx_q in iq:
            out.append(jm.idx_v)
    return np.array(out, dtype=int)
