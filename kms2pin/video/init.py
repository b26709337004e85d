"""Initial pose for tracking, without hand work or from a pose file.

:func:`initial_pose` finds a free-root model's pose in the first frame's
silhouettes (thesis §2.1.2 assumes a known starting pose; this supplies one):

1. **placement** - the joint angles are the rest pose's; the model's centre (the
   mean of its body centres) is put on the viewing ray through the centroid of
   the mask of the first camera that sees something, at the depth where the
   model's projected height (rest pose, ray-cast inner ellipsoids) equals the
   mask's bounding-box height (perspective: height ∝ 1/depth; a few fixed-point
   passes);
2. **coarse search** over the root rotation about the model's centre: yaw about
   world +y in ``yaw_steps`` steps and a few small pitches; each candidate is
   scored by the IoU of its rendered silhouettes with the masks over all
   cameras (rendered at reduced resolution);
3. **refinement** - the best few candidates are each given ``refine_steps`` ECM
   iterations-worth of :class:`~kms2pin.ecm.tracker.Tracker` steps on the same
   frame, and the best fit wins.

:func:`read_pose_json` reads a user's pose:
``{"joints": {name: degrees}, "root": {"position": [x, y, z],
"rotation": 3x3 | "quaternion_xyzw": [x, y, z, w]}}``; the names are the trajectory
CSV's (:attr:`Robot.coordinate_names`: a spherical joint's ``<joint>_x|y|z`` angles, a
prismatic joint's offset in spec length units); joints left out keep their rest
angle, the root left out keeps its rest pose.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import pinocchio as pin

from ..ecm.camera import Camera
from ..ecm.raycast import render_mask
from ..errors import InputDataError, did_you_mean
from ..jsonfile import read_json
from ..robot import Robot, rotation_error


@dataclass(frozen=True)
class InitResult:
    """What :func:`initial_pose_details` found: the pose, its fit (IoU over all
    cameras after refinement), the coarse yaw/pitch (degrees) and the candidates'
    coarse scores."""

    q: np.ndarray
    fit: float
    yaw_deg: float
    pitch_deg: float
    coarse: list[tuple[float, float, float]]  # (yaw, pitch, IoU)


def scaled_camera(camera: Camera, s: int) -> Camera:
    """The camera at 1/s of the resolution (same field of view, pixel centres kept)."""
    if s <= 1:
        return camera
    K = camera.K.copy()
    K[:2] /= s
    K[0, 2] = (camera.K[0, 2] + 0.5) / s - 0.5
    K[1, 2] = (camera.K[1, 2] + 0.5) / s - 0.5
    return Camera(K, camera.world_T_camera, max(1, camera.width // s), max(1, camera.height // s), dist=camera.dist)


def _shrink(mask: np.ndarray, cam: Camera) -> np.ndarray:
    if mask.shape == cam.shape:
        return mask
    small = cv2.resize(mask.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    return small > 0


def _largest_blob(mask: np.ndarray) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 2:
        return mask.astype(bool)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == k


def _extent(mask: np.ndarray) -> tuple[np.ndarray, float]:
    """Centroid (u, v) and bounding-box height (pixels) of a mask."""
    v, u = np.nonzero(mask)
    return np.array([u.mean(), v.mean()]), float(v.max() - v.min() + 1)


def _bodies(robot: Robot, q: np.ndarray):
    return [(P, robot.inner(b)) for P, b in zip(robot.body_poses(q), robot.bodies)]


def model_centre(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Mean of the body centres (world)."""
    return np.mean([P.translation for P in robot.body_poses(q)], axis=0)


def _move_root(q: np.ndarray, R: np.ndarray, about: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Rotate the free root by world rotation ``R`` about point ``about`` and translate by ``shift``."""
    T = pin.XYZQUATToSE3(q[:7])
    out = q.copy()
    out[:7] = pin.SE3ToXYZQUAT(pin.SE3(R @ T.rotation, about + R @ (T.translation - about) + shift))
    return out


def _iou(robot: Robot, q: np.ndarray, cams: Sequence[Camera], masks: Sequence[np.ndarray]) -> float:
    bodies = _bodies(robot, q)
    inter = union = 0
    for cam, m in zip(cams, masks):
        r = render_mask(cam, bodies)
        inter += int(np.count_nonzero(r & m))
        union += int(np.count_nonzero(r | m))
    return inter / union if union else 0.0


def place(robot: Robot, q: np.ndarray, camera: Camera, mask: np.ndarray, passes: int = 4) -> np.ndarray:
    """Translate the root so that the rendered model's centroid and height in ``camera``
    match ``mask``'s (see the module docstring, step 1)."""
    target_c, target_h = _extent(_largest_blob(mask))
    R_wc = camera.world_R_camera
    # start: the model centre on the ray through the mask centroid, at its current depth (or 3 heights)
    c = model_centre(robot, q)
    z = float(camera.depth(c[None])[0])
    if not np.isfinite(z) or z <= 0:
        z = 3.0 * robot.height
    for _ in range(passes):
        d, origin = camera.rays(target_c[None])
        d = d[0] / float(d[0] @ R_wc[:, 2])  # unit depth along the ray
        q = _move_root(q, np.eye(3), c, origin + z * d - c)
        c = origin + z * d
        r = render_mask(camera, _bodies(robot, q))
        if not r.any():
            break
        rc, rh = _extent(r)
        z_new = z * rh / target_h
        # the rendered centroid is off the mask centroid by perspective/shape: aim the ray past it
        target_c = target_c + (_extent(_largest_blob(mask))[0] - rc)
        if abs(z_new - z) < 1e-3 * z and np.linalg.norm(rc - _extent(_largest_blob(mask))[0]) < 0.5:
            break
        z = z_new
    return q


def _rot_y(a: float) -> np.ndarray:
    return pin.exp3(np.array([0.0, a, 0.0]))


def coarse_search(
    robot: Robot,
    q: np.ndarray,
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray],
    yaw_steps: int = 12,
    pitches_deg: Sequence[float] = (-10.0, 0.0, 10.0),
    render_scale: int = 2,
) -> list[tuple[float, float, float, np.ndarray]]:
    """(IoU, yaw°, pitch°, q) for every root rotation about the model centre, best first."""
    cams = [scaled_camera(c, render_scale) for c in cameras]
    small = [_shrink(m, c) for m, c in zip(masks, cams)]
    centre = model_centre(robot, q)
    T = pin.XYZQUATToSE3(q[:7])
    # pitch about the model's own left-right axis (its x axis at rest), turned with the yaw
    side = T.rotation[:, 0]
    side = side - side[1] * np.array([0.0, 1.0, 0.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([1.0, 0.0, 0.0])
    out = []
    for k in range(yaw_steps):
        yaw = 2 * np.pi * k / yaw_steps
        Ry = _rot_y(yaw)
        for p in pitches_deg:
            R = pin.exp3(Ry @ side * np.radians(p)) @ Ry
            qc = _move_root(q, R, centre, np.zeros(3))
            out.append((_iou(robot, qc, cams, small), float(np.degrees(yaw)), float(p), qc))
    out.sort(key=lambda t: -t[0])
    return out


def initial_pose_details(
    robot: Robot,
    cameras: Camera | Sequence[Camera],
    masks: np.ndarray | Sequence[np.ndarray],
    *,
    q_start: np.ndarray | None = None,
    yaw_steps: int = 12,
    pitches_deg: Sequence[float] = (-10.0, 0.0, 10.0),
    refine: int = 3,
    refine_steps: int = 3,
    render_scale: int = 2,
    tracker_kw: dict | None = None,
) -> InitResult:
    """:func:`initial_pose` with the details (see :class:`InitResult`)."""
    from ..ecm.tracker import Tracker

    cameras = [cameras] if isinstance(cameras, Camera) else list(cameras)
    if isinstance(masks, np.ndarray) and masks.ndim == 2:
        masks = [masks]
    masks = [np.asarray(m).astype(bool) for m in masks]
    if len(masks) != len(cameras):
        raise InputDataError(f"initial pose: {len(masks)} masks for {len(cameras)} cameras")
    for k, (m, c) in enumerate(zip(masks, cameras)):
        if m.shape != c.shape:
            raise InputDataError(
                f"initial pose: camera {k} mask is {m.shape[1]}x{m.shape[0]} but the camera is {c.width}x{c.height}"
            )
    if robot.root != "free":
        raise InputDataError(
            f"automatic initialization needs a free root (root='free'), not root={robot.root!r}; "
            "give the initial pose with --init"
        )
    seen = [k for k, m in enumerate(masks) if m.any()]
    if not seen:
        raise InputDataError("initial pose: every mask of the first frame is empty; nothing to start from")
    q = np.array(robot.q_rest if q_start is None else q_start, dtype=float)
    ref = seen[0]
    # place at full resolution in the first camera that sees something (coarse: scaled)
    rcam = scaled_camera(cameras[ref], render_scale)
    q = place(robot, q, rcam, _shrink(masks[ref], rcam))
    cands = coarse_search(robot, q, cameras, masks, yaw_steps, pitches_deg, render_scale)
    coarse = [(y, p, s) for s, y, p, _ in cands]
    # re-place the best candidates (rotation about the centre moves the silhouette a little)
    best: tuple[float, float, float, np.ndarray] | None = None
    # candidates are approximate poses: the body sizes are not measured at them; the
    # search itself tries the turns, so no alternative hypotheses either
    kw = {"prediction": "previous", "calibrate_sizes": False, "mirror_hypothesis": False, "swap_hypothesis": False,
          **(tracker_kw or {})}
    for score, yaw, pitch, qc in cands[: max(1, refine)]:
        qc = place(robot, qc, rcam, _shrink(masks[ref], rcam), passes=2)
        if refine_steps > 0:
            try:
                tr = Tracker(robot, cameras, q0=qc, **kw)
            except Exception:  # noqa: BLE001 - a camera does not see this candidate: skip it
                continue
            r = None
            for _ in range(refine_steps):
                r = tr.step(masks, source="initial pose")
            qc, fit = r.q, r.fit
        else:
            fit = score
        if best is None or fit > best[0]:
            best = (fit, yaw, pitch, qc)
    if best is None:
        s, y, p, qc = cands[0]
        best = (s, y, p, qc)
    return InitResult(best[3], float(best[0]), best[1], best[2], coarse)


def initial_pose(
    robot: Robot, cameras: Camera | Sequence[Camera], masks: np.ndarray | Sequence[np.ndarray], **kw: Any
) -> np.ndarray:
    """A starting configuration for ``robot`` (root="free") from one frame's masks
    (one per camera): placement, coarse root-rotation search, ECM refinement
    (module docstring).  Keyword arguments as :func:`initial_pose_details`."""
    return initial_pose_details(robot, cameras, masks, **kw).q


def _rotation(value, where: str) -> np.ndarray:
    R = np.asarray(value, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InputDataError(f"{where}: root rotation must be a 3x3 matrix")
    off, det = rotation_error(R)
    if off > 1e-3 or det < 0:
        raise InputDataError(f"{where}: root rotation is not a rotation matrix (RᵀR ≠ I or det < 0)")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def read_pose_json(robot: Robot, path: str | os.PathLike) -> np.ndarray:
    """Configuration from a pose file (module docstring); angles in degrees."""
    where = str(path)
    data = read_json(path, InputDataError)
    if not isinstance(data, dict):
        raise InputDataError(f"{where}: expected an object with 'joints' and/or 'root'")
    unknown = sorted(set(data) - {"joints", "root"})
    if unknown:
        raise InputDataError(f"{where}: unknown key(s) {', '.join(unknown)} (expected 'joints', 'root')")
    q = np.array(robot.q_rest, dtype=float)
    joints = data.get("joints", {})
    if not isinstance(joints, dict):
        raise InputDataError(f"{where}: 'joints' must be an object {{name: degrees}}")
    kinds = {n: j.kind for j in robot.joints if j.kind != "free" for n in j.names}
    for name, deg in joints.items():
        if name not in kinds:
            if f"{name}_x" in kinds:
                raise InputDataError(f"{where}: joint '{name}' is spherical: give {name}_x, {name}_y and "
                                     f"{name}_z (its X-Y-Z angles, degrees)")
            raise InputDataError(
                f"{where}: '{robot.system.name}' has no joint coordinate '{name}'{did_you_mean(name, kinds)}"
            )
        unit = "spec length units" if kinds[name] == "prismatic" else "degrees"
        if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not np.isfinite(deg):
            raise InputDataError(f"{where}: joint '{name}': value must be a number ({unit}), not {deg!r}")
    q = robot.with_coordinates(q, {name: float(v) for name, v in joints.items()})
    if "root" in data:
        root = data["root"]
        if robot.root != "free":
            raise InputDataError(f"{where}: 'root' given but the model's root is not free (use --root free)")
        if not isinstance(root, dict):
            raise InputDataError(f"{where}: 'root' must be an object with 'position' and 'rotation'")
        T = pin.XYZQUATToSE3(q[:7])
        p, R = T.translation.copy(), T.rotation.copy()
        if "position" in root:
            pos = np.asarray(root["position"], dtype=float) if _numbers(root["position"], 3) else None
            if pos is None:
                raise InputDataError(f"{where}: root position must be [x, y, z]")
            p = pos
        if "rotation" in root and "quaternion_xyzw" in root:
            raise InputDataError(f"{where}: give the root's 'rotation' or 'quaternion_xyzw', not both")
        if "rotation" in root:
            R = _rotation(root["rotation"], where)
        elif "quaternion_xyzw" in root:
            if not _numbers(root["quaternion_xyzw"], 4):
                raise InputDataError(f"{where}: quaternion_xyzw must be [x, y, z, w]")
            x, y, z, w = map(float, root["quaternion_xyzw"])
            n = np.sqrt(x * x + y * y + z * z + w * w)
            if not n > 1e-9:
                raise InputDataError(f"{where}: quaternion_xyzw is zero")
            R = pin.Quaternion(w / n, x / n, y / n, z / n).toRotationMatrix()
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def _numbers(value, n: int) -> bool:
    return (
        isinstance(value, list)
        and len(value) == n
        and all(not isinstance(v, bool) and isinstance(v, (int, float)) and np.isfinite(v) for v in value)
    )
