"""The M-step (thesis §2.1.2), in full 3-D: each body's 6-DoF pose refit on its own.

The thesis's M-step was planar and search-based (§4.1).  Ours is a short
Gauss-Newton fit per body over its world position and orientation, with
analytic derivatives, using every camera that sees the body.

Model.  Body i's *sharp* silhouette in a camera is ``s_i(u) = σ(h_i(u))`` with
``h_i = (1 - a_i(u)²) / (2 δ_i)``, ``a_i`` the closest approach of pixel u's
ray to the inner ellipsoid in the ellipsoid metric (``a <= 1`` exactly on the
inner silhouette, :mod:`kms2pin.ecm.density`) and ``δ_i`` about ``delta_px``
pixels in ``a`` units: a logistic edge ``delta_px`` wide centred on the true
outline.  The image of all bodies is their union ``M = 1 - Π_j (1 - s_j)``.

E-step (:func:`explained_by_others`).  For body i the pixels are soft-labelled
by what the *other* bodies already explain: ``o_i = 1 - Π_{j≠i} (1 - s_j)``.
Occlusion needs no depth order here: a silhouette is the union of the bodies'
images whichever is in front.

M-step (:func:`fit_body`).  With the others held (conditional maximization),
body i minimizes the squared difference between the mask ``y`` and the union::

    C_i = Σ_u (y(u) - o_i(u) - (1 - o_i(u)) s_i(u))²

i.e. a least-squares fit of its silhouette to the mask, weighted by the
fraction ``1 - o_i`` of each pixel the others leave unexplained.  Why this is
unbiased, unlike pulling a body's E-step pixels into it: a pixel that a
neighbour explains has ``1 - o_i ≈ 0`` and neither pulls nor pushes body i, and
on a body's own outline the residual is antisymmetric across the edge
(``1 - σ(h) = σ(-h)``), so with clean silhouettes the true pose is a
stationary point (up to pixel sampling and O(δ² curvature), both sub-pixel).
The cost is not flat along the viewing ray: moving nearer grows the image over
background, moving away uncovers foreground.

Unobserved directions.  The fit is damped towards the starting (primary) pose,
Levenberg-Marquardt style, relative to the data's own curvature, so
directions the images do not determine (a mostly occluded body; in one view,
turns that leave an outline unchanged) stay where they are: the body's target
equals its primary pose there and its spring exerts no force in them.  The
Gauss-Newton matrix ``H = JᵀJ`` is returned: the tracker turns it into
per-coordinate stiffness for the static update (thesis: "k may be different
for every coordinate of every body").

Derivatives.  With ``A = R diag(L⁻²) Rᵀ``, ``e = C - t`` (camera centre
relative to the body centre) and ``d`` the pixel's world ray, the closest point
is ``q* = e + s* d``, ``s* = max(-eᵀAd / dᵀAd, 0)``, ``a² = q*ᵀ A q*``.  For a
world translation ``δt`` and a world rotation vector ``ω`` applied to the body
(``t += δt``, ``R ← exp(ω) R``), by the envelope theorem
``d(a²) = -2 (gᵀ δt + ωᵀ (q* × g))`` with ``g = A q*``.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .camera import Camera
from .projection import BBox, body_bbox

#: ``h`` beyond which the logistic edge counts as saturated (σ(-7) < 1e-3).
H_CUT = 7.0

_WORLD_RAYS: weakref.WeakKeyDictionary[Camera, np.ndarray] = weakref.WeakKeyDictionary()


def world_rays(camera: Camera) -> np.ndarray:
    """(H, W, 3) world directions of the pixel rays, scaled to unit camera depth (cached)."""
    r = _WORLD_RAYS.get(camera)
    if r is None:
        r = np.ascontiguousarray(camera.ray_grid @ np.asarray(camera.world_R_camera).T)
        r.flags.writeable = False
        _WORLD_RAYS[camera] = r
    return r


def sigmoid(h: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * h))


@dataclass
class BodyImage:
    """One body in one camera: the region it is evaluated on and its edge width.

    ``box`` is the pixel box (of the body's inner ellipsoid grown to reach
    ``h = -H_CUT`` plus ``slack_px``); ``dirs`` (N, 3) the world rays of its
    pixels, every ``stride``-th row and column; ``delta`` the edge width in
    ``a²/2`` units; ``s`` the sharp silhouette at the pose it was made for.
    """

    camera: Camera
    box: BBox
    stride: int
    dirs: np.ndarray
    delta: float
    s: np.ndarray | None = None

    @property
    def slices(self) -> tuple[slice, slice]:
        b = self.box
        return slice(b.v0, b.v1, self.stride), slice(b.u0, b.u1, self.stride)

    @property
    def shape(self) -> tuple[int, int]:
        sv, su = self.slices
        return len(range(sv.start, sv.stop, sv.step)), len(range(su.start, su.stop, su.step))


def body_image(
    camera: Camera,
    pose: pin.SE3,
    inner: np.ndarray,
    delta_px: float,
    *,
    slack_px: float = 2.0,
    max_pixels: int = 6000,
) -> BodyImage | None:
    """The region of one body in one camera (None if it is not in view)."""
    inner = np.asarray(inner, dtype=float)
    depth = float(camera.depth(np.asarray(pose.translation)[None])[0])
    if depth <= 1e-9 * float(np.max(inner)):
        return None
    focal = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    radius_px = focal * float(np.sqrt(np.sort(inner)[:2].prod())) / depth  # a rough outline radius
    # (1 - a²)/2 ≈ distance / radius; at most 0.08 so that the centre (h = 1/2δ) is saturated
    delta = min(max(delta_px / max(radius_px, 1e-6), 1e-6), 0.08)
    grow = np.sqrt(1.0 + 2.0 * H_CUT * delta) + (slack_px / max(radius_px, 1e-6))
    box = body_bbox(camera, pose, inner * grow, margin=1)
    if box is None:
        return None
    rows, cols = box.shape
    stride = max(1, int(np.ceil(np.sqrt(rows * cols / max_pixels))))
    img = BodyImage(camera, box, stride, np.empty((0, 3)), delta)
    img.dirs = world_rays(camera)[img.slices].reshape(-1, 3)
    return img


def _geometry(img: BodyImage, R: np.ndarray, t: np.ndarray, inner: np.ndarray, jac: bool):
    """``a²`` per pixel and, if ``jac``, its derivative -2 [g, q*×g] (N, 6) (module docstring)."""
    A = (R / inner**2) @ R.T
    e = img.camera.centre - t
    Ae = A @ e
    d = img.dirs
    Ad = d @ A
    dot = d @ Ae
    nn = np.einsum("ij,ij->i", Ad, d)
    s = np.maximum(-dot / nn, 0.0)
    qs = e + s[:, None] * d
    g = Ae + s[:, None] * Ad
    a2 = np.einsum("ij,ij->i", qs, g)
    if not jac:
        return a2, None
    D = np.empty((len(d), 6))
    D[:, :3] = g
    D[:, 3:] = np.cross(qs, g)
    D *= -2.0
    return a2, D


def silhouette(img: BodyImage, pose: pin.SE3, inner: np.ndarray) -> np.ndarray:
    """Sharp silhouette ``s = σ((1 - a²) / 2δ)`` on the region's pixels (N,)."""
    a2, _ = _geometry(img, pose.rotation, pose.translation, np.asarray(inner, float), False)
    return sigmoid((1.0 - a2) / (2.0 * img.delta))


@dataclass(frozen=True)
class BodyView:
    """What one camera says about one body: its region, the mask ``y`` there,
    ``o``, how much of each pixel the other bodies explain, and ``weight``, each
    pixel's inlier responsibility (1 - outlier; None: all 1) (all (N,))."""

    image: BodyImage
    y: np.ndarray
    o: np.ndarray
    weight: np.ndarray | None = None


@dataclass(frozen=True)
class BodyFit:
    """M-step result: the intermediate pose, the Gauss-Newton matrix at it (6x6,
    world translation then world rotation vector), the evidence (pixels the body
    explains alone) and the final cost."""

    pose: pin.SE3
    hessian: np.ndarray
    evidence: float
    cost: float


def _moved(pose: pin.SE3, delta: np.ndarray) -> pin.SE3:
    """Pose moved by a world translation delta[:3] and a world rotation vector delta[3:]."""
    return pin.SE3(pin.exp3(delta[3:]) @ pose.rotation, pose.translation + delta[:3])


def fit_body(
    views: Sequence[BodyView],
    pose0: pin.SE3,
    inner: np.ndarray,
    *,
    iterations: int = 3,
    damping: float = 1e-3,
) -> BodyFit:
    """Refit one body's pose to its views by damped Gauss-Newton (module docstring).

    ``damping`` is the Tikhonov weight towards ``pose0`` relative to the largest
    curvature of the data (translations in body sizes, rotations in radians).
    (One body of :func:`fit_bodies`.)
    """
    if not views:
        return BodyFit(pose0, np.zeros((6, 6)), 0.0, 0.0)
    return fit_bodies([views], [pose0], [np.asarray(inner, dtype=float)], iterations=iterations, damping=damping)[0]


# --------------------------------------------------------------------------- batched
class _Batch:
    """Every body's views flattened into one pixel array (body-major), so that one
    evaluation of all bodies is a fixed number of NumPy calls whatever the number
    of bodies and cameras (a per-view loop costs a dozen calls per body per camera)."""

    def __init__(self, views: Sequence[Sequence[BodyView]], inners: np.ndarray, R0=None, t0=None, band=None):
        n = len(views)
        self.n = n
        self.inners = inners
        dirs, cen, y, o, inv, wt, body, nview = [], [], [], [], [], [], [], []
        for i, vs in enumerate(views):
            for v in vs:
                m = len(v.y)
                dirs.append(v.image.dirs)
                cen.append(np.broadcast_to(v.image.camera.centre, (m, 3)))
                y.append(v.y)
                o.append(v.o)
                inv.append(np.full(m, 1.0 / (2.0 * v.image.delta)))
                wt.append(np.ones(m) if v.weight is None else v.weight)
                body.append(np.full(m, i, dtype=np.intp))
            nview.append(len(vs))
        self.has = np.array(nview) > 0
        if not dirs:
            self.P = 0
            return
        self.dirs = np.concatenate(dirs)
        self.cen = np.concatenate(cen)
        self.y = np.concatenate(y)
        self.free = 1.0 - np.concatenate(o)
        self.o = np.concatenate(o)
        self.inv = np.concatenate(inv)
        self.wt = np.concatenate(wt)  # 1 - outlier responsibility
        self.body = np.concatenate(body)
        self.P = len(self.y)
        if band is not None:
            # keep the edge band only: pixels with |h| >= band at the starting poses are
            # saturated (s = 0 or 1 up to e^-band) and stay so for steps of a few pixels;
            # their residuals are constant and their Jacobians zero
            h = (1.0 - self._a2(R0, t0)) * self.inv
            keep = np.flatnonzero(np.abs(h) < band)
            for name in ("dirs", "cen", "y", "free", "o", "inv", "wt", "body"):
                setattr(self, name, getattr(self, name)[keep])
            self.P = len(keep)
        counts = np.bincount(self.body, minlength=n)
        self.start = np.r_[0, np.cumsum(counts)[:-1]]
        self.counts = counts

    def _sum(self, x: np.ndarray) -> np.ndarray:
        """Per-body sums of a per-pixel array (P,) or (P, k)."""
        if x.ndim == 1:
            return np.bincount(self.body, weights=x, minlength=self.n)
        out = np.zeros((self.n,) + x.shape[1:])
        nz = self.counts > 0
        out[nz] = np.add.reduceat(x, self.start[nz], axis=0)
        return out

    def _a2(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        b = self.body
        Rb = R[b]
        Linv = 1.0 / self.inners[b]
        d = np.einsum("pij,pi->pj", Rb, self.dirs) * Linv
        e = np.einsum("pij,pi->pj", Rb, self.cen - t[b]) * Linv
        s = np.maximum(-np.einsum("pi,pi->p", e, d) / np.einsum("pi,pi->p", d, d), 0.0)
        qp = e + s[:, None] * d
        return np.einsum("pi,pi->p", qp, qp)

    def evaluate(self, R: np.ndarray, t: np.ndarray, jac: bool, active: np.ndarray | None = None):
        """Cost (n,), gradient (n,6), Gauss-Newton matrix (n,6,6) and evidence (n,) of
        every body at poses (R (n,3,3), t (n,3)); inactive bodies' pixels are skipped
        (their entries are zero)."""
        n = self.n
        cost, grad, H, ev = np.zeros(n), np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros(n)
        if self.P == 0:
            return cost, grad, H, ev
        if active is not None and not active.all():
            sel = active[self.body]
            idx = np.flatnonzero(sel)
        else:
            idx = None
        take = (lambda a: a) if idx is None else (lambda a: a[idx])
        b = take(self.body)
        Rb = R[b]  # (P,3,3)
        Linv = 1.0 / self.inners[b]
        # body frame, scaled to the unit sphere: d' = Rᵀ d / L, e' = Rᵀ (C - t) / L
        d = np.einsum("pij,pi->pj", Rb, take(self.dirs)) * Linv
        e = np.einsum("pij,pi->pj", Rb, take(self.cen) - t[b]) * Linv
        dd = np.einsum("pi,pi->p", d, d)
        ed = np.einsum("pi,pi->p", e, d)
        s = np.maximum(-ed / dd, 0.0)
        qp = e + s[:, None] * d  # q' (unit-sphere frame)
        a2 = np.einsum("pi,pi->p", qp, qp)
        inv = take(self.inv)
        sil = sigmoid((1.0 - a2) * inv)
        free, y, o, wt = take(self.free), take(self.y), take(self.o), take(self.wt)
        r = y - o - free * sil
        rw = wt * r
        bins = lambda x: np.bincount(b, weights=x, minlength=n)  # noqa: E731
        cost = bins(rw * r)
        if not jac:
            return cost, grad, H, ev
        ev = bins(wt * free * sil * y)
        # g = A q* = R (q'/L);  q* × g = R ((L q') × (q'/L));  D = -2 [g, q*×g]
        gl = qp * Linv
        cl = np.cross(qp * self.inners[b], gl)
        w = free * sil * (1.0 - sil) * inv * -2.0  # dr/d(a²)... times D below gives dr/dδ
        J = np.empty((len(b), 6))
        J[:, :3] = np.einsum("pij,pj->pi", Rb, gl)
        J[:, 3:] = np.einsum("pij,pj->pi", Rb, cl)
        J *= w[:, None]
        Jw = J * wt[:, None]
        grad = np.zeros((n, 6))
        for k in range(6):
            grad[:, k] = bins(Jw[:, k] * r)
        if idx is None:
            starts, counts = self.start, self.counts
        else:
            counts = np.bincount(b, minlength=n)
            starts = np.r_[0, np.cumsum(counts)[:-1]]
        for i in np.flatnonzero(counts):
            sl = slice(starts[i], starts[i] + counts[i])
            H[i] = Jw[sl].T @ J[sl]
        return cost, grad, H, ev


def fit_bodies(
    views: Sequence[Sequence[BodyView]],
    poses0: Sequence[pin.SE3],
    inners: Sequence[np.ndarray],
    *,
    iterations: int = 3,
    damping: float = 1e-3,
    max_step: float | None = None,
    band: float | None = 3 * H_CUT,
) -> list[BodyFit]:
    """:func:`fit_body` for every body at once (``views[i]`` are body i's views).

    The same damped Gauss-Newton per body, but each Gauss-Newton step evaluates all
    bodies in one batch and solves their 6x6 systems together; a body whose step is
    rejected retries with more damping while the others wait.  ``max_step`` caps a
    body's step per iteration (translation in body sizes, rotation in radians;
    the larger of the two norms).  ``band``: only pixels with ``|h| < band`` at the
    starting poses are evaluated (the edge band; the others are saturated, constant
    residual and no gradient, while the body moves a few edge widths); None: all.
    The cost reported is then the band's.
    """
    n = len(poses0)
    inners = np.asarray(inners, dtype=float).reshape(n, 3)
    R = np.array([p.rotation for p in poses0]).reshape(n, 3, 3)
    t = np.array([p.translation for p in poses0]).reshape(n, 3)
    batch = _Batch(views, inners, R, t, band)
    cost, grad, H, ev = batch.evaluate(R, t, True)
    size = inners.mean(axis=1)
    S = np.concatenate([np.repeat(size[:, None], 3, 1), np.ones((n, 3))], axis=1)  # (n,6)
    Hn = S[:, :, None] * H * S[:, None, :]
    diag = np.einsum("nii->ni", Hn).max(axis=1)
    live = batch.has & (np.abs(H).reshape(n, -1).max(axis=1) > 0)
    prior = damping * np.maximum(diag, 1e-12)
    lam = np.full(n, 1e-3)
    offset = np.zeros((n, 6))
    eye = np.eye(6)
    for _ in range(iterations):
        if not live.any():
            break
        Hn = S[:, :, None] * H * S[:, None, :]
        dmax = np.einsum("nii->ni", Hn).max(axis=1)
        gn = S * grad + prior[:, None] * offset / S
        pending = live.copy()
        for _ in range(6):
            if not pending.any():
                break
            A = Hn + ((prior + lam * dmax)[:, None, None] * eye)
            A[~pending] = eye
            try:
                stepn = -np.linalg.solve(A, gn[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                break
            stepn[~pending] = 0.0
            if max_step is not None:
                big = np.maximum(np.linalg.norm(stepn[:, :3], axis=1), np.linalg.norm(stepn[:, 3:], axis=1))
                stepn *= np.minimum(1.0, max_step / np.maximum(big, 1e-300))[:, None]
            step = stepn * S
            Rc = R.copy()
            tc = t.copy()
            for i in np.flatnonzero(pending):
                Rc[i] = pin.exp3(step[i, 3:]) @ R[i]
                tc[i] = t[i] + step[i, :3]
            c2, g2, H2, e2 = batch.evaluate(Rc, tc, True, pending)
            new_off = offset + step
            p_old = 0.5 * prior * np.sum((offset / S) ** 2, axis=1)
            p_new = 0.5 * prior * np.sum((new_off / S) ** 2, axis=1)
            ok = pending & (0.5 * c2 + p_new <= 0.5 * cost + p_old)
            R[ok], t[ok], offset[ok] = Rc[ok], tc[ok], new_off[ok]
            cost[ok], grad[ok], H[ok], ev[ok] = c2[ok], g2[ok], H2[ok], e2[ok]
            lam[ok] = np.maximum(lam[ok] * 0.3, 1e-6)
            bad = pending & ~ok
            lam[bad] *= 10.0
            pending = bad
        live &= ~pending  # a body that found no better step stops (as fit_body)
    return [
        BodyFit(pin.SE3(R[i], t[i]) if batch.has[i] else poses0[i], H[i], float(ev[i]), float(cost[i]))
        for i in range(n)
    ]
