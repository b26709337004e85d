"""The C kernels (kms2pin/_kernels.c) and their NumPy twins (kms2pin/_numpy_kernels.py):
the same outputs on random inputs, kernel by kernel, and the switch between them."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pinocchio as pin
import pytest
from conftest import require_kernels

from kms2pin import native


def _quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _coords(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 7) random XYZQUAT placements."""
    return np.concatenate([rng.normal(size=(n, 3)), _quats(rng, n)], axis=1)


def _rotation(rng: np.random.Generator) -> np.ndarray:
    return pin.Quaternion(*_quats(rng, 1)[0]).toRotationMatrix()


def _metric(R: np.ndarray, inner: np.ndarray) -> np.ndarray:
    return (R / inner**2) @ R.T


def _strided(a: np.ndarray) -> np.ndarray:
    """The same values in a non-contiguous array (the C kernels' scalar loops)."""
    big = np.zeros((2 * a.shape[0],) + a.shape[1:])
    big[::2] = a
    return big[::2]


def _rays(rows: int, cols: int, half: float = 0.2) -> np.ndarray:
    """(rows, cols, 3) pixel rays at unit depth of a camera at the origin looking along +z."""
    v, u = np.meshgrid(np.linspace(-half, half, rows), np.linspace(-half, half, cols), indexing="ij")
    return np.ascontiguousarray(np.stack([u, v, np.ones_like(u)], axis=-1))


def _body(rng: np.random.Generator):
    """A body 8 units in front of the camera: rotation, centre, inner semi-axes, metric
    A and camera centre relative to it e."""
    R, t, inner = _rotation(rng), np.array([0.1, -0.2, 8.0]) + rng.normal(0, 0.1, 3), np.array([0.3, 0.8, 0.4])
    return R, t, inner, _metric(R, inner), -t


def _view_data(rng: np.random.Generator, dirs: np.ndarray, weighted: bool):
    """A mask drawn by the body moved a little, others' shares and inlier weights."""
    R, t, inner, A, e = _body(rng)
    a2 = np.empty(len(dirs))
    native.implementations("ellipsoid_a2")["numpy"](dirs, _metric(R, inner * 1.05), e - rng.normal(0, 0.05, 3), a2)
    y = (a2 <= 1.0).astype(float)
    o = rng.uniform(0, 0.5, len(dirs))
    w = rng.uniform(0.5, 1.0, len(dirs)) if weighted else None
    return R, t, inner, A, e, y, o, w


# Each case: kernel name -> (args, the indices of the arguments it writes); rng seeded per case.


def _linearize(rng, hessian=True, one_k=False):
    n, nv = 6, 10
    S = (rng.random((n, nv)) < 0.6).astype(float)
    S[:, :6] = 1.0  # the free flyer moves every body
    same = np.eye(nv)
    same[:6, :6] = 1.0  # a free flyer's six columns
    K = np.full((n, 7), 2.0) if one_k else rng.uniform(0.5, 2.0, (n, 7))
    if not one_k:
        K[2] = 0.0  # a body without springs
    args = [rng.normal(size=(6, nv)), _coords(rng, n), _coords(rng, n), K, S, same,
            np.empty(nv), np.empty((nv, nv)), np.empty((n, 7)), hessian]
    return args, (6, 7, 8)


def _frame_coordinates(rng, tuples=False):
    rows = [tuple(r) if tuples else r for r in _coords(rng, 5)]
    return [rows, rng.integers(0, 5, 8).astype(float), _coords(rng, 8), np.empty((8, 7))], (3,)


def _ellipsoid_a2(rng, strided=False):
    dirs = _rays(30, 40).reshape(-1, 3)
    _, _, _, A, e = _body(rng)
    if strided:
        dirs = _strided(dirs)
    return [dirs, A, e, np.empty(len(dirs))], (3,)


def _silhouette_fit(rng, jac=True, weighted=True, strided=False):
    dirs = _rays(40, 50, 0.4).reshape(-1, 3)  # far pixels too: h << -40
    _, _, _, A, e, y, o, w = _view_data(rng, dirs, weighted)
    if strided:
        dirs, y, o, w = _strided(dirs), _strided(y), _strided(o), None if w is None else _strided(w)
    H0 = rng.normal(size=(6, 6))
    return [dirs, A, e, 10.0, y, o, w, jac, H0 + H0.T, rng.normal(size=6)], (8, 9)


def _scale_fit(rng, weighted=True):
    dirs = _rays(40, 50).reshape(-1, 3)
    R, _, inner, A, e, y, o, w = _view_data(rng, dirs, weighted)
    return [dirs, A, e, R, inner, 6.0, y, o, w, np.eye(3), rng.normal(size=3)], (9, 10)


def _estep_body(rng, outlier=False, strided=False):
    rows, cols = 30, 40
    dirs = _rays(rows, cols).reshape(-1, 3)
    _, _, _, A, e = _body(rng)
    if strided:
        dirs = _strided(dirs)
    log_free = -rng.uniform(0, 3, (50, 60))
    log_free_o = -rng.uniform(0, 3, (50, 60)) if outlier else None
    return [dirs, A, e, 8.0, log_free, 7, 11, rows, cols, np.empty(rows * cols), log_free_o, 0.4], (4, 9, 10)


def _estep_view(rng, mask="bool"):
    rows, cols = 30, 40
    m = rng.random((50, 60))
    masks = {"bool": m < 0.5, "uint8": np.where(m < 0.5, 255, 0).astype(np.uint8), "float64": m}
    sp = rng.uniform(0, 5, rows * cols)
    log_free = -rng.uniform(0, 8, (50, 60))
    return [log_free, masks[mask], 7, 11, rows, cols, sp, np.empty(rows * cols), np.empty(rows * cols)], (7, 8)


def _estep_camera(rng, mask="bool"):
    H, W, n = 60, 80, 5
    rays = _rays(H, W, 0.3)
    boxes = np.array([[10, 5, 40, 30], [30, 20, 70, 55], [0, 0, 0, 0], [25, 10, 60, 40], [0, 50, 80, 60]], float)
    offset = np.zeros(n + 1)
    offset[1:] = np.cumsum((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]))
    N = int(offset[-1])
    A, e = [], []
    for _ in range(n):
        _, _, _, Ai, ei = _body(rng)
        A.append(Ai.ravel())
        e.append(ei + rng.normal(0, 0.3, 3))
    m = rng.random((H, W))
    masks = {"bool": m < 0.5, "float64": m}
    args = [rays, np.array(A), np.array(e), rng.uniform(3, 12, n), boxes, offset, masks[mask], np.zeros((H, W)),
            np.empty((N, 3)), np.empty(N), np.empty(N), np.empty(N)]
    return args, (7, 8, 9, 10, 11)


def _silhouette_bodies(rng, n: int, H: int, W: int):
    """n bodies seen by the camera of :func:`_rays` (H, W, 0.3), their metrics (n, 9),
    camera centres relative to them and boxes (the third out of view: empty)."""
    A, e = [], []
    for _ in range(n):
        _, _, _, Ai, ei = _body(rng)
        A.append(Ai.ravel())
        e.append(ei + rng.normal(0, 0.3, 3))
    # boxes around the image centre (where the bodies are), cutting their silhouettes
    boxes = np.c_[rng.integers(0, W // 2 - 4, n), rng.integers(0, H // 2 - 4, n), rng.integers(W // 2 + 4, W + 1, n),
                  rng.integers(H // 2 + 4, H + 1, n)].astype(float)
    boxes[2 % n] = 0.0
    return np.array(A), np.array(e), boxes


def _silhouette_union(rng):
    H, W = 60, 80
    A, e, boxes = _silhouette_bodies(rng, 5, H, W)
    out = rng.random((H, W)) < 0.1  # set pixels stay set
    return [_rays(H, W, 0.3), A, e, boxes, out], (4,)


def _silhouette_counts(rng, mask="bool"):
    H, W = 60, 80
    A, e, boxes = _silhouette_bodies(rng, 7, H, W)
    on = rng.random((H, W)) < 0.5
    off = ~on & (rng.random((H, W)) < 0.5)
    if mask == "uint8":
        on, off = on.astype(np.uint8), off.astype(np.uint8)
    offset = np.array([0, 2, 2, 3, 7], float)  # groups of 2, 0, 1 (out of view) and 4 bodies
    return [_rays(H, W, 0.3), A, e, boxes, offset, on, off, np.full((4, 2), -1.0)], (7,)


def _silhouette_add(rng):
    H, W = 60, 80
    A, e, boxes = _silhouette_bodies(rng, 5, H, W)
    counts = rng.integers(0, 3, (H, W)).astype(np.uint8)  # counts already there are added to
    return [_rays(H, W, 0.3), A, e, boxes, counts], (4,)


def _silhouette_swap(rng, mask="bool"):
    """Five bodies counted, two of them (one out of view) moved to new places."""
    H, W = 60, 80
    rays = _rays(H, W, 0.3)
    A, e, boxes = _silhouette_bodies(rng, 5, H, W)
    counts = np.zeros((H, W), np.uint8)
    native.implementations("silhouette_add")["numpy"](rays, A, e, boxes, counts)
    A_new, e_new, boxes_new = _silhouette_bodies(rng, 2, H, W)
    m = rng.random((H, W)) < 0.5
    m = m.astype(np.uint8) if mask == "uint8" else m
    return [rays, A[[1, 2]], e[[1, 2]], boxes[[1, 2]], A_new, e_new, boxes_new, counts, m], ()


def _fit_body(rng, max_step=-1.0, weighted=False):
    """Two cameras (at the origin looking along +z, at (8, 0, 8) along -x) see the body
    moved a little from where the fit starts."""
    R, t, inner, _, _ = _body(rng)
    R_true, t_true = pin.exp3(rng.normal(0, 0.05, 3)) @ R, t + rng.normal(0, 0.03, 3)
    front = _rays(40, 50, 0.15).reshape(-1, 3)
    views = []
    for centre, dirs in ((np.zeros(3), front), (np.array([8.0, 0.0, 8.0]), front[:, [2, 1, 0]] * [-1, 1, 1])):
        a2 = np.empty(len(dirs))
        native.implementations("ellipsoid_a2")["numpy"](dirs, _metric(R_true, inner), centre - t_true, a2)
        w = rng.uniform(0.5, 1.0, len(dirs)) if weighted else None
        views.append((dirs, centre, 8.0, (a2 <= 1.0).astype(float), rng.uniform(0, 0.1, len(dirs)), w))
    return [views, R, t, inner, 4, 1e-2, max_step, np.empty((3, 3)), np.empty(3), np.empty((6, 6))], (7, 8, 9)


def _fit_bodies(rng):
    """Three bodies' views packed per camera as the E-step leaves them: body 0 seen by
    both cameras, body 1 by the second only, body 2 by neither (its pose kept)."""
    bodies = [_fit_body(rng)[0] for _ in range(3)]
    cams, inv, seen = [], np.zeros((2, 3)), np.zeros((2, 3))
    for c in range(2):
        dirs, y, o, offset = [], [], [], [0.0]
        for i, args in enumerate(bodies):
            view = args[0][c]
            if (c, i) in ((0, 0), (1, 0), (1, 1)):
                dirs.append(view[0]), y.append(view[3]), o.append(view[4])
                inv[c, i], seen[c, i] = view[2] * (1.0 + 0.1 * i), 1.0
            offset.append(offset[-1] + (len(view[0]) if seen[c, i] else 0))
        cams.append((np.ascontiguousarray(np.concatenate(dirs)), np.concatenate(y), np.concatenate(o), np.array(offset), bodies[0][0][c][1]))
    R = np.array([b[1].ravel() for b in bodies])
    t, inner = np.array([b[2] for b in bodies]), np.array([b[3] for b in bodies])
    outs = [np.empty((3, 9)), np.empty((3, 3)), np.empty((3, 36)), np.empty((3, 2))]
    return [cams, inv, seen, R, t, inner, 4, 1e-2, 0.05, *outs], (9, 10, 11, 12)


def _pose_springs(rng):
    n, nv = 6, 10
    B = rng.normal(size=(n, 6, 6))
    K = (B @ B.transpose(0, 2, 1) + 6 * np.eye(6)).reshape(n, 36)
    S = (rng.random((n, nv)) < 0.7).astype(float)
    X, T = _coords(rng, n), _coords(rng, n)
    T[:, 3:] = -T[:, 3:]  # either sign: the same rotation
    return [rng.normal(size=(6, nv)), X, T, K, S, np.empty((nv, nv)), np.empty(nv)], (5, 6)


def _outline_pixels(rng):
    """Ellipsoids in front of, straddling and behind a camera."""
    n = 12
    Rwc, centre = _rotation(rng), rng.normal(size=3)
    local = np.c_[rng.uniform(-2, 2, (n, 2)), rng.uniform(-1, 8, n)]
    R = np.array([_rotation(rng).ravel() for _ in range(n)])
    K = np.array([[300.0, 0.5, 160], [0, 290, 120], [0, 0, 1]])
    return [R, centre + local @ Rwc.T, rng.uniform(0.1, 0.8, (n, 3)), Rwc, centre, K, np.empty((7 * n, 2))], (6,)


def _spring_targets(rng):
    """Rotations on both branches of the quaternion formula (near a half turn: trace <= 0),
    one body unseen (no curvature)."""
    n = 8
    R = np.array([pin.AngleAxis(float(a), _unit(rng)).toRotationMatrix() for a in rng.uniform(0.0, np.pi, n)])
    B = rng.normal(size=(n, 6, 6))
    H = B @ B.transpose(0, 2, 1)
    H[3] = 0.0
    return [R.reshape(n, 9), rng.normal(size=(n, 3)), H.reshape(n, 36), rng.uniform(0.02, 0.3, (n, 3)), 0.05,
            np.empty((n, 7)), np.empty((n, 36))], (5, 6)


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _pose_energy(rng):
    args, _ = _pose_springs(rng)
    return args[1:4], ()


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_pose_energy_is_pose_springs_energy_to_the_last_bit(backend):
    """The static update's last trial step takes the energy alone: the same number."""
    if backend == "c":
        require_kernels()
    impl = {n: native.implementations(n)[backend] for n in ("pose_energy", "pose_springs")}
    for seed in range(5):
        args, _ = _pose_springs(np.random.default_rng(seed))
        assert impl["pose_energy"](*args[1:4]) == impl["pose_springs"](*args) > 0.0


def _twist_prior(rng, free=0.0):
    """Five spherical joints in a q of 30 (their quaternions off unit, some w < 0), onto a
    Newton system of 20 columns that already holds values."""
    n, nq, nv = 5, 30, 20
    iq, iv = np.array([0.0, 5.0, 11.0, 17.0, 24.0]), np.array([0.0, 4.0, 8.0, 12.0, 16.0])
    q = rng.normal(size=nq)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    M = rng.normal(size=(nv, nv))
    return [q, iq, iv, axes, _quats(rng, n), free, 0.7, M @ M.T, rng.normal(size=nv)], (7, 8)


def _body_boxes(rng):
    n = 40
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    Rwc, centre = _rotation(rng), rng.normal(size=3)
    local = np.c_[rng.uniform(-6, 6, (n, 2)), rng.uniform(-2, 14, n)]  # behind, straddling, in front
    t = centre + local @ Rwc.T
    Rs = np.array([_rotation(rng).ravel() for _ in range(n)])
    inner = rng.uniform(0.2, 1.0, (n, 3))
    return [Rs, t, inner, Rwc, centre, K, 0.7, 2.0, 320, 240, np.zeros((n, 4)), np.empty(n), np.empty(n)], (10, 11, 12)


def _solve_shifted(rng, definite=True, shift=0.0):
    M = rng.normal(size=(7, 7))
    H = M @ M.T if definite else M + M.T
    return [H, rng.normal(size=7), shift, np.full(7, 3.0)], (3,)


def _cholesky_solve_row_by_row(H, g, shift):
    """(H + shift I) x = -g by Cholesky in plain Python floats, each sum in column order:
    the arithmetic of the C kernel's rows, one row at a time."""
    n = len(g)
    L = [[0.0] * n for _ in range(n)]
    for j in range(n):
        for i in range(j, n):
            s = float(H[i, j]) + (shift if i == j else 0.0)
            for m in range(j):
                s -= L[i][m] * L[j][m]
            L[i][j] = math.sqrt(s) if i == j else s / L[j][j]
    y = [0.0] * n
    for i in range(n):
        s = -float(g[i])
        for m in range(i):
            s -= L[i][m] * y[m]
        y[i] = s / L[i][i]
    x = [0.0] * n
    for i in reversed(range(n)):
        s = y[i]
        for m in range(i + 1, n):
            s -= L[m][i] * x[m]
        x[i] = s / L[i][i]
    return np.array(x)


def test_solve_shifted_rows_are_summed_as_one_row_at_a_time():
    """The C kernel's Cholesky takes four rows at a time; each sum keeps its own order, so
    the step is the row-by-row arithmetic's to the last bit (sizes not a multiple of four,
    a zero row among them)."""
    require_kernels()
    rng = np.random.default_rng(12)
    for n in (1, 5, 13, 61):
        M = rng.normal(size=(n, n))
        H = M @ M.T
        if n > 2:
            H[1, :] = H[:, 1] = 0.0
            H[1, 1] = 2.0
        g, step = rng.normal(size=n), np.empty(n)
        assert native.implementations("solve_shifted")["c"](H, g, 1e-9, step)
        np.testing.assert_array_equal(step, _cholesky_solve_row_by_row(H, g, 1e-9))


def _all_unit(rng, spoil=None):
    """A vector of 20 with three unit quaternions in it; ``spoil``: a NaN outside them, or one
    of them scaled off unit."""
    v = rng.normal(size=20)
    starts = np.array([1.0, 7.0, 14.0])
    for a in starts.astype(int):
        v[a : a + 4] /= np.linalg.norm(v[a : a + 4])
    if spoil == "nan":
        v[5] = np.nan
    elif spoil == "norm":
        v[7:11] *= 1.0 + 1e-9
    return [v, starts, 1.0 - 1e-12, 1.0 + 1e-12], ()


def _limits(rng, nq=12, m=7):
    """m limited coordinates of a q of nq: indices, bounds, and a q with some outside them."""
    iq = rng.choice(nq, m, replace=False).astype(float)
    lo = rng.uniform(-2.0, 0.0, m)
    hi = lo + rng.uniform(0.5, 3.0, m)
    q = rng.uniform(-4.0, 4.0, nq)
    return q, iq, lo, hi


def _clip_limits(rng):
    q, iq, lo, hi = _limits(rng)
    return [q, iq, lo, hi], (0,)


def _hold_limits(rng, none_held=False):
    """Joints at either limit pushed both ways (held when pushed outwards), and free ones."""
    q, iq, lo, hi = _limits(rng)
    nv = 10
    iv = rng.choice(nv, len(iq), replace=False).astype(float)
    i = iq.astype(int)
    q[i] = np.clip(q[i], lo, hi)
    q[i[:3]] = lo[:3]
    q[i[3:5]] = hi[3:5]
    grad = rng.normal(size=nv)
    if none_held:  # pushed inwards only
        v = iv.astype(int)
        grad[v[:3]] = -np.abs(grad[v[:3]])
        grad[v[3:5]] = np.abs(grad[v[3:5]])
    M = rng.normal(size=(nv, nv))
    span = hi - lo
    return [q, iq, iv, lo + 1e-12 * span, hi - 1e-12 * span, grad, M @ M.T], (5, 6)


def _closure_terms(rng, what=2):
    """Random dot-product terms of loop closures: 4 ends, 12 terms on 5 rows, 9 columns."""
    E, T, rows, nv = 4, 12, 5, 9
    moving = (rng.random((E, nv)) < 0.6).astype(float)
    kind = rng.integers(0, 3, (T, 2)).astype(float)
    end = rng.integers(0, E, (T, 2)).astype(float)
    row = rng.integers(0, rows, T).astype(float)
    order = np.triu(np.ones((nv, nv)), 1)
    order[:3, :3] = 0.5  # a three-column joint
    Jc = np.empty((rows, nv)) if what >= 1 else np.empty((0, 0))
    H = np.empty((rows, nv, nv)) if what >= 2 else np.empty((0, 0, 0))
    args = [rng.normal(size=(6, nv)), _coords(rng, E), moving, kind, end, rng.normal(size=(T, 6)), row,
            rng.normal(size=T), order, np.empty(rows), Jc, H, what]
    return args, (9, 10, 11)


def _nullspace_system(rng, m=5, nv=9, dependent=False):
    A = rng.normal(size=(m, nv))
    if dependent:  # a row that repeats two others' sum, and a zero row
        A[2], A[3] = A[0] + A[1], 0.0
    M = rng.normal(size=(nv, nv))
    C = rng.normal(size=(max(m - 1, 0), nv, nv))
    if dependent:  # the curvatures follow the rows (else the multipliers of the repeated rows,
        C[2], C[3] = C[0] + C[1], 0.0  # not unique, weigh them differently in each kernel)
    args = [A, rng.normal(size=nv), M @ M.T, C + C.transpose(0, 2, 1), np.empty((nv, nv)), np.empty((nv, nv)),
            np.empty(nv), np.empty(m)]
    # repeated rows have no unique multipliers (each kernel's pivoting picks its own basic
    # ones): the test compares A^T lam instead
    return args, (4, 5, 6) if dependent else (4, 5, 6, 7)


CASES: dict[str, Callable] = {
    "all_unit": _all_unit,
    "all_unit-nan": lambda rng: _all_unit(rng, "nan"),
    "all_unit-off-unit": lambda rng: _all_unit(rng, "norm"),
    "clip_limits": _clip_limits,
    "hold_limits": _hold_limits,
    "hold_limits-none-held": lambda rng: _hold_limits(rng, none_held=True),
    "closure_terms": _closure_terms,
    "closure_terms-residual": lambda rng: _closure_terms(rng, what=0),
    "closure_terms-jacobian": lambda rng: _closure_terms(rng, what=1),
    "nullspace_system": _nullspace_system,
    "outline_pixels": _outline_pixels,
    "nullspace_system-dependent-rows": lambda rng: _nullspace_system(rng, m=6, dependent=True),
    "nullspace_system-more-rows-than-columns": lambda rng: _nullspace_system(rng, m=7, nv=4),
    "linearize": _linearize,
    "linearize-gauss-newton-one-k": lambda rng: _linearize(rng, hessian=False, one_k=True),
    "frame_coordinates": _frame_coordinates,
    "frame_coordinates-tuples": lambda rng: _frame_coordinates(rng, tuples=True),
    "ellipsoid_a2": _ellipsoid_a2,
    "ellipsoid_a2-strided": lambda rng: _ellipsoid_a2(rng, strided=True),
    "silhouette_fit": _silhouette_fit,
    "silhouette_fit-unweighted": lambda rng: _silhouette_fit(rng, weighted=False),
    "silhouette_fit-no-jacobian": lambda rng: _silhouette_fit(rng, jac=False),
    "silhouette_fit-strided": lambda rng: _silhouette_fit(rng, strided=True),
    "scale_fit": _scale_fit,
    "scale_fit-unweighted": lambda rng: _scale_fit(rng, weighted=False),
    "estep_body": _estep_body,
    "estep_body-outlier": lambda rng: _estep_body(rng, outlier=True),
    "estep_body-strided": lambda rng: _estep_body(rng, outlier=True, strided=True),
    "estep_view": _estep_view,
    "estep_view-uint8": lambda rng: _estep_view(rng, "uint8"),
    "estep_view-float64": lambda rng: _estep_view(rng, "float64"),
    "estep_camera": _estep_camera,
    "estep_camera-float64": lambda rng: _estep_camera(rng, "float64"),
    "fit_bodies": _fit_bodies,
    "fit_body": _fit_body,
    "fit_body-max-step-weighted": lambda rng: _fit_body(rng, max_step=0.02, weighted=True),
    "pose_springs": _pose_springs,
    "pose_energy": _pose_energy,
    "body_boxes": _body_boxes,
    "silhouette_union": _silhouette_union,
    "silhouette_add": _silhouette_add,
    "silhouette_swap": _silhouette_swap,
    "silhouette_swap-uint8": lambda rng: _silhouette_swap(rng, "uint8"),
    "silhouette_counts": _silhouette_counts,
    "silhouette_counts-uint8": lambda rng: _silhouette_counts(rng, "uint8"),
    "solve_shifted": _solve_shifted,
    "spring_targets": _spring_targets,
    "twist_prior": _twist_prior,
    "twist_prior-free": lambda rng: _twist_prior(rng, free=1.0),
    "solve_shifted-indefinite": lambda rng: _solve_shifted(rng, definite=False),
    "solve_shifted-shifted": lambda rng: _solve_shifted(rng, definite=False, shift=20.0),
}


def _lam(kernel, args):
    """nullspace_system's multipliers (its last argument) on a copy of ``args``."""
    a = _copy(args)
    kernel(*a)
    return a[7]


def _copy(a):
    if isinstance(a, np.ndarray):
        return a.copy()
    if isinstance(a, list):
        return [_copy(x) for x in a]
    return a


def _assert_close(c, n, what: str) -> None:
    c, n = np.asarray(c, dtype=float), np.asarray(n, dtype=float)
    scale = float(np.nanmax(np.abs(n))) if n.size and not np.isnan(n).all() else 0.0  # NaN: equal where both are
    np.testing.assert_allclose(c, n, rtol=1e-9, atol=1e-12 * scale, err_msg=what)


def test_every_kernel_has_a_case():
    assert {case.split("-")[0] for case in CASES} == set(native.NAMES)


@pytest.mark.parametrize("case", sorted(CASES))
def test_c_and_numpy_kernels_agree(case):
    """The C kernel and its NumPy twin return the same values and write the same outputs."""
    require_kernels()
    name = case.split("-")[0]
    impl = native.implementations(name)
    args, outs = CASES[case](np.random.default_rng(sorted(CASES).index(case)))
    results = {}
    for backend in ("c", "numpy"):
        a = _copy(args)
        results[backend] = (impl[backend](*a), [a[i] for i in outs])
    (rc, oc), (rn, on) = results["c"], results["numpy"]
    assert type(rc) is type(rn)
    if isinstance(rn, tuple):
        for k, (x, y) in enumerate(zip(rc, rn)):
            _assert_close(x, y, f"return value {k}")
    elif rn is not None:
        _assert_close(rc, rn, "return value")
    for i, x, y in zip(outs, oc, on):
        _assert_close(x, y, f"argument {i}")
    if name == "body_boxes":
        assert set(on[2].tolist()) == {0.0, 1.0, 2.0}  # out of view, per body and boxed all met
        np.testing.assert_array_equal(oc[0], on[0])
    if name == "solve_shifted":
        assert rn is (case != "solve_shifted-indefinite")
    if name == "all_unit":  # unit quaternions in a finite vector, and each way to spoil them
        assert rn is (case == "all_unit")
    if name == "nullspace_system":  # the multipliers' forces A^T lam, unique also for repeated rows
        A = args[0]
        _assert_close(A.T @ _lam(impl["c"], args), A.T @ _lam(impl["numpy"], args), "A^T lam")
    if name == "estep_camera":
        assert not on[0].any()  # the union image zeroed again
    if name == "silhouette_union":
        assert on[0].sum() > args[4].sum()  # bodies painted
        np.testing.assert_array_equal(oc[0], on[0])
    if name == "silhouette_counts":
        assert (on[0][[1, 2]] == 0).all() and (on[0][[0, 3]] > 0).all()  # empty groups count nothing
        np.testing.assert_array_equal(oc[0], on[0])


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_fit_bodies_is_fit_body_body_by_body(backend):
    """The packed M-step gives each body what fit_body gives it from the same views (in
    camera order), to the last bit; an unseen body keeps its pose with no curvature."""
    if backend == "c":
        require_kernels()
    impl = {n: native.implementations(n)[backend] for n in ("fit_bodies", "fit_body")}
    args, _ = _fit_bodies(np.random.default_rng(3))
    cams, inv, seen, R, t, inner = args[:6]
    impl["fit_bodies"](*args)
    R_out, t_out, H_out, out = args[9:]
    for i in range(3):
        views = [(d[int(off[i]):int(off[i + 1])], centre, inv[c, i], y[int(off[i]):int(off[i + 1])],
                  o[int(off[i]):int(off[i + 1])], None) for c, (d, y, o, off, centre) in enumerate(cams) if seen[c, i]]
        Ri, ti, Hi = np.empty((3, 3)), np.empty(3), np.empty((6, 6))
        ev, cost = impl["fit_body"](views, R[i].reshape(3, 3), t[i], inner[i], 4, 1e-2, 0.05, Ri, ti, Hi)
        np.testing.assert_array_equal(R_out[i], Ri.ravel())
        np.testing.assert_array_equal(t_out[i], ti)
        np.testing.assert_array_equal(H_out[i], Hi.ravel())
        assert tuple(out[i]) == (ev, cost)
    assert not np.array_equal(R_out[0], R[0]) and not np.array_equal(t_out[1], t[1])  # seen bodies moved
    np.testing.assert_array_equal(R_out[2], R[2])
    assert not H_out[2].any() and tuple(out[2]) == (0.0, 0.0)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_spring_targets_are_pinocchio_s_quaternions_and_the_floored_matrices(backend):
    """T holds pin.SE3ToXYZQUAT's numbers to the last bit (rotations on both branches of
    the formula, slightly off orthonormal as fits are), K each H plus floor times the
    largest scaled diagonal entry over the squared scale (translations in mean semi-axes)."""
    if backend == "c":
        require_kernels()
    kernel = native.implementations("spring_targets")[backend]
    rng = np.random.default_rng(11)
    n = 400
    R = np.array([pin.AngleAxis(float(a), _unit(rng)).toRotationMatrix() for a in rng.uniform(0.0, np.pi, n)])
    R[::3] += rng.normal(size=R[::3].shape) * 1e-4
    t = rng.normal(size=(n, 3))
    B = rng.normal(size=(n, 6, 6))
    H = B @ B.transpose(0, 2, 1)
    inner = rng.uniform(0.02, 0.3, (n, 3))
    T, K = np.empty((n, 7)), np.empty((n, 36))
    hmax = kernel(R.reshape(n, 9), t, H.reshape(n, 36), inner, 0.05, T, K)
    assert (np.trace(R, axis1=1, axis2=2) <= 0).sum() > 50  # both branches met
    np.testing.assert_array_equal(T, [pin.SE3ToXYZQUAT(pin.SE3(Ri, ti)) for Ri, ti in zip(R, t)])
    s = np.c_[np.repeat(inner.mean(axis=1, keepdims=True), 3, axis=1), np.ones((n, 3))]
    expected = max(H[i, d, d] * s[i, d] ** 2 for i in range(n) for d in range(6))
    assert hmax == expected
    np.testing.assert_allclose(K.reshape(n, 6, 6), H + np.eye(6) * (0.05 * expected / s**2)[:, None, :], rtol=1e-15)
    H[:] = 0.0  # nothing seen: K is H and the caller takes no springs
    assert kernel(R.reshape(n, 9), t, H.reshape(n, 36), inner, 0.05, T, K) == 0.0 and not K.any()


def test_fit_bodies_refuses_offsets_past_its_pixels():
    require_kernels()
    args, _ = _fit_bodies(np.random.default_rng(4))
    dirs, y, o, offset, centre = args[0][0]
    bad = offset.copy()
    bad[-1] = len(dirs) + 5
    args[0][0] = (dirs, y, o, bad, centre)
    with pytest.raises(ValueError, match="offsets"):
        native.implementations("fit_bodies")["c"](*args)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_silhouette_counts_are_those_of_each_group_s_union(backend):
    """Each group's counts are those of silhouette_union's image of the group alone."""
    if backend == "c":
        require_kernels()
    args, _ = _silhouette_counts(np.random.default_rng(5))
    rays, A, e, boxes, offset, on, off, counts = args
    native.implementations("silhouette_counts")[backend](*args)
    for k in range(len(offset) - 1):
        sl = slice(int(offset[k]), int(offset[k + 1]))
        img = np.zeros(on.shape, dtype=bool)
        native.implementations("silhouette_union")["numpy"](rays, A[sl], e[sl], boxes[sl], img)
        assert counts[k].tolist() == [(img & on).sum(), (img & off).sum()]


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_a_swap_changes_the_counts_as_the_silhouettes_painted_anew(backend):
    """silhouette_swap's change of (intersection, union) with the mask is that of the union
    of the bodies kept and the new ones, painted by silhouette_union, against the union of
    all the old; silhouette_add counts each body's pixels once."""
    if backend == "c":
        require_kernels()
    for seed in range(4):
        rays, A_old, e_old, b_old, A_new, e_new, b_new, counts, mask = _silhouette_swap(np.random.default_rng(seed))[0]
        A, e, boxes = _silhouette_bodies(np.random.default_rng(seed), 5, 60, 80)  # the five counted bodies
        np.testing.assert_array_equal(A[[1, 2]], A_old)
        paint = native.implementations("silhouette_union")["numpy"]
        every, kept = np.zeros((60, 80), bool), np.zeros((60, 80), bool)
        paint(rays, A, e, boxes, every)
        paint(rays, A[[0, 3, 4]], e[[0, 3, 4]], boxes[[0, 3, 4]], kept)
        paint(rays, A_new, e_new, b_new, kept)
        once = np.zeros((60, 80), np.uint8)
        native.implementations("silhouette_add")[backend](rays, A, e, boxes, once)
        np.testing.assert_array_equal(once, counts)
        d = native.implementations("silhouette_swap")[backend](rays, A_old, e_old, b_old, A_new, e_new, b_new, counts,
                                                                mask)
        expected = (int((kept & mask).sum() - (every & mask).sum()), int((kept | mask).sum() - (every | mask).sum()))
        assert d == expected and d != (0, 0)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_the_count_kernels_refuse_counts_they_cannot_hold(backend):
    """A count past 255 is refused, and so is a swap of bodies the counts do not hold."""
    if backend == "c":
        require_kernels()
    rays, A, e, boxes, _ = _silhouette_add(np.random.default_rng(1))[0]
    add = native.implementations("silhouette_add")[backend]
    with pytest.raises(ValueError, match="255"):
        add(rays, A, e, boxes, np.full((60, 80), 255, np.uint8))
    swap = native.implementations("silhouette_swap")[backend]
    with pytest.raises(ValueError, match="not all in counts"):
        swap(rays, A, e, boxes, A[:1], e[:1], boxes[:1], np.zeros((60, 80), np.uint8), np.ones((60, 80), bool))
    with pytest.raises(ValueError, match="not all in counts"):  # the old bodies past 255 on a pixel
        swap(rays, *(np.repeat(x[:1], 300, axis=0) for x in (A, e, boxes)), A[:1], e[:1], boxes[:1],
             np.full((60, 80), 255, np.uint8), np.ones((60, 80), bool))
    with pytest.raises(TypeError, match="uint8"):  # a bool image holds no counts
        add(rays, A, e, boxes, np.zeros((60, 80), bool))
    with pytest.raises(TypeError, match="uint8"):
        swap(rays, A, e, boxes, A, e, boxes, np.zeros((60, 80), bool), np.ones((60, 80), bool))


def test_the_silhouette_kernels_refuse_boxes_off_the_image():
    require_kernels()
    args, _ = _silhouette_counts(np.random.default_rng(6))
    k = native.implementations("silhouette_counts")["c"]
    bad = args[3].copy()
    bad[0, 2] = 81.0  # past the 80 columns
    with pytest.raises(ValueError):
        k(*args[:3], bad, *args[4:])
    with pytest.raises(ValueError):
        native.implementations("silhouette_union")["c"](*args[:3], bad, np.zeros((60, 80), dtype=bool))
    with pytest.raises(ValueError):  # a mask of another size
        k(*args[:5], args[5][:, :40], *args[6:])


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_frame_coordinates_compose_the_placements(backend):
    """out[i] = rows[joints[i]] * offsets[i], as Pinocchio composes SE3 placements."""
    if backend == "c":
        require_kernels()
    rng = np.random.default_rng(3)
    (rows, joints, offsets, out), _ = _frame_coordinates(rng)
    native.implementations("frame_coordinates")[backend](rows, joints, offsets, out)
    for i, j in enumerate(joints.astype(int)):
        M = pin.XYZQUATToSE3(rows[j]) * pin.XYZQUATToSE3(offsets[i])
        np.testing.assert_allclose(pin.XYZQUATToSE3(out[i]).homogeneous, M.homogeneous, atol=1e-12)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_hold_limits_takes_out_the_joints_pushed_outwards(backend):
    """Projected Levenberg-Marquardt's active set, checked element by element: a joint at its
    lower limit with grad > 0 (descent pushes it below) or at its upper limit with grad < 0
    is held (zero gradient, its row and column zero, the largest diagonal entry on the
    diagonal); every other entry is untouched."""
    if backend == "c":
        require_kernels()
    for seed in range(5):
        args, _ = _hold_limits(np.random.default_rng(seed))
        q, iq, iv, lo_at, hi_at, grad, H = args
        g0, H0 = grad.copy(), H.copy()
        gsq = native.implementations("hold_limits")[backend](*args)
        held = [int(v) for k, v in enumerate(iv) if (q[int(iq[k])] <= lo_at[k] and g0[int(v)] > 0)
                or (q[int(iq[k])] >= hi_at[k] and g0[int(v)] < 0)]
        assert held  # the case holds some joints
        free = [a for a in range(len(g0)) if a not in held]
        np.testing.assert_array_equal(grad[held], 0.0)
        np.testing.assert_array_equal(grad[free], g0[free])
        np.testing.assert_array_equal(H[np.ix_(free, free)], H0[np.ix_(free, free)])
        np.testing.assert_array_equal(H[np.ix_(held, free)], 0.0)
        np.testing.assert_array_equal(H[np.ix_(held, held)], np.diag(np.full(len(held), H0.diagonal().max())))
        assert gsq == pytest.approx(float(np.sum(g0[free] ** 2)), rel=1e-12)


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_clip_limits_clips_only_the_limited_coordinates(backend):
    if backend == "c":
        require_kernels()
    q, iq, lo, hi = _limits(np.random.default_rng(7))
    q0 = q.copy()
    native.implementations("clip_limits")[backend](q, iq, lo, hi)
    i = iq.astype(int)
    expected = q0.copy()
    expected[i] = np.minimum(np.maximum(q0[i], lo), hi)
    np.testing.assert_array_equal(q, expected)
    assert (q0[i] < lo).any() and (q0[i] > hi).any()  # the case clips both ways


def test_use_switches_every_kernel_and_restores_the_choice():
    before = {name: getattr(native.kernels, name) for name in native.NAMES}
    enabled = native.ENABLED
    with native.use("numpy") as k:
        assert k is native.kernels and not native.ENABLED
        assert all(getattr(k, n) is native.implementations(n)["numpy"] for n in native.NAMES)
    assert {name: getattr(native.kernels, name) for name in native.NAMES} == before
    assert native.ENABLED == enabled
    with pytest.raises(ValueError, match="one of c, numpy"), native.use("fortran"):
        pass
    with pytest.raises(KeyError, match="no kernel 'fit'"):
        native.implementations("fit")


def test_use_c_switches_every_kernel_to_the_extension():
    require_kernels()
    enabled = native.ENABLED
    with native.use("c"):
        assert native.ENABLED
        assert all(getattr(native.kernels, n) is native.implementations(n)["c"] for n in native.NAMES)
    assert native.ENABLED == enabled


def test_the_extension_has_exactly_the_numpy_kernels():
    c = require_kernels()
    assert {n for n in dir(c) if callable(getattr(c, n)) and not n.startswith("_")} == set(native.NAMES)


@pytest.mark.parametrize("value, enabled", [("0", False), ("1", True)])
def test_kms2pin_native_chooses_the_backend(value, enabled):
    if enabled:
        require_kernels()
    env = {**os.environ, "KMS2PIN_NATIVE": value}
    out = subprocess.run([sys.executable, "-c", "from kms2pin import native; print(native.ENABLED, "
                          "native.kernels.fit_body.__module__)"], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == [str(enabled), "kms2pin._kernels" if enabled else "kms2pin._numpy_kernels"]
