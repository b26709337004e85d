"""The constraint system C(q) = 0 and its Jacobian C_q, derived with SymPy (thesis §2.3, §3.2.2).

Coordinates: q ∈ R^{7n}, body i's block q[7i:7i+7] = [mu_x, mu_y, mu_z, θ0, θ1, θ2, θ3]
(eq. 2.8), bodies in ``System.bodies`` order.  Rows, per body in that order:

* ``"<body> Euler parameter norm"``: θᵀθ - 1 (eq. 2.6);
* for its joint to the lower body i (skipped for the root with ``root="free"``), with
  parent bvec (a_ij, o_ij) and child bvec (a_ji, o_ji):

  - ``"<joint> position x|y|z"``: mu_i + R_0i a_ij - mu_j - R_0j a_ji (eq. 2.13/2.15);
  - revolute, ``"<joint> axis x|y|z"``: R_0i o_ij - R_0j o_ji, all three rows, one of
    them redundant (eq. 2.15, §2.3.2);
  - fixed, ``"<joint> orientation R[r][c]"``: R_0j - R_0i R_align, all nine rows
    (eq. 2.13), three of them redundant;
  - spherical (kms2pin): the position rows alone (eq. 2.15's coincidence), no
    orientation row;
  - prismatic (kms2pin): the nine orientation rows of a fixed joint and, instead of the
    position rows, ``"<joint> line n1|n2"``: (R_0i n_k) . (mu_j - mu_i) + n_k . (R_align
    a_ji - a_ij) for two unit vectors n_1, n_2 perpendicular to o_ij (parent frame):
    the child's point mu_j + R_0j a_ji lies on the line through mu_i + R_0i a_ij along
    R_0i o_ij (with the orientation rows, R_0i^T R_0j = R_align).

Then, for each loop closure (``System.closures``, kms2pin: thesis §4.2), the same rows
of its joint between its parent and child bodies, which are not parent and child in the
tree (labelled ``"<closure> ..."``; the inertial frame where one end is an inertial
bvec).  Closures often add rows that depend on others (a planar loop's out-of-plane
rows): the number of independent rows, so the degrees of freedom, is the numerical rank
of C_q (the SVD/QR constraint selection of §2.3.2), not a count of joint rows.

The inertial frame has mu = 0 and R = I.  Every row is a polynomial of degree <= 3 in
q (2 without prismatic joints below a body), so C_q has degree <= 2.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg
import sympy as sp
from sympy.polys.rings import PolyElement

from ..model import JOINT_DOF, System
from .kinematics import check_root, forward_kinematics
from .rotations import alignment_matrix, perpendicular_axis

COORDINATE_NAMES = ("mu_x", "mu_y", "mu_z", "theta0", "theta1", "theta2", "theta3")
AXES = "xyz"


def quat_matrix(
    t0: sp.Expr | PolyElement, t1: sp.Expr | PolyElement, t2: sp.Expr | PolyElement, t3: sp.Expr | PolyElement
) -> list[list]:
    """Eq. 2.7 as nested lists; works for SymPy symbols and for polynomial-ring elements."""
    return [
        [1 - 2 * t2**2 - 2 * t3**2, 2 * (t1 * t2 - t0 * t3), 2 * (t1 * t3 + t0 * t2)],
        [2 * (t1 * t2 + t0 * t3), 1 - 2 * t1**2 - 2 * t3**2, 2 * (t2 * t3 - t0 * t1)],
        [2 * (t1 * t3 - t0 * t2), 2 * (t2 * t3 + t0 * t1), 1 - 2 * t1**2 - 2 * t2**2],
    ]


def _matvec(M, v) -> list:
    return [sum((M[r][c] * v[c] for c in range(3) if v[c] != 0), 0) for r in range(3)]


def _matmul(A, B) -> list[list]:
    return [[sum((A[r][k] * B[k][c] for k in range(3) if B[k][c] != 0), 0) for c in range(3)] for r in range(3)]


def _terms(poly, nq: int):
    """(a, b, c, coef) per term of a polynomial of degree <= 3; index nq stands for the constant 1."""
    out = []
    for monom, coef in poly.terms():
        idx = [k for k, e in enumerate(monom) if e for _ in range(e)]
        if len(idx) > 3:  # pragma: no cover - the rows are of degree <= 3
            raise ValueError("constraint of degree > 3")
        idx += [nq] * (3 - len(idx))
        out.append((idx[0], idx[1], idx[2], float(coef)))
    return out


def _joint_rows(joint, parent, child, zero) -> list[tuple]:
    """(row, label) of one joint's constraints (see the module docstring); ``parent`` and
    ``child`` are (mu, R) of the two bodies as ring elements (the inertial frame's are
    constants)."""
    (mu_i, R_i), (mu_j, R_j) = parent, child
    a_ij, o_ij = [float(x) for x in joint.parent_bvec.pos], [float(x) for x in joint.parent_bvec.orient]
    a_ji, o_ji = [float(x) for x in joint.child_bvec.pos], [float(x) for x in joint.child_bvec.orient]
    out = []
    if joint.kind != "prismatic":  # eq. 2.13 / 2.15: both ends at one world point
        Ra_ij, Ra_ji = _matvec(R_i, a_ij), _matvec(R_j, a_ji)
        out += [(mu_i[k] + Ra_ij[k] - mu_j[k] - Ra_ji[k] + zero, f"position {AXES[k]}") for k in range(3)]
    if joint.kind == "revolute":  # eq. 2.15: the axes aligned
        Ro_ij, Ro_ji = _matvec(R_i, o_ij), _matvec(R_j, o_ji)
        out += [(Ro_ij[k] - Ro_ji[k] + zero, f"axis {AXES[k]}") for k in range(3)]
    elif joint.kind in ("fixed", "prismatic"):  # eq. 2.13: R_0j = R_0i R_align
        R_align = alignment_matrix(o_ij, o_ji)
        RR_ = _matmul(R_i, R_align.tolist())
        out += [(R_j[r][c] - RR_[r][c] + zero, f"orientation R[{r}][{c}]") for r in range(3) for c in range(3)]
    if joint.kind == "prismatic":  # the child's point on the parent's line
        n1 = perpendicular_axis(o_ij)
        gap = R_align @ np.asarray(a_ji) - np.asarray(a_ij)
        for k, n in enumerate((n1, np.cross(o_ij, n1)), start=1):
            Rn = _matvec(R_i, n.tolist())
            row = sum((Rn[c] * (mu_j[c] - mu_i[c]) for c in range(3)), zero) + float(n @ gap)
            out.append((row, f"line n{k}"))
    elif joint.kind not in ("fixed", "revolute", "spherical"):  # pragma: no cover - the language's four
        raise ValueError(f"unsupported joint kind {joint.kind!r}")
    return out


@dataclass(frozen=True)
class Partition:
    """A numerical coordinate partitioning (eq. 2.24) at one point."""

    independent: np.ndarray  # indices into q (sorted)
    dependent: np.ndarray  # indices into q (sorted)


class SymbolicModel:
    """Symbolic constraints of one system and fast numeric callables derived from them.

    The rows are built, expanded and differentiated (C_q = ∂C/∂q, and the constant
    second derivatives used by Newton's method) as SymPy sparse polynomials over the
    doubles (``sympy.xring(..., RR)``); :attr:`constraints` and :attr:`jacobian_entries`
    give them as SymPy expressions (for code generation), and :meth:`lambdified`
    gives ``sympy.lambdify`` versions.  The numeric :meth:`C`, :meth:`C_q` and
    :meth:`constraint_hessian` evaluate the polynomial coefficients with NumPy
    (every row has degree <= 2), which is fast to build and to call.

    Attributes:
        system, root: what it models (``root`` is ``"spec"`` or ``"free"``).
        n_bodies, nq (= 7n), nc (number of rows, redundant rows included), dof.
        symbols: the 7n SymPy symbols ``q0 .. q{7n-1}``.
        coordinate_labels: ``"<body>.mu_x"`` ... ``"<body>.theta3"``.
        polys: the nc rows of C(q) as SymPy polynomial-ring elements.
        constraints: the same as SymPy expressions (expanded polynomials).
        labels: one human-readable label per row.
        jacobian_entries: the structurally nonzero entries of C_q as (row, column, expr).
        build_seconds: wall time of the symbolic construction.
    """

    def __init__(self, system: System, root: str = "spec"):
        start = time.perf_counter()
        self.system = system
        self.root = check_root(root)
        n = len(system.bodies)
        self.n_bodies = n
        self.nq = 7 * n
        self.symbols = sp.symbols(f"q0:{self.nq}")
        self.coordinate_labels = tuple(f"{b.name}.{c}" for b in system.bodies for c in COORDINATE_NAMES)
        index = {b.name: i for i, b in enumerate(system.bodies)}
        # Polynomial ring over the doubles: the rows are built, expanded and
        # differentiated as SymPy sparse polynomials (much faster than Expr trees).
        self.ring, g = sp.xring([str(x) for x in self.symbols], sp.RR)
        zero = self.ring.zero

        def frame(i: int | None):
            if i is None:
                return [zero, zero, zero], [[1.0 if r == c else 0.0 for c in range(3)] for r in range(3)]
            return g[7 * i : 7 * i + 3], quat_matrix(*g[7 * i + 3 : 7 * i + 7])

        rows = []
        labels: list[str] = []
        dof = 0
        for j_idx, (body, joint) in enumerate(zip(system.bodies, system.joints)):
            th = g[7 * j_idx + 3 : 7 * j_idx + 7]
            rows.append(sum((t**2 for t in th), zero) - 1)
            labels.append(f"{body.name} Euler parameter norm")
            if joint.parent is None and self.root == "free":
                dof += 6
                continue
            dof += JOINT_DOF[joint.kind]
            parent = frame(None if joint.parent is None else index[joint.parent])
            new_rows = _joint_rows(joint, parent, frame(j_idx), zero)
            rows += [r for r, _ in new_rows]
            labels += [f"{joint.name} {lab}" for _, lab in new_rows]
        for joint in system.closures:  # the same rows between two bodies that are not parent and child
            ends = (frame(None if b is None else index[b]) for b in (joint.parent, joint.child))
            new_rows = _joint_rows(joint, *ends, zero)
            rows += [r for r, _ in new_rows]
            labels += [f"{joint.name} {lab}" for _, lab in new_rows]
        self.polys = tuple(rows)
        self.labels = tuple(labels)
        self.nc = len(rows)
        self.dof = dof
        self.n_dependent = self.nq - dof

        # C_q = dC/dq entry by entry (sparse: a row involves at most two bodies)
        jac = []
        for r, p in enumerate(rows):
            used = sorted({k for monom in p.monoms() for k, e in enumerate(monom) if e})
            for k in used:
                d = p.diff(g[k])
                if d:
                    jac.append((r, k, d))
        self._jac_polys = tuple(jac)

        # numeric evaluators from the polynomial coefficients (every row has degree <= 3)
        nq = self.nq
        terms = [(r, *t) for r, p in enumerate(rows) for t in _terms(p, nq)]
        self._c_rows, self._c_a, self._c_b, self._c_c, self._c_coef = (np.array(x) for x in zip(*terms))
        terms = [(e, *t) for e, (_, _, d) in enumerate(jac) for t in _terms(d, nq)]
        self._j_ent, self._j_a, self._j_b, self._j_c, self._j_coef = (np.array(x) for x in zip(*terms))
        self._jrows = np.array([r for r, _, _ in jac], dtype=int)
        self._jcols = np.array([k for _, k, _ in jac], dtype=int)
        # second derivatives d2C_r/dq_i dq_k = coef * q_other (q_nq = 1: a constant), from
        # each term coef q_a q_b of dC_r/dq_i (degree <= 2, so its third index is nq)
        second = []
        for r, i, d in jac:
            for a, b, _, c in _terms(d, nq):
                if a < nq:
                    second.append((r, i, a, c, b))
                if b < nq:
                    second.append((r, i, b, c, a))
        self._hr, self._hi, self._hk, self._hc, self._ho = (
            (np.array(x) for x in zip(*second))
            if second
            else (np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0, int))
        )
        if system.closures:  # the rank of C_q at the tree's rest pose (closed there, or nearly)
            self.n_dependent = self.rank(forward_kinematics(system, root=self.root))
            self.dof = self.nq - self.n_dependent
        self.build_seconds = time.perf_counter() - start

    @cached_property
    def constraints(self) -> tuple[sp.Expr, ...]:
        """C(q) as SymPy expressions (expanded polynomials in the symbols q0..)."""
        return tuple(p.as_expr(*self.symbols) for p in self.polys)

    @cached_property
    def jacobian_entries(self) -> tuple[tuple[int, int, sp.Expr], ...]:
        """The structurally nonzero entries of C_q as (row, column, SymPy expression)."""
        return tuple((r, k, d.as_expr(*self.symbols)) for r, k, d in self._jac_polys)

    def __repr__(self) -> str:
        return f"SymbolicModel('{self.system.name}', root={self.root!r}, nq={self.nq}, nc={self.nc}, dof={self.dof})"

    # ------------------------------------------------------------------ symbolic views
    def jacobian_matrix(self) -> sp.SparseMatrix:
        """C_q as a SymPy sparse matrix (nc x 7n)."""
        return sp.SparseMatrix(self.nc, self.nq, {(r, c): e for r, c, e in self.jacobian_entries})

    @cached_property
    def cse_constraints(self) -> tuple[list, list]:
        """``sympy.cse`` of :attr:`constraints`: (substitutions t0, t1, ..., reduced rows)."""
        return sp.cse(list(self.constraints), symbols=sp.numbered_symbols("t"))

    @cached_property
    def cse_jacobian(self) -> tuple[list, list]:
        """``sympy.cse`` of the :attr:`jacobian_entries` expressions."""
        return sp.cse([e for _, _, e in self.jacobian_entries], symbols=sp.numbered_symbols("t"))

    def lambdified(self) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
        """(C, C_q) numeric callables made by ``sympy.lambdify`` from :attr:`constraints`
        and :attr:`jacobian_entries` (built once, then cached); for cross-checks."""
        if "_lambdified" not in self.__dict__:
            self.__dict__["_lambdified"] = self._make_lambdified()
        return self.__dict__["_lambdified"]

    def _make_lambdified(self):
        args = [list(self.symbols)]
        c_fn = sp.lambdify(args, list(self.constraints), modules="numpy")
        j_fn = sp.lambdify(args, [e for _, _, e in self.jacobian_entries], modules="numpy")

        def C(q):
            return np.asarray(c_fn(self._flat(q)), dtype=float)

        def C_q(q):
            out = np.zeros((self.nc, self.nq))
            out[self._jrows, self._jcols] = np.asarray(j_fn(self._flat(q)), dtype=float)
            return out

        return C, C_q

    # ------------------------------------------------------------------ numerics
    def _flat(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape == (self.n_bodies, 7):
            q = q.reshape(-1)
        if q.shape != (self.nq,):
            raise ValueError(f"q must have shape ({self.nq},) or ({self.n_bodies}, 7), not {q.shape}")
        return q

    def _ext(self, q) -> np.ndarray:
        return np.append(self._flat(q), 1.0)

    def C(self, q: np.ndarray) -> np.ndarray:
        """C(q), shape (nc,)."""
        x = self._ext(q)
        vals = self._c_coef * x[self._c_a] * x[self._c_b] * x[self._c_c]
        return np.bincount(self._c_rows, vals, minlength=self.nc)

    def C_q(self, q: np.ndarray) -> np.ndarray:
        """C_q(q) = dC/dq, shape (nc, 7n)."""
        x = self._ext(q)
        vals = np.bincount(
            self._j_ent, self._j_coef * x[self._j_a] * x[self._j_b] * x[self._j_c], minlength=len(self._jrows)
        )
        out = np.zeros((self.nc, self.nq))
        out[self._jrows, self._jcols] = vals
        return out

    def constraint_hessian(self, q: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Σ_r lam_r ∂²C_r/∂q², shape (7n, 7n) (constant in q without prismatic joints)."""
        lam = np.asarray(lam, dtype=float)
        x = self._ext(q)
        out = np.zeros((self.nq, self.nq))
        np.add.at(out, (self._hi, self._hk), self._hc * x[self._ho] * lam[self._hr])
        return out

    def rank(self, q: np.ndarray) -> int:
        """The numerical rank of C_q at ``q`` (singular values above 1e-9 of the largest): how
        many of the rows are independent there."""
        sig = np.linalg.svd(self.C_q(q), compute_uv=False)
        return int((sig > 1e-9 * sig[0]).sum()) if sig.size and sig[0] > 0 else 0

    def partition(self, q: np.ndarray, Cq: np.ndarray | None = None) -> Partition:
        """Numerical coordinate partitioning q = [q_I, q_D] (eq. 2.24) at ``q``.

        QR with column pivoting of C_q picks the ``nq - dof`` best-conditioned columns
        as the dependent coordinates q_D; the other ``dof`` are independent.  (The
        thesis fixes one inertial Euler parameter θ_{j,0} per revolute joint, which
        fails where ∂θ0/∂θ = 0, fig. 2.2(c); a numerical choice never does.)  With loop
        closures ``nq - dof`` is the rank of C_q (:meth:`rank`) at ``q``.
        """
        if Cq is None:
            Cq = self.C_q(q)
        _, piv = scipy.linalg.qr(Cq, mode="r", pivoting=True)
        n_dep = self.n_dependent
        if self.system.closures:
            sig = np.linalg.svd(Cq, compute_uv=False)
            n_dep = int((sig > 1e-9 * sig[0]).sum()) if sig.size and sig[0] > 0 else 0
        dep = np.sort(piv[:n_dep])
        ind = np.sort(piv[n_dep:])
        return Partition(ind, dep)

    def B_di(self, q: np.ndarray, partition: Partition | None = None, rtol: float = 1e-10) -> np.ndarray:
        """B_di (7n x dof) of eq. 2.32 at ``q``: δq = B_di δq_I.

        Rows of the independent coordinates are I, rows of the dependent ones are
        -C_qd⁺ C_qi with C_qd⁺ the SVD pseudo-inverse (eq. 2.30-2.31, singular values
        below ``rtol`` * the largest are discarded).  Columns follow
        ``partition.independent`` (the numerical partition at ``q`` by default).
        """
        B, _, _ = self.B_di_and_pinv(q, partition, rtol)
        return B

    def B_di_and_pinv(
        self, q: np.ndarray, partition: Partition | None = None, rtol: float = 1e-10, Cq: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, Partition]:
        """(B_di, C_qd⁺, partition) at ``q``."""
        if Cq is None:
            Cq = self.C_q(q)
        part = partition or self.partition(q, Cq)
        pinv = svd_pinv(Cq[:, part.dependent], rtol)
        B = np.zeros((self.nq, len(part.independent)))
        B[part.independent, np.arange(len(part.independent))] = 1.0
        B[part.dependent, :] = -pinv @ Cq[:, part.independent]
        return B, pinv, part


def svd_pinv(A: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Moore-Penrose pseudo-inverse V Σ̄⁻¹ U_rᵀ (eq. 2.31), small singular values discarded."""
    U, sig, Vt = np.linalg.svd(A, full_matrices=False)
    if sig.size == 0:
        return np.zeros(A.shape[::-1])
    keep = sig > rtol * sig[0]
    return (Vt[keep].T / sig[keep]) @ U[:, keep].T


_CACHE: dict[tuple[System, str], SymbolicModel] = {}


def symbolic_model(system: System, root: str = "spec") -> SymbolicModel:
    """The :class:`SymbolicModel` of ``system``, built once per (system, root)."""
    key = (system, check_root(root))
    model = _CACHE.get(key)
    if model is None:
        model = _CACHE[key] = SymbolicModel(system, root)
    return model
