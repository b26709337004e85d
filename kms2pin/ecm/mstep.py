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

E-step (:class:`kms2pin.ecm.estep.UnionEStep`).  For body i the pixels are soft-labelled
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
Gauss-Newton matrix ``H = JᵀJ`` is returned: the springs (:mod:`kms2pin.ecm.springs`) turn it into
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

import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .._numpy_kernels import H_CUT, closest
from ..native import kernels
from .camera import Camera
from .projection import BBox, body_bbox

#: pixels a body's box is grown by beyond its edge (h = -H_CUT)
SLACK_PX = 2.0

_WORLD_RAYS: weakref.WeakKeyDictionary[Camera, np.ndarray] = weakref.WeakKeyDictionary()


def _frozen(cls, **fields):
    """The frozen dataclass ``cls`` with ``fields`` (every one), made without its
    ``__init__``'s per-field ``object.__setattr__``: the E-step and the M-step make a box,
    a view and a fit per body (and camera) and iteration."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


def world_rays(camera: Camera) -> np.ndarray:
    """(H, W, 3) world directions of the pixel rays, scaled to unit camera depth (cached)."""
    r = _WORLD_RAYS.get(camera)
    if r is None:
        r = np.ascontiguousarray(camera.ray_grid @ np.asarray(camera.world_R_camera).T)
        r.flags.writeable = False
        _WORLD_RAYS[camera] = r
    return r


@dataclass
class BodyImage:
    """One body in one camera: the region it is evaluated on and its edge width.

    ``box`` is the pixel box (of the body's inner ellipsoid grown to reach
    ``h = -H_CUT`` plus ``slack_px``); ``dirs`` (N, 3) the world rays of its
    pixels, every ``stride``-th row and column; ``delta`` the edge width in
    ``a²/2`` units; ``s`` (set by the tracker's E-step) ``softplus(h) = -log(1 - s)``
    of the sharp silhouette ``s = σ(h)`` at the pose it was made for.
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
    slack_px: float = SLACK_PX,
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


def body_images(
    camera: Camera,
    poses: Sequence[pin.SE3],
    inners: Sequence[np.ndarray],
    delta_px: float,
    *,
    slack_px: float = SLACK_PX,
    max_pixels: int = 6000,
    arrays: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[BodyImage | None]:
    """:func:`body_image` of every body in one camera, the box arithmetic vectorized
    over bodies (same boxes and edge widths; distorted cameras and bodies that are
    not entirely in front of the camera go through :func:`body_image`).  ``arrays``:
    :func:`pose_arrays` of ``poses``, if the caller has them already."""
    n = len(poses)
    if n == 0:
        return []
    if camera.dist is not None:
        return [
            body_image(camera, P, L, delta_px, slack_px=slack_px, max_pixels=max_pixels) for P, L in zip(poses, inners)
        ]
    inner = np.asarray(inners, dtype=float).reshape(n, 3)
    Rs, ts = pose_arrays(poses) if arrays is None else arrays
    status, boxes, delta = body_box_arrays(camera, Rs, ts, inner, delta_px, slack_px)
    rays = world_rays(camera)
    out: list[BodyImage | None] = []
    for i, (st, (u0, v0, u1, v1), dl) in enumerate(zip(status.tolist(), boxes.astype(int).tolist(), delta.tolist())):
        if st == 0:  # behind the camera or out of the image
            out.append(None)
        elif st == 1:  # straddling, containing the camera or degenerate
            out.append(body_image(camera, poses[i], inner[i], delta_px, slack_px=slack_px, max_pixels=max_pixels))
        else:
            stride = max(1, math.ceil(math.sqrt((v1 - v0) * (u1 - u0) / max_pixels)))
            dirs = rays[v0:v1:stride, u0:u1:stride].reshape(-1, 3)
            out.append(BodyImage(camera, BBox(u0, v0, u1, v1), stride, dirs, dl))
    return out


def pose_arrays(poses: Sequence[pin.SE3]) -> tuple[np.ndarray, np.ndarray]:
    """The rotations (n, 3, 3) and translations (n, 3) of ``poses``."""
    return np.array([P.rotation for P in poses]), np.array([P.translation for P in poses])


def body_box_arrays(camera: Camera, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, delta_px: float, slack_px: float):
    """:func:`body_images`' per-body status (0: not in view, 1: per-body path, 2: box),
    boxes (n, 4: u0, v0, u1, v1) and edge widths of the bodies at rotations ``Rs`` and
    centres ``ts`` (the ``body_boxes`` kernel, :mod:`kms2pin.native`)."""
    n = len(Rs)
    H, W = camera.shape
    boxes, delta, status = np.zeros((n, 4)), np.empty(n), np.empty(n)
    kernels.body_boxes(Rs.reshape(n, 9), ts, inner, camera.world_R_camera, camera.centre, camera.K, float(delta_px),
                       float(slack_px), W, H, boxes, delta, status)
    return status, boxes, delta


def closest_approach(img: BodyImage, R: np.ndarray, t: np.ndarray, inner: np.ndarray, jac: bool):
    """``a²`` per pixel and, if ``jac``, its derivative -2 [g, q*×g] (N, 6) (module docstring)."""
    A = (R / inner**2) @ R.T
    e = img.camera.centre - t
    if not jac:
        a2 = np.empty(len(img.dirs))
        kernels.ellipsoid_a2(img.dirs, A, e, a2)
        return a2, None
    qs, g = closest(img.dirs, A, e)
    a2 = np.einsum("ij,ij->i", qs, g)
    D = np.empty((len(qs), 6))
    D[:, :3] = g
    D[:, 3:] = np.cross(qs, g)
    D *= -2.0
    return a2, D


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


@dataclass(frozen=True)
class PackedViews:
    """One E-step's views of every body as the ``estep_camera`` kernel leaves them (what
    the bodies' :class:`BodyView` hold, without an object per body and camera):
    ``cameras``, per camera, ``(dirs (N, 3), y (N,), o (N,), offset (n + 1,), centre (3,))``
    with body i's pixels at ``offset[i]:offset[i + 1]``; ``inv`` (cameras, n) ``1/(2δ)``;
    ``seen`` (cameras, n) 1 where the camera sees the body, else 0 (float64)."""

    cameras: list[tuple]
    inv: np.ndarray
    seen: np.ndarray


@dataclass(frozen=True)
class PackedFits:
    """Every body's :class:`BodyFit` as arrays: rotations ``R`` (n, 3, 3) and centres ``t``
    (n, 3) of the intermediate poses (world), Gauss-Newton matrices ``hessian`` (n, 6, 6),
    ``evidence`` and ``cost`` (n,)."""

    R: np.ndarray
    t: np.ndarray
    hessian: np.ndarray
    evidence: np.ndarray
    cost: np.ndarray

    def __len__(self) -> int:
        return len(self.R)

    def __getitem__(self, i: int) -> BodyFit:
        return BodyFit(pin.SE3(self.R[i], self.t[i]), self.hessian[i], float(self.evidence[i]), float(self.cost[i]))


def fit_packed(views: PackedViews, Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, *, iterations: int = 3,
               damping: float = 1e-3, max_step: float | None = None) -> PackedFits:
    """:func:`fit_bodies` on packed views (the same fits, in one kernel call), the bodies
    starting at rotations ``Rs`` (n, 3, 3) and centres ``ts`` (n, 3), semi-axes ``inner``."""
    n = len(Rs)
    R, t, H, out = np.empty((n, 9)), np.empty((n, 3)), np.empty((n, 36)), np.empty((n, 2))
    kernels.fit_bodies(views.cameras, views.inv, views.seen, np.ascontiguousarray(Rs).reshape(n, 9), ts,
                       np.asarray(inner, dtype=float), int(iterations), float(damping),
                       -1.0 if max_step is None else float(max_step), R, t, H, out)
    return PackedFits(R.reshape(n, 3, 3), t, H.reshape(n, 6, 6), out[:, 0], out[:, 1])


def body_cost(views: Sequence[BodyView], pose: pin.SE3, inner: np.ndarray, jac: bool):
    """Cost Σ wt r², gradient, Gauss-Newton matrix (6x6) and evidence of one body
    (the evidence and, without ``jac``, the gradient and matrix are 0)."""
    cost = 0.0
    H = np.zeros((6, 6))
    grad = np.zeros(6)
    evidence = 0.0
    R, t = pose.rotation, pose.translation
    A = (R / inner**2) @ R.T
    for v in views:
        c, e = kernels.silhouette_fit(
            v.image.dirs, A, v.image.camera.centre - t, 1.0 / (2.0 * v.image.delta), v.y, v.o, v.weight, jac, H, grad,
        )
        cost += c
        evidence += e
    return cost, grad, H, evidence


def fit_body(
    views: Sequence[BodyView],
    pose0: pin.SE3,
    inner: np.ndarray,
    *,
    iterations: int = 3,
    damping: float = 1e-3,
    max_step: float | None = None,
) -> BodyFit:
    """Refit one body's pose to its views by damped Gauss-Newton (module docstring).

    ``damping`` is the Tikhonov weight towards ``pose0`` relative to the largest
    curvature of the data (translations in body sizes, rotations in radians).
    ``max_step`` caps a step (the larger of its translation, in body sizes, and its
    rotation, in radians).
    """
    inner = np.asarray(inner, dtype=float)
    if not views:
        return BodyFit(pose0, np.zeros((6, 6)), 0.0, 0.0)
    R, t, H = np.empty((3, 3)), np.empty(3), np.empty((6, 6))
    evidence, cost = kernels.fit_body(
        [(v.image.dirs, v.image.camera.centre, 1.0 / (2.0 * v.image.delta), v.y, v.o, v.weight) for v in views],
        pose0.rotation, pose0.translation, inner, int(iterations), float(damping),
        -1.0 if max_step is None else float(max_step), R, t, H,
    )
    return _frozen(BodyFit, pose=pin.SE3(R, t), hessian=H, evidence=evidence, cost=cost)


def fit_bodies(
    views: Sequence[Sequence[BodyView]],
    poses0: Sequence[pin.SE3],
    inners: Sequence[np.ndarray],
    *,
    iterations: int = 3,
    damping: float = 1e-3,
    max_step: float | None = None,
) -> list[BodyFit]:
    """:func:`fit_body` for every body (``views[i]`` are body i's views); each body is
    fit on its own, the others held (conditional maximization)."""
    return [
        fit_body(v, p, np.asarray(L, dtype=float), iterations=iterations, damping=damping, max_step=max_step)
        for v, p, L in zip(views, poses0, inners)
    ]


def body_scale_cost(views: Sequence[BodyView], R: np.ndarray, t: np.ndarray, inner: np.ndarray):
    """Cost, gradient and Gauss-Newton matrix (3x3) of one body's silhouette fit in the
    log semi-axes of its inner ellipsoid, the pose held (:func:`fit_body_scale`)."""
    cost, grad, H = 0.0, np.zeros(3), np.zeros((3, 3))
    A = (R / inner**2) @ R.T
    for v in views:
        cost += kernels.scale_fit(
            v.image.dirs, A, v.image.camera.centre - t, R, inner, 1.0 / (2.0 * v.image.delta), v.y, v.o, v.weight,
            H, grad,
        )
    return cost, grad, H


def fit_body_scale(
    views: Sequence[BodyView],
    pose: pin.SE3,
    inner: np.ndarray,
    *,
    iterations: int = 4,
    prior: float = 1e-2,
    max_log_scale: float = 0.35,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis scale of a body's inner ellipsoid fitted to its views with its pose held.

    The same silhouette cost as :func:`fit_body` (module docstring), minimized over
    ``log L_k`` (the body's semi-axes) by damped Gauss-Newton.  ``prior`` pulls
    towards the given size, relative to the data's largest curvature, so an axis the
    images do not see (one along every camera's viewing ray) keeps its size; each
    log-scale stays within ``±max_log_scale``.  Returns the factors (3,) that multiply
    ``inner`` and the Gauss-Newton matrix (3x3, in log semi-axes) at the result.
    """
    inner = np.asarray(inner, dtype=float)
    R, t = np.asarray(pose.rotation), np.asarray(pose.translation)
    x = np.zeros(3)
    if not views:
        return np.ones(3), np.zeros((3, 3))
    cost, grad, H = body_scale_cost(views, R, t, inner)
    if not np.any(H):
        return np.ones(3), H
    lam_p = prior * float(np.max(np.diag(H)))
    lam = 1e-3
    for _ in range(iterations):
        improved = False
        for _ in range(6):
            A = H + (lam_p + lam * float(np.max(np.diag(H)))) * np.eye(3)
            step = -np.linalg.solve(A, grad + lam_p * x)
            x_new = np.clip(x + step, -max_log_scale, max_log_scale)
            c2, g2, H2 = body_scale_cost(views, R, t, inner * np.exp(x_new))
            if 0.5 * c2 + 0.5 * lam_p * x_new @ x_new <= 0.5 * cost + 0.5 * lam_p * x @ x:
                x, cost, grad, H = x_new, c2, g2, H2
                lam = max(lam * 0.3, 1e-6)
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
    return np.exp(x), H
