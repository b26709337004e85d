"""ECM tracking (thesis §2.1.2): E-step, 3-D M-step per body, static update, per frame.

Each frame starts from the previous result (or a constant-velocity prediction)
and iterates E -> M -> constrain until the configuration stops changing:

1. E-step (:func:`kms2pin.ecm.mstep.body_image` + the union in :meth:`Tracker.step`):
   in every camera each body's sharp silhouette ``s_j`` is evaluated at the
   current (kinematically valid) pose and every body learns how much of each
   pixel the *others* explain, ``o_i = 1 - Π_{j≠i}(1 - s_j)`` (soft labels).
2. M-step (:func:`kms2pin.ecm.mstep.fit_body`): each body's 6-DoF pose is refit
   on its own to the mask, the others held: the intermediate bodies.
3. Static update (:func:`kms2pin.static_update`): springs between primary and
   intermediate bodies pull the configuration back to a valid one.  Every
   coordinate of every body gets its own stiffness, read off the M-step's
   Gauss-Newton matrix (the thesis: "k may be different for every coordinate of
   every body ... to compensate for noise or ambiguities"): a body seen edge-on,
   along the viewing ray, or mostly hidden has soft springs in the directions
   the images do not fix, so the well-seen bodies carry it.  With the M-step's
   own curvature as the springs, M-step + static update is close to one
   Gauss-Newton step on the whole-body silhouette fit in joint space.

The edge width ``δ`` of the sharp silhouettes is annealed from ``delta_start``
to ``delta_final`` pixels over the first iterations of a frame (a wide edge
for capture range, a narrow one for accuracy).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import contextmanager

import cv2
import numpy as np
import pinocchio as pin

from ..errors import CameraError, InputDataError, OptionError, did_you_mean
from ..native import kernels as _kernels
from ..robot import Robot
from ..virtual_work import _structure, body_frames, static_update
from . import mstep as _mstep
from .camera import Camera
from .limbs import left_right_joints, limb_joints, sagittal_mirror, twin_limbs
from .mstep import BodyImage, BodyView, _geometry, body_images, fit_bodies, fit_body_scale, pose_arrays, world_rays
from .projection import BBox, body_bbox
from .trajectory import FrameResult, Trajectory, TrajectoryCsvWriter

__all__ = [
    "SEGMENTED_MASKS", "FrameResult", "Tracker", "Trajectory", "TrajectoryCsvWriter", "bin_mask", "clean_mask", "limb_joints",
]


def clean_mask(mask: np.ndarray) -> np.ndarray:
    """3x3 median filter: removes isolated flipped pixels and 1-pixel specks and
    holes, smooths ragged outlines by a pixel."""
    return cv2.medianBlur(mask.astype(np.uint8), 3).astype(bool)


def bin_mask(mask: np.ndarray, factor: int = 2) -> np.ndarray:
    """The fraction of each ``factor`` x ``factor`` block of ``mask`` that is set
    (float64, the image of :meth:`Camera.binned`; a last partial block is dropped)."""
    f = int(factor)
    h, w = mask.shape[0] // f, mask.shape[1] // f
    if h == 0 or w == 0:
        return np.zeros((h, w))
    m = np.asarray(mask[: h * f, : w * f], dtype=np.float32)
    return cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)


def _newton_step(A: np.ndarray, g: np.ndarray, native: bool) -> np.ndarray:
    """The Gauss-Newton step -A⁻¹ g, with A shifted by 1e-9 of its largest diagonal entry
    (Cholesky in C, else LU; ``A`` may be changed)."""
    n = len(g)
    shift = 1e-9 * max(float(A.diagonal().max()), 1e-300) if n else 0.0
    dq = np.empty(n)
    if not (native and _kernels.solve_shifted(A, g, shift, dq)):
        A[np.diag_indices(n)] += shift
        dq = -np.linalg.solve(A, g)
    return dq


def _delta_to_stiffness(H: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Diagonal spring stiffness on [mu, theta0..3] (7,) from a 6x6 Gauss-Newton matrix
    in (world translation, world rotation vector): δθ = ½ E(θ) ω and ω = 2 E(θ)ᵀ δθ,
    so the rotational energy ½ ωᵀ H_ωω ω is ½ δθᵀ (4 E H_ωω Eᵀ) δθ."""
    w, x, y, z = theta
    E = np.array([[-x, -y, -z], [w, z, -y], [-z, w, x], [y, -x, w]])  # [0, ω] ⊗ θ / ... (world ω)
    Kth = 4.0 * E @ H[3:, 3:] @ E.T
    return np.r_[np.diag(H[:3, :3]), np.diag(Kth)]


_I6 = np.arange(6)
#: halvings of a static-update step that raises the springs' energy before it gives up
_BACKTRACK = 4
#: bounds of the calibrated body sizes relative to the model's (:meth:`Tracker.calibrate`)
_SCALE_MIN, _SCALE_MAX = float(np.exp(-0.35)), float(np.exp(0.35))
#: pull of the refined body sizes towards the spec's, relative to a body's largest size
#: information (:meth:`Tracker._refine_sizes`)
_SIZE_PRIOR = 0.01


def _quat_mul_conj(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊗ conj(b) for (n, 4) quaternions in (x, y, z, w) order."""
    av, aw, bv, bw = a[:, :3], a[:, 3:], b[:, :3], b[:, 3:]
    out = np.empty_like(a)
    out[:, 3:] = aw * bw + np.sum(av * bv, axis=1, keepdims=True)
    out[:, :3] = bw * av - aw * bv - np.cross(av, bv)
    return out


def _log_quat(qr: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of unit quaternions (n, 4), (x, y, z, w): angle in [0, pi]."""
    v, w = qr[:, :3], qr[:, 3]
    sign = np.where(w < 0, -1.0, 1.0)
    v, w = v * sign[:, None], w * sign
    nv = np.linalg.norm(v, axis=1)
    small = nv < 1e-12
    scale = np.where(small, 2.0 / np.maximum(w, 1e-300), 2.0 * np.arctan2(nv, w) / np.where(small, 1.0, nv))
    return v * scale[:, None]


_KIND_WORDS = {"mirror": "mirror", "swap": "left/right-swapped", "limb": "limb-search"}
_MERGE = np.radians(10.0)  # an alternative hypothesis this close to the main one is dropped
#: limb search (``Tracker(limb_search=...)``): a joint closer to its rest angle than this
#: is not swung; the IoU a swung limb must gain to be kept; the ECM iterations (binned
#: masks) a candidate is screened with; how many of the best screened are refined (a
#: candidate that has further to go screens lower)
_LIMB_MIN = np.radians(5.0)
_LIMB_GAIN = 0.003
_LIMB_ITERATIONS = 3
_LIMB_REFINED = 2
#: a limb-search hypothesis (``Tracker(limb_hypothesis=...)``) whose running fit falls this
#: far behind the main one's is dropped
_LIMB_BEHIND = 0.02
#: twin limbs whose first joints come this close, or pass each other, have crossed
#: (side-on, they overlap); for this many frames after, their exchange is tried
_CROSS_DEG = np.radians(8.0)
_CROSS_FRAMES = 4
_LIMB_AND = " and "  # joins the two joints of a twin limbs' exchange
_LIMB_RESET = " reset"  # follows the joint of a limb whose joints below it were put back at rest
#: Tracker options for masks from a real segmentation (``track --video`` uses them): its
#: fit is noisy, and the limb search on a drop of 0.015 fired on many frames, where 0.03
#: tracked ten segmented clips as well at 1.5-2.5x the frames/s.  Until the segmentation
#: learnt the background from the temporal mode it also kept the first frame's sizes
#: (``size_every=0``): the false blob the median left beside the subject was a systematic
#: error the size refinement took up.  Without it the refinement helps two cameras on all
#: ten clips (0.22-0.35 % of the height against 0.26-0.39 %; with a cast shadow 0.31-0.34
#: against 0.38-0.44 % on four): docs/tracking.md, video
SEGMENTED_MASKS = {"limb_search_drop": 0.03}


#: numeric options of :class:`Tracker`: name -> (lowest, highest, whether the lowest is
#: excluded, whether a whole number, whether None is allowed)
_RANGES = {
    "max_iterations": (1, None, False, True, False),
    "min_iterations": (1, None, False, True, False),
    "tol_deg": (0.0, None, False, False, False),
    "tol_px": (0.0, None, True, False, True),
    "delta_start": (0.0, None, True, False, False),
    "delta_final": (0.0, None, True, False, False),
    "coarse_delta_px": (0.0, None, True, False, True),
    "m_iterations": (1, None, False, True, False),
    "damping": (0.0, None, False, False, False),
    "stiffness_floor": (0.0, None, False, False, False),
    "max_pixels": (1, None, False, True, False),
    "static_iterations": (1, None, False, True, False),
    "outlier": (0.0, 1.0, False, False, False),
    "outlier_px": (0.0, None, True, False, False),
    "max_step": (0.0, None, True, False, True),
    "poor_fit": (0.0, 1.0, False, False, False),
    "max_prediction_deg": (0.0, None, False, False, False),
    "size_every": (0, None, False, True, False),
    "size_iterations": (1, None, False, True, False),
    "hypothesis_smoothing": (0.0, 1.0, True, False, False),
    "mirror_margin": (0.0, None, False, False, False),
    "swap_margin": (0.0, None, False, False, False),
    "hypothesis_iterations": (1, None, False, True, True),
    "depth_prior": (0.0, None, False, False, False),
    "upright": (0.0, None, False, False, False),
    "rest_prior": (0.0, None, False, False, False),
    "limb_search_drop": (-np.inf, None, False, False, False),  # negative: search on every frame
    "limb_hypothesis_drop": (-np.inf, None, False, False, False),
    "limb_margin": (0.0, None, False, False, False),
}


def _check_options(options: dict) -> None:
    """Raise :class:`OptionError` for a numeric option of :class:`Tracker` that is of the
    wrong type, not finite or out of its range (``_RANGES``)."""
    for name, (lo, hi, open_lo, whole, none_ok) in _RANGES.items():
        value = options[name]
        if value is None and none_ok:
            continue
        kinds = (int, np.integer) if whole else (int, float, np.integer, np.floating)
        if isinstance(value, bool) or not isinstance(value, kinds):
            what = "a whole number" if whole else "a number"
            raise OptionError(f"{name} must be {what}{' or None' if none_ok else ''}, not {value!r}")
        low_ok = value > lo if open_lo else value >= lo
        if not (np.isfinite(value) and low_ok and (hi is None or value <= hi)):
            bound = f"{'>' if open_lo else '>='} {lo}" + (f" and <= {hi}" if hi is not None else "")
            raise OptionError(f"{name} must be {bound}{' or None' if none_ok else ''}, not {value!r}")


class Tracker:
    """ECM tracker for one robot seen by one or more cameras (thesis §2.1.2).

    Per frame: E-step, M-step and static update (eq. 2.28, springs eq. 2.33) until
    the pose settles.  Measurements: docs/tracking.md.

    Args:
        robot: the model (``root="free"`` for a moving subject).
        cameras: one :class:`Camera` per mask stream, or a single camera.
        q0: starting pose (default ``robot.q_rest``); every camera must see part of
            the model there, else :class:`CameraError`.
        max_iterations, min_iterations: most and fewest ECM iterations per frame.
        tol_deg, tol_px: a frame has converged when no joint moves more than ``tol_deg``
            (degrees; the root's translation: 1 % of the model height as 1°) or no body's
            outline more than ``tol_px`` pixels in any camera (None: joints only; one
            camera then ran 7.4 iterations a frame, not 5.0).
        prediction: ``"constant_velocity"`` (the last frame's motion) or ``"previous"``.
        delta_start, delta_final: edge width of the sharp silhouettes (pixels), halved
            each iteration from the first to the second; 2.8 = 4 x 0.7 reaches 0.7 on the
            third (3.0 on the fourth; 2.8 is 1.25x as fast).
        coarse_delta_px: iterations whose edge is at least this wide (pixels, above
            ``delta_final``) run binned 2x2 (:meth:`Camera.binned`).  None: off (it
            cost one camera accuracy).
        m_iterations: Gauss-Newton iterations of each body's M-step.
        damping: M-step pull towards the body's pose from the joints, relative to its
            largest data curvature: a body the images hardly fix stays put.  0.05: one
            camera 2.5 % against 3.7 % with 0.01 (docs/tracking.md, M-step damping).
        stiffness_floor: spring stiffness floor, a fraction of the stiffest body's (added
            to every spring with ``static="full"``, a lower bound with ``"diagonal"``).
        max_pixels: pixels per body and camera above which the M-step subsamples.
        static, static_iterations: springs (eq. 2.33) ``"full"`` 6x6 per body (the
            M-step's Gauss-Newton matrix) or the thesis's ``"diagonal"``; the Gauss-Newton
            steps of ``"full"`` (``"diagonal"`` runs to convergence).
        clean: 3x3 median-filter the masks (:func:`clean_mask`); off, as it also removes
            thin detail (hands) and did not help the noisy benchmark.
        outlier, outlier_px: outlier class; a pixel weighs ``p / (p + outlier)``, ``p`` its
            probability under the bodies' union with an edge at least ``outlier_px`` wide.
            0 (off): on the noisy walk even 0.01 made the track diverge.
        max_step: cap on an M-step step (mean semi-axes or radians; None: no cap).
        poor_fit: a frame fitting worse (IoU with the masks) is flagged ``"poor fit
            (...)"`` and passes no velocity on.
        max_prediction_deg: cap on each joint's predicted motion per frame (degrees; root
            translation as in ``tol_deg``), against spinning.
        scales: (n_bodies, 3) factors on the spec's semi-axes to start from (default 1).
        calibrate_sizes: fit the scales on the first frame at ``q0`` (:meth:`calibrate`;
            it cut multi-camera errors by 29-63 %); off if that frame is not at ``q0``.
        size_every: refine calibrated sizes on frames 0, n, 2n, ... that fit at least as
            well as the running fit and have no flag (10 % size error, one camera: 0.97 %
            against 1.29 %).  0 keeps the first frame's, for masks with systematic
            errors (docs/tracking.md, size refinement).
        size_iterations: E-step / size-fit rounds of the calibration.
        mirror_hypothesis, swap_hypothesis: also track the pose's mirror image in the
            camera, and the pose with left/right joints exchanged (None: with one camera,
            a free root and left/right bodies; the swap only with joint limits).
        hypothesis_smoothing: a new frame's weight in every hypothesis's running fit
            (IoU); switches and the limb search wait about 1 / this frames.
        mirror_margin, swap_margin, limb_margin: how far an alternative's running fit
            must lead the main one's to replace it (flag ``"switched to the ..."``).
        hypothesis_iterations: ECM iterations of each alternative a frame (None: as
            ``max_iterations``); fewer are faster but lose turns.
        binned_hypotheses: track the alternatives binned 2x2 (1.25-1.38x the frames/s,
            less accurate).
        depth_prior: spring holding a free root's distance along each camera's ray at the
            prediction, times the root translation's mean stiffness (0: off; it saved no
            lost track).
        upright, up: spring keeping along ``up`` (world, default +y) the free root's axis
            that is so at ``q0``, times the root rotation's mean stiffness (0: off).
            0.1 for upright subjects seen by one camera: a lost full body tracked to
            3-4.6 % (docs/tracking.md, upright prior).
        rest_prior: spring pulling every joint, not the root, towards the spec's rest
            pose, times the joints' mean stiffness (0: off).  0.01 for subjects near rest
            seen by one camera: joint error 10.6° -> 8.2° (docs/tracking.md, rest prior).
        limb_search, limb_search_drop: when the fit falls more than the drop below the
            running fit, try every limb (:func:`limb_joints`) swung the other way or put
            back at rest below its first joint, and twin limbs exchanged; keep the best
            if it fits better (one camera: also after twins cross).  On (None too;
            one-camera walk 2.6 % -> 1.9 %).  0.03 for segmented masks; negative: every
            frame (docs/tracking.md, limb search).
        limb_hypothesis, limb_hypothesis_drop: on a smaller fall, beyond this drop,
            track the best candidate as an alternative instead (None: with one camera and
            the limb search): the hand's worst seed 10.1 % -> 4.4 %.
    """

    def __init__(
        self,
        robot: Robot,
        cameras: Camera | Sequence[Camera],
        *,
        q0=None,
        max_iterations: int = 8,
        min_iterations: int = 3,
        tol_deg: float = 0.2,
        tol_px: float | None = 0.25,
        prediction: str = "constant_velocity",
        delta_start: float = 2.8,
        delta_final: float = 0.7,
        coarse_delta_px: float | None = None,
        m_iterations: int = 2,
        damping: float = 5e-2,
        stiffness_floor: float = 1e-2,
        max_pixels: int = 1_000_000,
        static: str = "full",
        static_iterations: int = 3,
        clean: bool = False,
        outlier: float = 0.0,
        outlier_px: float = 3.0,
        max_step: float | None = 0.5,
        poor_fit: float = 0.5,
        max_prediction_deg: float = 20.0,
        scales=None,
        calibrate_sizes: bool = True,
        size_every: int = 5,
        size_iterations: int = 4,
        mirror_hypothesis: bool | None = None,
        swap_hypothesis: bool | None = None,
        hypothesis_smoothing: float = 0.2,
        mirror_margin: float = 0.0,
        swap_margin: float = 0.01,
        hypothesis_iterations: int | None = None,
        binned_hypotheses: bool = False,
        depth_prior: float = 0.0,
        upright: float = 0.0,
        up=(0.0, 1.0, 0.0),
        rest_prior: float = 0.0,
        limb_search: bool | None = None,
        limb_search_drop: float = 0.015,
        limb_hypothesis: bool | None = None,
        limb_hypothesis_drop: float = 0.005,
        limb_margin: float = 0.005,
        **unknown,
    ):
        if unknown:
            name = next(iter(unknown))
            raise TypeError(f"Tracker got an unknown option '{name}'{did_you_mean(name, _OPTIONS)}")
        _check_options(locals())
        if prediction not in ("constant_velocity", "previous"):
            raise OptionError(f"prediction must be 'constant_velocity' or 'previous', not {prediction!r}")
        self.robot = robot
        self.cameras = [cameras] if isinstance(cameras, Camera) else list(cameras)
        if not self.cameras:
            raise OptionError("a tracker needs at least one camera")
        if min_iterations > max_iterations:
            raise OptionError(f"min_iterations ({min_iterations}) must not exceed max_iterations ({max_iterations})")
        if not delta_final <= delta_start:
            raise OptionError(f"delta_start ({delta_start}) must not be below delta_final ({delta_final})")
        self.max_iterations = int(max_iterations)
        self.min_iterations = int(min_iterations)
        self.tol = np.radians(tol_deg)
        self.tol_px = None if tol_px is None else float(tol_px)
        self.depth_prior = float(depth_prior)
        self.upright = float(upright)
        self.rest_prior = float(rest_prior)
        up = np.asarray(up, dtype=float)
        norm = float(np.linalg.norm(up)) if up.shape == (3,) else 0.0
        if not (np.isfinite(norm) and norm > 0.0):
            raise OptionError(f"up must be a non-zero 3-vector, not {up.tolist()!r}")
        self.up = up / norm
        self.limb_search = True if limb_search is None else bool(limb_search)
        self.limb_search_drop = float(limb_search_drop)
        if limb_hypothesis is None:
            limb_hypothesis = len(self.cameras) == 1
        self.limb_hypothesis = bool(limb_hypothesis) and self.limb_search
        self.limb_hypothesis_drop, self.limb_margin = float(limb_hypothesis_drop), float(limb_margin)
        # limbs: joint name -> (its q index, q indices of the revolute joints below it)
        m = robot.model
        self._limbs = {}
        for name in limb_joints(robot):
            j = m.getJointId(name)
            below = [m.joints[k].idx_q for k in m.subtrees[j][1:] if m.joints[k].nq == 1]
            self._limbs[name] = (m.joints[j].idx_q, np.array(below, dtype=int))
        self._limb_pairs = twin_limbs(robot, list(self._limbs))
        self._scratch: dict[tuple, np.ndarray] = {}  # per camera and size: the E-step's union image (_zeroed)
        self._fk: tuple | None = None  # _body_poses' last configuration and poses
        self._anchor: np.ndarray | None = None  # the root's position at the frame's start (depth_prior)
        self.prediction = prediction
        self.delta_start, self.delta_final = float(delta_start), float(delta_final)
        self.coarse_delta_px = None if coarse_delta_px is None else float(coarse_delta_px)
        if self.coarse_delta_px is not None and not self.coarse_delta_px > self.delta_final:
            raise OptionError(
                f"coarse_delta_px must be above delta_final ({self.delta_final}) or None, not {coarse_delta_px!r}"
            )
        # each camera binned 2x2, for the wide-edge iterations (coarse_delta_px)
        self._binned = {c: c.binned(2) for c in self.cameras if min(c.width, c.height) >= 8}
        self.m_iterations, self.damping = m_iterations, damping
        self.stiffness_floor = stiffness_floor
        self.max_pixels = max_pixels
        if static not in ("full", "diagonal"):
            raise OptionError(f"static must be 'full' or 'diagonal', not {static!r}")
        self.static, self.static_iterations = static, static_iterations
        self.clean = clean
        self.outlier, self.outlier_px = float(outlier), float(outlier_px)
        self.max_step = max_step
        self.poor_fit = float(poor_fit)
        self.max_prediction = np.radians(float(max_prediction_deg))
        # (n_bodies, 3) semi-axes: the spec's, and those times the measured scales
        self._spec_inner = np.array([robot.inner(b) for b in robot.bodies], dtype=float).reshape(-1, 3)
        self._spec_outer = np.array([robot.outer(b) for b in robot.bodies], dtype=float).reshape(-1, 3)
        self.scales = np.ones((len(robot.bodies), 3))
        if scales is not None:
            sc = np.asarray(scales, dtype=float)
            if sc.shape != self.scales.shape or not np.all(sc > 0):
                raise OptionError(f"scales must be positive, shape {self.scales.shape}; got shape {sc.shape}")
            self.scales = sc.copy()
        self.inner = self._spec_inner * self.scales
        self.outer = self._spec_outer * self.scales
        self.calibrate_sizes, self.size_iterations = bool(calibrate_sizes), int(size_iterations)
        self._calibrated = False
        self.size_every = int(size_every)
        # the evidence on the body sizes so far (:meth:`_refine_sizes`): per body the sum of
        # its size fits' Gauss-Newton matrices (in log semi-axes), and of those matrices
        # times the fitted log-scales
        self._size_info = np.zeros((len(robot.bodies), 3, 3))
        self._size_rhs = np.zeros((len(robot.bodies), 3))
        self._alts: dict[str, list] = {}  # alternative hypotheses: kind -> [q, previous q, score, fit]
        self._reset(robot.q_rest if q0 is None else q0, "initial pose")
        self._root_dofs = 3 if robot.root == "free" else 0
        # the joints' velocity indices (rest_prior: every dof but the free root's six)
        self._joint_dofs = np.arange(6 if self._root_dofs else 0, robot.model.nv)
        # the limited joints' q and velocity indices (the static update's active set)
        lim = [
            (robot.model.joints[j].idx_q, robot.model.joints[j].idx_v)
            for j in range(1, robot.model.njoints)
            if robot.model.joints[j].nq == 1 and np.isfinite(robot.lower_limits[robot.model.joints[j].idx_q])
        ]
        self._limited = (np.array([a for a, _ in lim], dtype=int), np.array([b for _, b in lim], dtype=int))
        # the root's own axis that is vertical at q0 (root frame)
        self._up_root = pin.XYZQUATToSE3(self.q[:7]).rotation.T @ self.up if self._root_dofs else None
        if self._root_dofs:  # constants of the upright spring (_upright_spring)
            self._up_projector = np.eye(3) - np.outer(self._up_root, self._up_root)
            self._up_skew = pin.skew(self.up)
        self._sagittal = sagittal_mirror(robot) if robot.root == "free" else None
        if mirror_hypothesis is None:
            mirror_hypothesis = len(self.cameras) == 1 and self._sagittal is not None
        if mirror_hypothesis and self._sagittal is None:
            raise ValueError("mirror_hypothesis needs root='free' and left/right bodies (names with left/right)")
        self.mirror_hypothesis = bool(mirror_hypothesis)
        self._swap_pairs = left_right_joints(robot, self._sagittal)
        if swap_hypothesis is None:
            # without joint limits a swapped leg finds a pose (a knee bent backwards) that
            # fits as well, and the swaps did more harm than good on the benchmark
            swap_hypothesis = len(self.cameras) == 1 and self._swap_pairs is not None and robot.has_limits
        if swap_hypothesis and self._swap_pairs is None:
            raise ValueError(
                "swap_hypothesis needs left/right joints (names left*/right*) whose exchange mirrors the body"
            )
        self.swap_hypothesis = bool(swap_hypothesis)
        self.hypothesis_smoothing = float(hypothesis_smoothing)
        self.mirror_margin, self.swap_margin = float(mirror_margin), float(swap_margin)
        self.binned_hypotheses = bool(binned_hypotheses)
        self.hypothesis_iterations = (
            self.max_iterations if hypothesis_iterations is None else max(1, int(hypothesis_iterations))
        )
        for c, cam in enumerate(self.cameras):
            if not self.visible_bodies(cameras=[cam]):
                name = f" '{cam.name}'" if cam.name else ""
                raise CameraError(
                    f"camera {c}{name} does not see the model at the starting pose: no body of "
                    f"'{robot.system.name}' falls in its {cam.width}x{cam.height} image (camera at "
                    f"{np.round(cam.centre, 3).tolist()}); check the camera's placement or the initial pose"
                )

    # ------------------------------------------------------------------ checks
    def visible_bodies(self, q: np.ndarray | None = None, cameras: Sequence[Camera] | None = None) -> list[int]:
        """Indices of bodies whose inner silhouette falls in at least one camera."""
        poses = self.robot.body_poses(self.q if q is None else q)
        cams = self.cameras if cameras is None else cameras
        return [i for i, P in enumerate(poses) if any(body_bbox(c, P, self.inner[i], 0) is not None for c in cams)]

    def _masks(self, masks, source: str) -> list[np.ndarray]:
        if isinstance(masks, np.ndarray) and masks.ndim == 2:
            masks = [masks]
        masks = list(masks)
        if len(masks) != len(self.cameras):
            raise InputDataError(f"{source}: {len(masks)} masks for {len(self.cameras)} cameras")
        out = []
        for k, (m, cam) in enumerate(zip(masks, self.cameras)):
            m = np.asarray(m)
            if m.ndim != 2 or m.shape != cam.shape:
                size = f"{m.shape[1]}x{m.shape[0]}" if m.ndim == 2 else f"of shape {m.shape}"
                raise InputDataError(f"{source}: camera {k} mask is {size} but the camera is {cam.width}x{cam.height}")
            m = m.astype(bool) if m.dtype != bool else m
            if self.clean and m.any():
                m = clean_mask(m)
            out.append(m)
        return out

    def fit(self, q: np.ndarray, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame") -> float:
        """The silhouette fit at ``q``: the intersection over union of the model's inner
        ellipsoids (at the tracker's current body sizes) with ``masks``, pooled over
        every camera, as :attr:`FrameResult.fit` reports it for a frame that every camera
        sees.  E.g. to ask whether a pose the tracker did not choose fits the images as
        well (``benchmarks/ecm.py`` compares the true poses' fit with the tracked ones')."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.model.nq,):
            raise ValueError(f"q has shape {q.shape}; the model has nq = {self.robot.model.nq}")
        return self._iou(q, self._masks(masks, source))

    def _iou(self, q: np.ndarray, masks: Sequence[np.ndarray]) -> float:
        poses, Rs, ts = self._body_poses(q)
        inter = union = 0
        for cam, mask in zip(self.cameras, masks):
            model = np.zeros(cam.shape, dtype=bool)
            images = body_images(cam, poses, self.inner, 0.5, slack_px=0.0, max_pixels=10**9, arrays=(Rs, ts))
            for P, li, img in zip(poses, self.inner, images):
                if img is None:
                    continue
                a2, _ = _geometry(img, P.rotation, P.translation, li, False)
                model[img.slices] |= (a2 <= 1.0).reshape(img.shape)
            inter += int(np.count_nonzero(model & mask))
            union += int(np.count_nonzero(model | mask))
        return inter / union if union else 1.0

    # ------------------------------------------------------------------ ECM
    def _body_poses(self, q: np.ndarray):
        """The body poses at ``q`` and their :func:`pose_arrays`, kept for the last ``q``
        asked for: the outline test after an iteration, the next iteration's E-step and
        the fit of the frame's result all want the same ones."""
        key = np.asarray(q, dtype=float).tobytes()
        if self._fk is None or self._fk[0] != key:
            poses = self.robot.body_poses(q)
            self._fk = (key, poses, *pose_arrays(poses))
        return self._fk[1:]

    def _outline_points(self, q: np.ndarray) -> np.ndarray:
        """World points (n_bodies * 7, 3) that outline the bodies at ``q``: each inner
        ellipsoid's centre and the two ends of each of its axes."""
        _, R, t = self._body_poses(q)  # (n, 3, 3), (n, 3)
        ends = R * self.inner[:, None, :]  # (n, 3, 3): column k = axis k's half length
        pts = np.concatenate([t[:, None], t[:, None] + ends.transpose(0, 2, 1), t[:, None] - ends.transpose(0, 2, 1)], 1)
        return pts.reshape(-1, 3)

    def _outline_pixels(self, q: np.ndarray) -> list[np.ndarray]:
        """:meth:`_outline_points` projected into every camera (NaN behind it)."""
        pts = self._outline_points(q)
        return [cam.project(pts) for cam in self.cameras]

    def _image_motion(self, a: list[np.ndarray], b: list[np.ndarray]) -> float:
        """Largest image displacement (pixels, over the cameras) between two sets of
        :meth:`_outline_pixels`; points behind a camera are left out."""
        moved = 0.0
        for pa, pb in zip(a, b):
            d = np.linalg.norm(pa - pb, axis=1)
            d = d[np.isfinite(d)]
            if len(d):
                moved = max(moved, float(d.max()))
        return moved

    def _change(self, q0: np.ndarray, q1: np.ndarray) -> float:
        """Largest joint change (rad); root translation in hundredths of the height per degree."""
        dq = np.abs(pin.difference(self.robot.model, q0, q1))
        if self._root_dofs:
            dq[:3] *= np.radians(1.0) / (0.01 * self.robot.height)
        return float(dq.max()) if len(dq) else 0.0

    def calibrate(
        self, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame", q: np.ndarray | None = None
    ) -> np.ndarray:
        """Fit every body's semi-axes to ``masks`` with the configuration held at ``q``
        (default: the current pose, i.e. ``q0`` before the first frame).

        The model's sizes rarely match the subject's.  In one view a body that is too
        long or too wide is otherwise explained by tilting or turning it (a 10 % length
        error equals a 26° tilt), so the first frame, whose pose is known, is used to
        measure them: per body and axis a log-scale is fit by Gauss-Newton to the
        silhouette cost of the M-step (:func:`kms2pin.ecm.mstep.fit_body_scale`),
        alternating with the E-step as the edge width anneals.  Axes no camera sees
        (along the viewing ray) keep the model's size.  Returns the scale factors
        (n_bodies, 3) relative to the model, also kept in :attr:`scales`.  The last
        round's fits are the first evidence of the size refinement (``size_every``,
        :meth:`_refine_sizes`); calling this again starts that evidence afresh.
        """
        masks = self._masks(masks, source)
        q = self.q if q is None else np.asarray(q, dtype=float)
        delta = self.delta_start
        for _ in range(max(1, self.size_iterations)):
            poses, views = self.e_step(q, masks, delta)
            for i, v in enumerate(views):
                f, H = fit_body_scale(v, poses[i], self.inner[i], iterations=2)
                self._set_scales(i, self.scales[i] * f)
                self._size_info[i] = H
                self._size_rhs[i] = H @ np.log(self.scales[i])
            delta = max(self.delta_final, 0.5 * delta)
        self._calibrated = True
        return self.scales.copy()

    def _refine_sizes(self, q: np.ndarray, masks) -> None:
        """Fold a tracked frame's evidence on the body sizes into :attr:`scales`.

        Each body's log semi-axes are fit to the frame with the pose held at ``q`` (as
        in :meth:`calibrate`), giving an estimate ``x_k`` and its Gauss-Newton matrix
        ``H_k``.  The sizes become the information-weighted mean of every frame's so
        far, the first frame's (the calibration) included, pulled towards the spec's by
        ``_SIZE_PRIOR`` of the largest information: ``x = (Σ H_k + λ I)⁻¹ Σ H_k x_k``.
        An axis along the viewing ray has no information in that frame, so it keeps its
        estimate until the subject turns it into view.
        """
        poses, views = self.e_step(q, masks, self.delta_final)
        for i, v in enumerate(views):
            f, H = fit_body_scale(v, poses[i], self.inner[i], iterations=2)
            self._size_info[i] += H
            self._size_rhs[i] += H @ np.log(self.scales[i] * f)
            info = self._size_info[i]
            lam = _SIZE_PRIOR * float(np.max(np.diag(info)))
            if lam <= 0.0:  # nothing seen of this body yet
                continue
            self._set_scales(i, np.exp(np.linalg.solve(info + lam * np.eye(3), self._size_rhs[i])))

    def _set_scales(self, i: int, scales: np.ndarray) -> None:
        """Body ``i``'s semi-axis factors (clipped to the calibration's bounds) and its
        inner and outer ellipsoids to match."""
        self.scales[i] = np.clip(scales, _SCALE_MIN, _SCALE_MAX)
        self.inner[i] = self._spec_inner[i] * self.scales[i]
        self.outer[i] = self._spec_outer[i] * self.scales[i]

    def iterate(
        self,
        q: np.ndarray,
        masks: Sequence[np.ndarray],
        delta_px: float,
        timings: dict,
        cameras: Sequence[Camera] | None = None,
    ) -> np.ndarray:
        """One ECM iteration (E-step, M-step, static update) from ``q``; returns the new q.
        ``cameras``: the cameras of ``masks`` (default the tracker's; e.g. binned)."""
        robot = self.robot
        n = len(robot.bodies)
        t0 = time.perf_counter()
        poses, views = self.e_step(q, masks, delta_px, cameras)
        t1 = time.perf_counter()
        # M-step: every body on its own.
        fits = fit_bodies(
            views, poses, self.inner, iterations=self.m_iterations, damping=self.damping, max_step=self.max_step
        )
        t2 = time.perf_counter()
        if self.static == "diagonal":
            targets, k = np.empty((n, 7)), np.zeros((n, 7))
            for i, fit in enumerate(fits):
                quat = pin.Quaternion(fit.pose.rotation)
                theta = np.array([quat.w, quat.x, quat.y, quat.z])
                targets[i] = [*fit.pose.translation, *theta]
                k[i] = _delta_to_stiffness(fit.hessian, theta)
            kmax = float(k.max())
            if kmax <= 0:
                q_new = q
            else:
                k = np.maximum(k / kmax, self.stiffness_floor)
                q_new = robot.clamp(static_update(robot, q, targets, k, max_iter=30, tol=1e-10).q)
        else:
            q_new = self._static_update_full(q, fits)
        t3 = time.perf_counter()
        timings["e_step"] += t1 - t0
        timings["m_step"] += t2 - t1
        timings["static_update"] += t3 - t2
        return q_new

    def e_step(
        self, q: np.ndarray, masks: Sequence[np.ndarray], delta_px: float, cameras: Sequence[Camera] | None = None
    ) -> tuple[list[pin.SE3], list[list[BodyView]]]:
        """E-step at ``q``: each body's sharp silhouette in every camera, their union,
        and for every body its :class:`BodyView` per camera (mask, what the other bodies
        explain, inlier weights).  ``masks`` are bool, or float64 fractions (binned);
        ``cameras`` theirs (default the tracker's).  Returns the body poses and the views."""
        robot = self.robot
        cameras = self.cameras if cameras is None else cameras
        n = len(robot.bodies)
        poses, Rs, ts = self._body_poses(q)
        native = _mstep.NATIVE
        if native:  # every body's metric A = R diag(L^-2) R^T, in one go
            As = (Rs / self.inner[:, None, :] ** 2) @ Rs.transpose(0, 2, 1)
        # sharp silhouettes, their union per camera, what the others explain
        images: list[list] = [[None] * len(cameras) for _ in range(n)]
        views: list[list[BodyView]] = [[] for _ in range(n)]
        widen = delta_px / max(delta_px, self.outlier_px)  # h at the outlier edge width
        for c, (cam, mask) in enumerate(zip(cameras, masks)):
            log_free = self._zeroed(c, cam.shape)  # Σ_j log(1 - s_j)
            if native and self.outlier <= 0 and cam.dist is None:
                fused = self._e_step_fused(cam, mask, Rs, ts, As, log_free, delta_px)
                if fused is not None:  # the lines below in one C call
                    for i, v in enumerate(fused):
                        if v is not None:
                            views[i].append(v)
                    self._scratch[c, cam.shape] = log_free
                    continue
            log_free_o = np.zeros(cam.shape) if self.outlier > 0 else None
            # the union needs every pixel: the E-step works at full resolution
            body_imgs = body_images(cam, poses, self.inner, delta_px, max_pixels=10**9, arrays=(Rs, ts))
            if native:
                es = cam.centre - ts
            for i, img in enumerate(body_imgs):
                if img is None:
                    continue
                if native:  # the lines below, per pixel in C (kms2pin/_kernels.c)
                    img.s = np.empty(len(img.dirs))  # softplus(h) = -log(1 - s)
                    b = img.box
                    _kernels.estep_body(
                        img.dirs, As[i], es[i], 1.0 / (2.0 * img.delta), log_free, b.v0, b.u0, b.v1 - b.v0,
                        b.u1 - b.u0, img.s, log_free_o, widen,
                    )
                    images[i][c] = img
                    continue
                a2, _ = _geometry(img, poses[i].rotation, poses[i].translation, self.inner[i], False)
                h = (1.0 - a2) / (2.0 * img.delta)
                img.s = np.logaddexp(0.0, h)  # softplus(h) = -log(1 - s)
                log_free[img.slices] -= img.s.reshape(img.shape)
                if log_free_o is not None:
                    log_free_o[img.slices] -= np.logaddexp(0.0, widen * h).reshape(img.shape)
                images[i][c] = img
            weight = None
            if log_free_o is not None:
                # outlier class: p(y | model) of the union (edge >= outlier_px wide) against a
                # constant outlier density; inlier responsibility = p / (p + ε)
                miss = np.exp(log_free_o)  # 1 - M
                p_in = mask * (1.0 - miss) + (1.0 - mask) * miss  # mask: 0/1 or a fraction
                weight = p_in / (p_in + self.outlier)
            for i in range(n):
                img = images[i][c]
                if img is None:
                    continue
                if native:
                    b = img.box
                    o, y = np.empty(len(img.s)), np.empty(len(img.s))
                    _kernels.estep_view(log_free, mask, b.v0, b.u0, b.v1 - b.v0, b.u1 - b.u0, img.s, o, y)
                else:
                    others = log_free[img.slices].ravel() + img.s
                    o = -np.expm1(np.minimum(others, 0.0))
                    y = mask[img.slices].ravel().astype(float)  # 0/1, or a binned fraction
                wt = None if weight is None else weight[img.slices].ravel()
                views[i].append(self._subsampled(img, y, o, wt))
            for img in body_imgs:  # zeroed again for the next E-step
                if img is not None:
                    log_free[img.slices] = 0.0
            self._scratch[c, cam.shape] = log_free
        return poses, views

    def _e_step_fused(self, cam: Camera, mask, Rs, ts, As, log_free, delta_px: float) -> list | None:
        """One camera's E-step in one C call (``kms2pin._kernels.estep_camera``): every
        body's :class:`BodyView` (None: out of view), the same as the per-body kernels
        give; None when a body needs :func:`kms2pin.ecm.mstep.body_image`'s per-body
        path (straddling the camera plane or degenerate)."""
        n = len(Rs)
        status, boxes, delta = _mstep._boxes(cam, Rs, ts, self.inner, delta_px, _mstep.SLACK_PX)
        if (status == 1).any():
            return None
        seen = status == 2
        boxes[~seen] = 0.0
        counts = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        offset = np.zeros(n + 1)
        np.cumsum(counts, out=offset[1:])
        N = int(offset[-1])
        dirs, sp, o, y = np.empty((N, 3)), np.empty(N), np.empty(N), np.empty(N)
        inv = np.where(seen, 0.5 / np.where(seen, delta, 1.0), 1.0)
        _kernels.estep_camera(
            world_rays(cam), As.reshape(n, 9), cam.centre - ts, inv, boxes, offset, np.ascontiguousarray(mask),
            log_free, dirs, sp, o, y,
        )
        out: list = [None] * n
        ib, off = boxes.astype(int).tolist(), offset.astype(int).tolist()
        for i in np.flatnonzero(seen).tolist():
            a, b = off[i], off[i + 1]
            img = BodyImage(cam, BBox(*ib[i]), 1, dirs[a:b], float(delta[i]))
            img.s = sp[a:b]
            out[i] = self._subsampled(img, y[a:b], o[a:b], None)
        return out

    def _zeroed(self, c: int, shape: tuple[int, int]) -> np.ndarray:
        """Camera ``c``'s scratch image of ``shape`` for the E-step's union, all zeros: the last
        E-step's, which re-zeroed it over the bodies' boxes only (a fresh 320x240 array
        a camera and iteration costs more than the boxes' pixels).  It is taken out
        until then, so an E-step that raised leaves none behind."""
        buf = self._scratch.pop((c, shape), None)
        return buf if buf is not None else np.zeros(shape)

    def _subsampled(self, img, y: np.ndarray, o: np.ndarray, weight: np.ndarray | None) -> BodyView:
        """The M-step's view of a full-resolution body image: every ``stride``-th row and
        column when the box holds more than ``max_pixels`` pixels."""
        if len(y) <= self.max_pixels:
            return BodyView(img, y, o, weight)
        rows, cols = img.shape
        stride = max(1, int(np.ceil(np.sqrt(rows * cols / self.max_pixels))))
        if stride == 1:
            return BodyView(img, y, o, weight)
        b = img.box
        sub = BodyImage(img.camera, b, stride, world_rays(img.camera)[b.v0 : b.v1 : stride, b.u0 : b.u1 : stride].reshape(-1, 3), img.delta)

        def pick(a):
            return np.ascontiguousarray(a.reshape(rows, cols)[::stride, ::stride]).ravel()

        return BodyView(sub, pick(y), pick(o), None if weight is None else pick(weight))

    def _static_update_full(self, q: np.ndarray, fits) -> np.ndarray:
        """Virtual-work equilibrium with a full 6x6 spring per body (its M-step curvature).

        The springs act on each body's pose error ``e_i = (t_i - t'_i, log(R_i R'_iᵀ))``
        (world axes) with stiffness ``K_i = H_i`` plus a floor; the equilibrium
        ``Σ J_iᵀ K_i e_i = 0`` (B^T Q = 0, eq. 2.28, with Q_i = -K_i e_i) is found by
        Gauss-Newton in joint space.  This is the thesis's per-coordinate stiffness
        taken one step further: coordinates of a body are coupled (an elongated body
        is stiff across its axis, soft along it) in the body's own directions, not
        the world's.

        Each Gauss-Newton step must lower the springs' energy ``½ Σ e_iᵀ K_i e_i`` (plus
        the priors'): a step that raises it is halved, up to ``_BACKTRACK`` times, and if
        none lowers it the update stops there.  The springs are nonlinear in the
        rotations, and a full step can overshoot far: on the two-camera full-body walk
        with joint limits (noise seed 1) undamped steps raised the energy 200-fold
        within one update and turned the root by 91°.
        """
        robot = self.robot
        model, data = robot.model, robot.data
        n, nv = len(fits), model.nv
        S = np.ones((n, 6))
        S[:, :3] = self.inner.mean(axis=1)[:, None]
        Hf = np.array([f.hessian for f in fits])  # (n, 6, 6)
        hmax = float((np.einsum("nii->ni", Hf) * S**2).max())
        if hmax <= 0:
            return q
        K = Hf  # a fresh array
        K[:, _I6, _I6] += self.stiffness_floor * hmax / S**2
        T = np.array([pin.SE3ToXYZQUAT(f.pose) for f in fits])  # (n, 7) [t, x, y, z, w]
        st = _structure(robot)
        native = _mstep.NATIVE
        K36 = K.reshape(n, 36)
        qi, vi = self._limited
        limited = len(qi) > 0
        if limited:
            lo, hi = robot.lower_limits[qi] + 1e-12, robot.upper_limits[qi] - 1e-12
        priors = {}  # the priors' stiffnesses, fixed at the first configuration's springs

        def springs(q):
            """Newton system A, g and energy of the springs (and priors) at q."""
            pin.computeJointJacobians(model, data, q)
            X = body_frames(model, data, robot.frame_ids, st, native)
            if native:  # the lines below in one C call (kms2pin/_kernels.c)
                A, g = np.empty((nv, nv)), np.empty(nv)
                energy = _kernels.pose_springs(data.J, X, T, K36, st.support, A, g)
            else:
                # pose error e_i = (t_i - t'_i, log(R_i R'_i^T)) in world axes
                e = np.empty((n, 6))
                e[:, :3] = X[:, :3] - T[:, :3]
                e[:, 3:] = _log_quat(_quat_mul_conj(X[:, 3:], T[:, 3:]))
                # LOCAL_WORLD_ALIGNED Jacobians at the body centres from data.J (world frame)
                Jw = data.J
                J = np.empty((n, 6, nv))
                J[:, 3:] = Jw[3:][None] * st.support[:, None, :]
                J[:, :3] = (Jw[:3][None] + np.cross(Jw[3:].T[None], X[:, None, :3]).transpose(0, 2, 1)) * st.support[
                    :, None, :
                ]
                KJ = (K @ J).reshape(6 * n, nv)
                A = J.reshape(6 * n, nv).T @ KJ
                g = KJ.T @ e.ravel()
                energy = 0.5 * float(np.einsum("ni,nij,nj->", e, K, e))
            if not priors and self._root_dofs:
                priors["depth"] = self.depth_prior * float(np.trace(A[:3, :3])) / 3.0
                priors["upright"] = self.upright * float(A[3, 3] + A[4, 4] + A[5, 5]) / 3.0
            if self._root_dofs and self.depth_prior > 0 and self._anchor is not None:
                energy += self._depth_spring(A, g, data, priors["depth"])
            if self._root_dofs and self.upright > 0:
                energy += self._upright_spring(A, g, data, priors["upright"])
            if self.rest_prior > 0 and self._joint_dofs.size:
                if "rest" not in priors:
                    priors["rest"] = self.rest_prior * float(np.mean(A[self._joint_dofs, self._joint_dofs]))
                energy += self._rest_spring(A, g, q, priors["rest"])
            return A, g, energy

        A, g, energy = springs(q)
        for _ in range(self.static_iterations):
            dq = _newton_step(A, g, native)
            if limited:
                # a joint at a limit that the step pushes further is held there, and the
                # step is solved for the others (projected Gauss-Newton's active set): its
                # clipped step need not lower the energy
                blocked = np.zeros(nv, dtype=bool)
                blocked[vi] = ((q[qi] <= lo) & (dq[vi] < 0)) | ((q[qi] >= hi) & (dq[vi] > 0))
                if blocked.any():
                    free = ~blocked
                    dq = np.zeros(nv)
                    dq[free] = _newton_step(np.ascontiguousarray(A[np.ix_(free, free)]), g[free], native)
            for _ in range(_BACKTRACK + 1):
                q_new = pin.integrate(model, q, dq)
                if limited:  # projected Gauss-Newton: the spec's joint limits
                    q_new = robot.clamp(q_new)
                A_new, g_new, e_new = springs(q_new)
                if e_new <= energy * (1.0 + 1e-12):
                    break
                dq = 0.5 * dq
            else:
                break  # no step lowers the energy: q is (close to) a minimum
            q, A, g, energy = q_new, A_new, g_new, e_new
            if np.abs(dq).max() < 1e-7:
                break
        return q

    def _depth_spring(self, A: np.ndarray, g: np.ndarray, data, k: float) -> float:
        """Add to the static update's Newton system ``A``, ``g`` a spring of stiffness ``k``
        holding the root's distance along each camera's ray to its value at the frame's
        start (:attr:`_anchor`); return its energy."""
        root = data.oMi[1]
        p, R = root.translation, root.rotation
        energy = 0.0
        for cam in self.cameras:
            n = self._anchor - cam.centre
            n /= max(float(np.linalg.norm(n)), 1e-300)
            jac = n @ R  # d(n . p) / d(root's local linear velocity)
            r = float(n @ (p - self._anchor))
            A[:3, :3] += k * np.outer(jac, jac)
            g[:3] += k * jac * r
            energy += 0.5 * k * r * r
        return energy

    def _rest_spring(self, A: np.ndarray, g: np.ndarray, q: np.ndarray, k: float) -> float:
        """Add to the static update's Newton system ``A``, ``g`` the spring of ``rest_prior``,
        stiffness ``k`` on every joint angle (not the root): energy ½ k Σ (q_j - rest_j)²
        with rest the spec's rest pose; return the energy."""
        d = pin.difference(self.robot.model, self.robot.q_rest, q)[self._joint_dofs]
        A[self._joint_dofs, self._joint_dofs] += k
        g[self._joint_dofs] += k * d
        return 0.5 * k * float(d @ d)

    def _upright_spring(self, A: np.ndarray, g: np.ndarray, data, k: float) -> float:
        """Add to the static update's Newton system ``A``, ``g`` the spring of ``upright``,
        stiffness ``k``: energy ½ k |R u - up|² with R the root's rotation and u its axis
        that was vertical at ``q0`` (zero for any turn about ``up``); return the energy.
        With ω the root's local angular velocity, J = d(R u)/dω = -R [u]x = -[R u]x R, so
        JᵀJ = I - u uᵀ (|u| = 1) and the gradient Jᵀ(R u - up) = Rᵀ (up x R u)."""
        R = data.oMi[1].rotation
        Ru = R @ self._up_root
        A[3:6, 3:6] += k * self._up_projector
        g[3:6] += k * (R.T @ (self._up_skew @ Ru))
        d = Ru - self.up
        return 0.5 * k * float(d @ d)

    def step(self, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame") -> FrameResult:
        """Track one frame: ``masks`` is one (H, W) mask per camera (bool or 0/1).

        A frame whose masks are all empty keeps the last pose and is flagged
        ``"empty mask"``; a camera whose mask alone is empty is left out of the
        frame (flag ``"empty mask in camera k"``).
        """
        masks = self._masks(masks, source)
        robot = self.robot
        model = robot.model
        timings = {"e_step": 0.0, "m_step": 0.0, "static_update": 0.0, "sizes": 0.0}
        empty = [not m.any() for m in masks]
        if all(empty):
            res = FrameResult(self.q.copy(), robot.maximal_coordinates(self.q), 0, 0.0, False, ("empty mask",), timings)
            self._advance(self.q, keep_velocity=False)
            self._alts.clear()
            return res
        flags = tuple(f"empty mask in camera {c}" for c, e in enumerate(empty) if e)
        with self._cameras_seeing(masks) as masks:
            if self.calibrate_sizes and not self._calibrated:
                self.calibrate(masks, source)
            q = self.q.copy()
            if self.prediction == "constant_velocity" and self._prev is not None:
                q = robot.clamp(pin.integrate(model, q, self._velocity()))
            coarse = self._coarse(masks)
            q, it, converged = self._ecm(q, masks, timings, coarse=coarse)
            fit = self._iou(q, masks)
            moved, spawn = (), None
            if self.limb_search and self._settled() and fit < self._score - self.limb_search_drop:
                q, fit, limb = self._swing_limbs(q, fit, masks, timings)
                moved = self._limbs_moved(q, limb)
            elif self.limb_hypothesis and self.frame > 0 and "limb" not in self._alts \
                    and fit < self._score - self.limb_hypothesis_drop:
                # a smaller fall: the best candidate is not kept but tracked beside this pose
                spawn = self._swing_limbs(q, fit, masks, timings, screen_only=True)
            if self.limb_search and self.frame > 0 and len(self.cameras) == 1:
                # after twins cross, only one view can mistake one for the other
                q, fit, limb = self._exchange_crossed_limbs(q, fit, masks, timings)
                again = self._limbs_moved(q, limb)
                # twins exchanged twice this frame are back in place: no exchange to report
                moved = () if again and again == moved else moved + again
            flags += moved
            if self.mirror_hypothesis or self.swap_hypothesis or self.limb_hypothesis:
                q, fit, switched = self._hypotheses_step(q, fit, masks, timings, coarse, spawn)
                if switched:
                    flags += (f"switched to the {_KIND_WORDS[switched]} hypothesis",)
            else:
                self._running_fit(fit)
            poor = fit < self.poor_fit
            if poor:
                flags += (f"poor fit ({fit:.2f})",)
            if fit == 0.0:  # the model's silhouettes miss the masks: nothing to go on
                q = self.q.copy()
                flags += ("lost: kept the last pose",)
            # a frame fitting at least as well as the running fit, and with nothing to report
            # (no switch, no limb search, no empty camera), is evidence on the body sizes.
            # The first frame counts twice: its calibration at the starting pose, then this
            # refinement at the tracked pose.  Counted once, it measured the same on the
            # benchmarks but left a thigh 11 % short on the clean one-camera walk of
            # tests/ecm/test_tracker.py (test_sizes_along_the_viewing_ray_...)
            if self._calibrated and self.size_every > 0 and self.frame % self.size_every == 0 \
                    and not flags and fit >= self._score:
                t0 = time.perf_counter()
                self._refine_sizes(q, masks)
                timings["sizes"] += time.perf_counter() - t0
        res = FrameResult(q.copy(), robot.maximal_coordinates(q), it, fit, converged, flags, timings)
        # a poorly fitting pose is no basis for a velocity: coasting on it carries a lost
        # track out of the view
        self._advance(q, keep_velocity=not poor)
        return res

    def _coarse(self, masks: Sequence[np.ndarray]) -> tuple[list[Camera], list[np.ndarray]] | None:
        """The binned cameras and masks of the wide-edge iterations (``coarse_delta_px``),
        or None when they are off (or a camera is too small to bin)."""
        if self.coarse_delta_px is None or self.delta_start < self.coarse_delta_px:
            return None
        return self._binned_views(masks)

    def _binned_views(self, masks: Sequence[np.ndarray]) -> tuple[list[Camera], list[np.ndarray]] | None:
        """The cameras and masks binned 2x2, or None if a camera is too small to bin."""
        if not all(c in self._binned for c in self.cameras):
            return None
        return [self._binned[c] for c in self.cameras], [bin_mask(m) for m in masks]

    def _ecm(
        self, q: np.ndarray, masks, timings: dict, max_iterations: int | None = None, coarse=None, binned=False
    ) -> tuple[np.ndarray, int, bool]:
        """ECM iterations from ``q`` until the configuration stops changing (edge width
        annealed), at most ``max_iterations`` (default: the tracker's); returns the
        configuration, the iterations run and whether it converged.  ``coarse``: the
        binned cameras and masks (:meth:`_binned_views`) for the iterations whose edge is
        at least ``coarse_delta_px`` wide, or for all of them if ``binned``."""
        it = 0
        self._anchor = q[:3].copy() if self._root_dofs else None
        delta = self.delta_start
        limit = self.max_iterations if max_iterations is None else max(1, int(max_iterations))
        pts = self._outline_pixels(q) if self.tol_px is not None else None
        for it in range(1, limit + 1):
            if coarse is not None and (binned or delta >= self.coarse_delta_px * 0.9999):
                q_new = self.iterate(q, coarse[1], 0.5 * delta, timings, coarse[0])
            else:
                q_new = self.iterate(q, masks, delta, timings)
            settled = self._change(q, q_new) < self.tol
            if pts is not None:
                pts_new = self._outline_pixels(q_new)
                settled = settled or self._image_motion(pts, pts_new) < self.tol_px
                pts = pts_new
            q = q_new
            at_final = delta <= self.delta_final * 1.0001
            delta = max(self.delta_final, 0.5 * delta)
            if at_final and it >= min(self.min_iterations, limit) and settled:
                return q, it, True
        return q, it, False

    def _mirror(self, q: np.ndarray) -> np.ndarray:
        """The mirror-image configuration of ``q`` in the (first) camera: the root's
        orientation reflected through the plane across the viewing ray at the root and
        through the model's own left/right plane (a proper rotation), joints kept."""
        M = pin.XYZQUATToSE3(q[:7])
        d = M.translation - self.cameras[0].centre
        d /= max(float(np.linalg.norm(d)), 1e-12)
        R = (np.eye(3) - 2.0 * np.outer(d, d)) @ M.rotation @ self._sagittal
        out = q.copy()
        out[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, M.translation))
        return out

    def _root_angle(self, a: np.ndarray, b: np.ndarray) -> float:
        Ra, Rb = pin.XYZQUATToSE3(a[:7]).rotation, pin.XYZQUATToSE3(b[:7]).rotation
        return float(np.linalg.norm(pin.log3(Ra.T @ Rb)))

    def _swap(self, q: np.ndarray) -> np.ndarray:
        """``q`` with the angles of every left/right pair of joints exchanged."""
        out = q.copy()
        a, b = self._swap_pairs
        out[a], out[b] = q[b], q[a]
        return out

    def _alternatives(self) -> dict:
        """The alternative hypotheses tracked: kind -> (flip of a configuration, margin)."""
        kinds = {}
        if self.mirror_hypothesis:
            kinds["mirror"] = (self._mirror, self.mirror_margin)
        if self.swap_hypothesis:
            kinds["swap"] = (self._swap, self.swap_margin)
        if self.limb_hypothesis:  # spawned by the limb search (_hypotheses_step's spawn), not as a flip
            kinds["limb"] = (None, self.limb_margin)
        return kinds

    def _merged(self, kind: str, qa: np.ndarray, q: np.ndarray) -> bool:
        """Whether alternative ``qa`` of ``kind`` has become the main hypothesis ``q``."""
        if self._root_dofs and self._root_angle(qa, q) >= _MERGE:
            return False
        if kind == "mirror":
            return True
        if kind == "limb":
            return float(np.abs(pin.difference(self.robot.model, qa, q)[self._joint_dofs]).max()) < _MERGE
        a, b = self._swap_pairs
        return float(np.abs(np.concatenate([qa[a] - q[a], qa[b] - q[b]])).max()) < _MERGE

    def _hypotheses_step(
        self, q: np.ndarray, fit: float, masks, timings: dict, coarse=None, spawn=None
    ) -> tuple[np.ndarray, float, str]:
        """Track the alternative hypotheses alongside the main one (``q``, its ``fit``
        this frame); return the pose to report, its fit and the kind switched to ("" if
        none).  An alternative is spawned as the flip of the main one (the limb-search
        hypothesis as ``spawn``, the limb search's (configuration, fit, limb) this
        frame), tracked with its own constant-velocity prediction, and dropped when it
        merges with the main one or falls well behind; the one whose running fit leads
        by more than its margin becomes the main one."""
        a = self.hypothesis_smoothing
        last_score = self._score
        self._running_fit(fit)
        switched = ""
        if self.frame == 0:
            return q, fit, switched
        kinds = self._alternatives()
        binned = self.binned_hypotheses and bool(self._alts)
        if binned:  # all the alternatives' iterations on the binned masks
            coarse = coarse or self._binned_views(masks)
            binned = coarse is not None
        best = None
        for kind, (flip, margin) in kinds.items():
            alt = self._alts.get(kind)
            if alt is None:  # spawn: the flipped image of this frame's fit and of the last frame's
                if flip is not None:
                    self._alts[kind] = [flip(q), flip(self.q), self._score, None]
                continue
            qa, pa, sc, _ = alt
            pred = qa
            if self.prediction == "constant_velocity":
                pred = self.robot.clamp(pin.integrate(self.robot.model, qa, self._velocity(pa, qa)))
            qa_new, _, _ = self._ecm(pred, masks, timings, self.hypothesis_iterations, coarse, binned)
            fa = self._iou(qa_new, masks)
            sc = (1.0 - a) * sc + a * fa
            self._alts[kind] = [qa_new, qa, sc, fa]
            if sc > self._score + margin and (best is None or sc > self._alts[best][2]) and self._settled():
                best = kind
        if best is not None:
            qa_new, qa, sc, fa = self._alts[best]
            # the alternative leads: it becomes the main hypothesis (its last pose too, for
            # the velocity); the old main one becomes that alternative
            self._alts[best] = [q, self.q.copy(), self._score, fit]
            self.q = qa.copy()
            q, fit = qa_new, fa
            self._score = sc
            switched = best
            for kind in list(self._alts):  # the others were flips of the old main one
                if kind != best:
                    del self._alts[kind]
        if spawn is not None and spawn[2] and not switched and "limb" not in self._alts:
            qs, fs, limb = spawn
            last = self.q.copy()  # the last frame's pose with the moved limbs as in qs: no velocity
            self._copy_limbs(last, qs, limb)
            self._alts["limb"] = [qs, last, (1.0 - a) * last_score + a * fs, fs]
        for kind in list(self._alts):
            qa, _, sc, _ = self._alts[kind]
            # a hypothesis that is (or merged into) the main one, or fell well behind, is
            # dropped; the next frame spawns a fresh one
            behind = _LIMB_BEHIND if kind == "limb" else 0.05
            if self._merged(kind, qa, q) or sc < self._score - behind:
                del self._alts[kind]
        return q, fit, switched

    def _exchange_crossed_limbs(
        self, q: np.ndarray, fit: float, masks, timings: dict
    ) -> tuple[np.ndarray, float, str]:
        """Limb search after twin limbs cross: a pair whose first joints have come within
        ``_CROSS_DEG`` of each other, or passed each other since the last frame, in the
        last ``_CROSS_FRAMES`` frames (side-on, the two arms or legs overlap) gets its
        exchange (:meth:`_limb_candidates`) tried by a frame's ECM iterations, kept if
        its fit (IoU) beats ``fit`` by ``_LIMB_GAIN``.  As the limbs come apart, a model
        limb can follow its twin's image while the other stays hidden behind the trunk;
        the fit hardly falls, so the search on a falling fit does not see it.  Returns
        as :meth:`_swing_limbs`."""
        out = (q, fit, "")
        coarse = None
        for left, right, a, b in self._limb_pairs:
            d, d_last = q[a[0]] - q[b[0]], self.q[a[0]] - self.q[b[0]]
            if abs(d) < _CROSS_DEG or d * d_last < 0.0:
                self._crossed[left] = self.frame
                continue
            c = self._exchanged(q, a, b)
            if c is None or self.frame - self._crossed.get(left, -_CROSS_FRAMES - 1) > _CROSS_FRAMES:
                continue
            coarse = coarse or self._coarse(masks)
            qc, _, _ = self._ecm(c, masks, timings, coarse=coarse)
            fc = self._iou(qc, masks)
            if fc > out[1] + _LIMB_GAIN:
                out = (qc, fc, left + _LIMB_AND + right)
        return out

    def _exchanged(self, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """``q`` with the angles at q indices ``a`` and ``b`` (twin limbs) exchanged, or
        None if no angle of theirs differs by ``_LIMB_MIN`` (nothing to exchange)."""
        if np.abs(q[a] - q[b]).max() < _LIMB_MIN:
            return None
        c = q.copy()
        c[a], c[b] = q[b], q[a]
        return self.robot.clamp(c)

    def _limbs_moved(self, q: np.ndarray, limb: str) -> tuple[str, ...]:
        """After the limb search kept ``limb`` (a joint, or two joined by ``_LIMB_AND``)
        in ``q``: take the moved limbs' velocity away (the move is no motion to carry on)
        and return the frame's flag (none if ``limb`` is "")."""
        if not limb:
            return ()
        moved, reset = self._copy_limbs(self.q, q, limb)
        if reset:
            return (f"put the joints below '{moved[0]}' back at rest",)
        if len(moved) == 1:
            return (f"swung '{limb}' the other way",)
        return (f"swapped '{moved[0]}' and '{moved[1]}'",)

    def _copy_limbs(self, dst: np.ndarray, src: np.ndarray, limb: str) -> tuple[list[str], bool]:
        """Copy into ``dst`` from ``src`` the angles of the limbs a limb-search label
        (:meth:`_swing_limbs`) names, every joint of each limb; return their first
        joints' names and whether the joints below were put back at rest."""
        names = limb.removesuffix(_LIMB_RESET).split(_LIMB_AND)
        for name in names:
            iq, below = self._limbs[name]
            dst[iq], dst[below] = src[iq], src[below]
        return names, limb.endswith(_LIMB_RESET)

    def _settled(self) -> bool:
        """Whether the running fit has settled: it averages about 1 / hypothesis_smoothing
        frames, and before that it is mostly the first frame's, which the size calibration
        (or the initialization) fitted to that very frame.  Until then a fall below it says
        nothing of a limb, and an alternative hypothesis's lead nothing of the pose."""
        return self.frame >= round(1.0 / self.hypothesis_smoothing)  # > 0: checked in __init__

    def _running_fit(self, fit: float) -> None:
        """Fold this frame's fit into the main hypothesis's running fit (exponentially
        smoothed, weight ``hypothesis_smoothing`` on the new frame)."""
        a = self.hypothesis_smoothing
        self._score = fit if self.frame == 0 else (1.0 - a) * self._score + a * fit

    def _limb_candidates(self, q: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """Each limb swung the other way: its first joint's angle reflected about the rest
        angle, once with the joints below kept and once with them put back at rest
        (an arm swung back over the trunk is often bent there too).  Each limb with its
        first joint kept and the joints below put back at rest (labelled ``"<joint>
        reset"``): in one view a finger can fold its last joints the wrong way round
        while its outline still fits.  And each pair of left/right twin limbs exchanged
        (labelled ``"<left> and <right>"``): side-on, one view hardly tells the arms
        apart, and after they cross one model arm can take the other's image while its
        twin stays hidden behind the trunk."""
        rest = self.robot.q_rest
        out = []
        for left, right, a, b in self._limb_pairs:
            c = self._exchanged(q, a, b)
            if c is not None:
                out.append((left + _LIMB_AND + right, c))
        for name, (iq, below) in self._limbs.items():
            if len(below) and np.abs(q[below] - rest[below]).max() >= _LIMB_MIN:
                c = q.copy()
                c[below] = rest[below]
                out.append((name + _LIMB_RESET, self.robot.clamp(c)))
            if abs(q[iq] - rest[iq]) < _LIMB_MIN:
                continue
            c = q.copy()
            c[iq] = 2.0 * rest[iq] - q[iq]
            out.append((name, self.robot.clamp(c)))
            if len(below) and np.abs(q[below] - rest[below]).max() >= _LIMB_MIN:
                c = c.copy()
                c[below] = rest[below]
                out.append((name, self.robot.clamp(c)))
        return out

    def _swing_limbs(
        self, q: np.ndarray, fit: float, masks, timings: dict, screen_only: bool = False
    ) -> tuple[np.ndarray, float, str]:
        """Limb search: try every limb swung the other way or with the joints below its
        first put back at rest, and every pair of twin limbs exchanged
        (:meth:`_limb_candidates`), each screened by a few ECM iterations on
        the masks binned 2x2; the best two swings, the best exchange and the best limb
        put back at rest are refined at full resolution, and the best is kept if its
        fit (IoU) beats ``fit`` by ``_LIMB_GAIN``.  (The exchanges and the limbs put
        back at rest do not compete with the swings for the refinement: an exchange,
        both arms' images already explained, screens high; a limb put back at rest in
        the swings' two slots made the one-camera thesis lower body's seed 9 end at
        1.80x its start, against 1.04x in its own slot.)
        Returns the configuration, its fit and the limb's joint ("" if none was kept;
        ``"<joint> reset"`` for a limb put back at rest below its first joint,
        ``"<left> and <right>"`` for twin limbs exchanged).  ``screen_only``: the best
        screened candidate, unrefined (the limb-search hypothesis's start)."""
        cands = self._limb_candidates(q)
        binned = self._binned_views(masks)
        if not cands or binned is None:
            return q, fit, ""
        screened = []
        for name, c in cands:
            qc, _, _ = self._ecm(c, masks, timings, _LIMB_ITERATIONS, binned, binned=True)
            screened.append((self._iou(qc, masks), name, qc))
        screened.sort(key=lambda x: -x[0])
        if screen_only:
            fc, name, qc = screened[0]
            return (qc, fc, name) if fc > fit + _LIMB_GAIN else (q, fit, "")
        slots = [_LIMB_REFINED, 1, 1]  # refined per kind (swing, exchange, reset), best screened first
        refined = []
        for s in screened:
            kind = 1 if _LIMB_AND in s[1] else 2 if s[1].endswith(_LIMB_RESET) else 0
            if slots[kind] > 0:
                slots[kind] -= 1
                refined.append((-s[0], kind, s))
        out = (q, fit, "")
        coarse = self._coarse(masks)
        for *_, (_, name, qc) in sorted(refined, key=lambda x: x[:2]):
            qc, _, _ = self._ecm(qc, masks, timings, coarse=coarse)
            fc = self._iou(qc, masks)
            if fc > out[1] + _LIMB_GAIN:
                out = (qc, fc, name)
        return out

    def swing_limbs(
        self, q: np.ndarray, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame"
    ) -> tuple[np.ndarray, float, str]:
        """The limb search of ``limb_search`` on one frame: ECM from ``q`` (as
        :meth:`refine`), then every limb swung the other way or put back at rest below
        its first joint, and every pair of twin limbs exchanged; the tracker is left as
        it was.  Returns the configuration, its fit (IoU) and the joint of the limb
        swung ("" if none improved the fit; ``"<joint> reset"`` if the joints below it
        were put back at rest; ``"<left> and <right>"`` if twin limbs were exchanged)."""
        with self._cameras_seeing(self._masks(masks, source)) as masks:
            if not masks:
                return np.array(q, dtype=float), 0.0, ""
            timings = {"e_step": 0.0, "m_step": 0.0, "static_update": 0.0}
            q0, _, _ = self._ecm(self.robot.clamp(np.array(q, dtype=float)), masks, timings, coarse=self._coarse(masks))
            return self._swing_limbs(q0, self._iou(q0, masks), masks, timings)

    def _velocity(self, prev: np.ndarray | None = None, cur: np.ndarray | None = None) -> np.ndarray:
        """Last frame's motion (tangent vector), each angle capped at ``max_prediction_deg``
        and the root's translation at that many hundredths of the model height (as in
        ``tol_deg``): a joint the images hardly fix can start to spin, and an uncapped
        prediction would carry the spin on from frame to frame."""
        prev = self._prev if prev is None else prev
        cur = self.q if cur is None else cur
        v = pin.difference(self.robot.model, prev, cur)
        cap = np.full(len(v), self.max_prediction)
        if self._root_dofs:
            cap[:3] = np.degrees(self.max_prediction) * 0.01 * self.robot.height
        return np.clip(v, -cap, cap)

    def refine(
        self, q: np.ndarray, masks: np.ndarray | Sequence[np.ndarray], source: str = "frame"
    ) -> tuple[np.ndarray, float]:
        """ECM on one frame's ``masks`` from ``q`` (a frame's iterations, no prediction,
        no alternative hypotheses), leaving the tracker as it was; returns the
        configuration and its fit (IoU).  E.g. to compare a pose found by a search with
        the tracked one before restarting from it."""
        with self._cameras_seeing(self._masks(masks, source)) as masks:
            if not masks:
                return np.array(q, dtype=float), 0.0
            timings = {"e_step": 0.0, "m_step": 0.0, "static_update": 0.0}
            q_new, _, _ = self._ecm(self.robot.clamp(np.array(q, dtype=float)), masks, timings, coarse=self._coarse(masks))
            return q_new, self._iou(q_new, masks)

    @contextmanager
    def _cameras_seeing(self, masks: Sequence[np.ndarray]):
        """Within: :attr:`cameras` are only those whose mask is not empty; yields their
        masks.  The cameras are restored on leaving, also on an error."""
        saved = self.cameras
        seen = [m.any() for m in masks]
        self.cameras = [c for c, s in zip(saved, seen) if s]
        try:
            yield [m for m, s in zip(masks, seen) if s]
        finally:
            self.cameras = saved

    def restart(self, q0: np.ndarray) -> None:
        """Go on from ``q0`` as from a first frame's pose (no velocity, no alternative
        hypotheses), keeping every option, the measured body sizes and the root's upright
        axis, e.g. when the subject has been found again after leaving the view."""
        self._reset(q0, "restart pose")

    def _reset(self, q0, what: str) -> None:
        """Start from ``q0``: no velocity, no alternative hypotheses, frame 0."""
        q0 = np.array(q0, dtype=float)
        if q0.shape != (self.robot.nq,):
            raise InputDataError(f"{what} has {q0.size} values but '{self.robot.system.name}' needs {self.robot.nq}")
        if not np.isfinite(q0).all():
            raise InputDataError(f"{what} is not finite (coordinate {int(np.flatnonzero(~np.isfinite(q0))[0])})")
        self.q = q0
        self._prev: np.ndarray | None = None
        self._alts.clear()
        self._crossed: dict[str, int] = {}  # twin limbs (left joint) -> frame they last crossed
        self._score = 0.0
        self.frame = 0

    def _advance(self, q: np.ndarray, keep_velocity: bool = True) -> None:
        self._prev = self.q.copy() if keep_velocity else q.copy()
        self.q = q.copy()
        self.frame += 1

    def track(
        self,
        frames: Iterable,
        *,
        progress: bool = False,
        on_frame: Callable[[int, FrameResult], None] | None = None,
    ) -> Trajectory:
        """Track a sequence; each item is the frame's masks (one per camera)."""
        results: list[FrameResult] = []
        iterator = frames
        if progress:
            from tqdm import tqdm

            iterator = tqdm(frames, unit="frame", desc="tracking")
        for k, masks in enumerate(iterator):
            r = self.step(masks, source=f"frame {k}")
            results.append(r)
            if on_frame is not None:
                on_frame(k, r)
        return Trajectory(
            self.robot, np.array([r.q for r in results]).reshape(-1, self.robot.nq), results, scales=self.scales
        )


#: the keyword options of :class:`Tracker` (for a misspelt one's did-you-mean)
_OPTIONS = tuple(p for p in inspect.signature(Tracker.__init__).parameters
                 if p not in ("self", "robot", "cameras", "unknown"))
