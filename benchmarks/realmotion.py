"""Real human motion (issue #31): CMU motion capture rendered as capsules, tracked with the
model ``kms2pin import`` makes of the same skeleton; accuracy in mm at 13 joints, and speed.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realmotion.py [--only walk-2cam-320,...]
        [--bvh FILE] [--frames N] [--seed 0] [--option NAME=VALUE] [--defaults] [--no-references]
        [--cache DIR] [--arm-probe]

What is measured (docs/benchmarks.md, "Real human motion"):

- **The subject**: the BVH file imported exactly (every joint spherical, ``kms2pin import
  --scale 0.05644 --fps 30``), rendered as capsules (``synth --shape capsule``: each body's
  capsule, not its ellipsoid) at 30 Hz with 5 % noise (``synth --noise 0.05``).  ``fast``
  is the same trial at twice the speed (imported at 15 frames/s and played at 30): every
  frame's motion doubled; ``mirror`` the trial mirrored left to right (:func:`mirrored`):
  another walker, since the subject's two sides differ, making the mirror-image walk.
- **The model**: ``kms2pin import --hinge LeftKnee,RightKnee,LeftElbow,RightElbow`` (knees and
  elbows hinged, as a careful user would), edited as a careful user would: the hinges
  given anatomical limits (:data:`HINGE_LIMITS`), and (:data:`FIXED`) the pelvis sides
  and the fingers, which the file never moves, and the thumbs, 1-2 pixels wide, made
  fixed joints.  It differs from the subject in its
  shape (ellipsoids, sized by the anthropometric table, against the capsules), in those
  fixed joints, and in its hinges (CMU's knees and elbows turn about one axis: exact).
- **The rig**: cameras around the walking path as a lab places them (:func:`rig`), 5.5-7 m
  from its centre, 2-2.8 m high, one lens that keeps the whole path in every view; one
  camera is the first of them, two the first two, four all.  320x240 and 640x480.
- **The track**: :class:`kms2pin.ecm.Tracker` started at the floor pose of the first frame
  (below: for this model, the true joint positions exactly, the shape still not the
  subject's); with the presets for people (``kms2pin.ecm.PEOPLE``: the learnt
  motion model and the reach search; one camera ``PEOPLE_ONE_CAMERA``: those and the
  upright, rest and ground priors), or the tracker's defaults (``--defaults``).
- **Errors** at the 13 joints (hips, knees, ankles, shoulders, elbows, wrists, the neck),
  the mean distance per frame in mm, no alignment: the mean over the frames, the median,
  the 90th percentile, the worst frame, the last 30 frames' mean over the first 30's; knee
  and elbow flexion (the angle between the bones, from the joint positions) RMSE, the
  knees' and the elbows' apart; the same for the track smoothed offline (``track --smooth``
  at :data:`SMOOTH_HZ`, :mod:`kms2pin.ecm.smoothing`); frames/s; with one camera the error split along the
  camera's rays (the depth one view hardly sees) and across them
  (:func:`kms2pin.ecm.evaluate.ray_parts`); with tracks beside (``--option
  second_track=...``) the same for each stretch taken from the track that fits it best
  (``track --stretches``, :mod:`kms2pin.ecm.stretches`), raw and smoothed.
- **References**: the *floor*, the model's configuration nearest the subject's true joint
  points on each frame (:func:`floor_poses`: what the model can express at best; here the
  import's own angles, exact at the 13 joints, checked); *ECM from the floor*,
  one frame's ECM started at the floor pose on each frame (what the silhouettes pull the
  best pose to; :meth:`Tracker.refine`); and *own renders*, the same track on the
  model's own ellipsoids moving as the floor (the tracker's figure on its own renders, and
  the baseline of the frames/s ratio).
- **Fit**: the mean silhouette fit (IoU, :meth:`Tracker.fit` at the sizes the track ended
  with) of the tracked poses, of the floor poses and of ECM from the floor, and the share
  of frames where the floor fits better than the track.  It tells the tracker's share of
  the error apart: where the floor fits better the track lost a search (ECM's basin
  holds a better pose it did not reach); where the track fits as well or better, the
  silhouettes cannot tell the poses apart.
- **The arm probe** (``--arm-probe``, :func:`arm_probe`): the same question for a lost arm
  alone.  Where the track has a wrist more than 150 mm off, the arm is put at the truth,
  the rest of the body left as tracked, and one frame's ECM is run from there and from the
  track: if the true arm ends fitting better, a search that proposed it would keep it; if
  not, the silhouettes cannot tell the arm's place, and no search can.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import os
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pinocchio as pin  # noqa: E402

from kms2pin.bvh import BvhFile, ImportOptions, import_bvh, read_bvh  # noqa: E402
from kms2pin.commands._outputs import replaced  # noqa: E402
from kms2pin.ecm import PEOPLE, PEOPLE_ONE_CAMERA, Camera, Tracker  # noqa: E402
from kms2pin.ecm.evaluate import ray_parts  # noqa: E402
from kms2pin.ecm.limbs import hinged_bodies, sides  # noqa: E402
from kms2pin.ecm.options import OPTION_GROUP  # noqa: E402
from kms2pin.ecm.smoothing import smooth  # noqa: E402
from kms2pin.ecm.stretches import stretches, track_poses  # noqa: E402
from kms2pin.ecm.synth import synthesize  # noqa: E402
from kms2pin.lang import parse_text  # noqa: E402
from kms2pin.robot import Robot  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MOCAP = Path("shared") / "data" / "mocap" / "cmu_131_01_start_walk_stop.bvh"
#: the shared CMU trial: ../shared/data/mocap beside the repository (a worktree's: further up)
BVH = next((d / MOCAP for d in ROOT.parents if (d / MOCAP).exists()), ROOT.parent / MOCAP)
SCALE = 0.05644  # CMU units to metres (the data's README)
FPS = 30.0
NOISE = 0.05
#: the low-pass cutoff of the smoothed rows (Hz; ``track --smooth``): gait analysis's usual
#: 6 Hz for walking, not tuned here
SMOOTH_HZ = 6.0
#: the 13 joints, by the body whose joint point each is (a wrist: the hand's; CMU's 'Neck'
#: joint, between the lower and the upper neck)
JOINTS = ("LeftHip", "LeftKnee", "LeftAnkle", "RightHip", "RightKnee", "RightAnkle", "LeftShoulder", "LeftElbow",
          "lhand", "RightShoulder", "RightElbow", "rhand", "Neck")
#: flexion angles: (the joint, the one above it, the one below), by their places in JOINTS
FLEXION = {"left knee": (1, 0, 2), "right knee": (4, 3, 5), "left elbow": (7, 6, 8), "right elbow": (10, 9, 11)}
HINGES = ("LeftKnee", "RightKnee", "LeftElbow", "RightElbow")
#: the hinges' limits a careful user adds (degrees; the import makes flexion positive)
HINGE_LIMITS = (-5.0, 160.0)
#: joints a careful user makes fixed: the pelvis sides and the fingers never move in CMU's
#: files, and the thumbs are 1-2 pixels wide at these resolutions
FIXED = ("LHipJoint", "RHipJoint", "LFingers", "RFingers", "LThumb", "RThumb")
#: where rendered masks are kept between runs (``--cache``)
CACHE = Path(tempfile.gettempdir()) / "kms2pin-realmotion"
#: motions: (the trial's playback speed, mirrored left to right)
MOTIONS = {"walk": (1.0, False), "fast": (2.0, False), "mirror": (1.0, True)}
#: the lab's cameras: (azimuth from the path's main direction, deg; distance from the path's
#: centre, m; height, m); n cameras are the first n
CAMERAS = ((60.0, 6.0, 2.0), (150.0, 6.5, 2.8), (240.0, 7.0, 2.4), (330.0, 5.5, 2.2))
#: the cases: (motion, cameras, size as a multiple of 320x240, the preset: PEOPLE_ONE_CAMERA
#: with one camera, PEOPLE with more)
CASES = {f"{m}-{n}cam-{w}": (m, n, w // 320, PEOPLE_ONE_CAMERA if n == 1 else PEOPLE)
         for m in MOTIONS for n in (2, 4, 1) for w in (320, 640)}


@dataclass(frozen=True)
class Sequence:
    """A motion: the ``subject`` (exact import) and its configurations ``q`` at 30 Hz, the
    tracking ``model`` (hinged, :data:`FIXED` fixed) and its ``floor`` poses; ``path``
    (frames, 3) the root's positions over the whole motion (the rig's)."""

    name: str
    subject: Robot
    q: np.ndarray
    model: Robot
    floor: np.ndarray
    path: np.ndarray


def tracking_model(bvh, speed: float) -> tuple[Robot, np.ndarray]:
    """The model a careful user tracks with (module docstring) and its import's
    configurations with :data:`FIXED` left out (its floor poses, :func:`floor_poses`)."""
    imp = import_bvh(bvh, ImportOptions(scale=SCALE, fps=FPS / speed, hinges=HINGES, name="model"))
    text = imp.text
    lines = {name: next(x for x in text.splitlines() if x.strip().startswith("constraint") and f", {name}.joint" in x)
             for name in FIXED + HINGES}
    for name in FIXED:
        text = text.replace(lines[name], lines[name].replace("spherical(", "fixed("))
    for name in HINGES:
        text = text.replace(lines[name], lines[name].replace(", 0);", f", 0, {HINGE_LIMITS[0]:g}, {HINGE_LIMITS[1]:g});"))
    spec = parse_text(text, "model.kms")
    robot = Robot(spec, spec.system(), "free")
    kept = [imp.robot.model.getJointId(robot.model.names[j]) for j in range(1, robot.model.njoints)]
    cols = np.concatenate([np.arange(imp.robot.model.idx_qs[j], imp.robot.model.idx_qs[j] + imp.robot.model.nqs[j])
                           for j in kept])
    return robot, imp.q[:, cols]


def points(robot: Robot, q: np.ndarray, names=None) -> np.ndarray:
    """(n, 3) world positions (m) of the joint points of the bodies ``names`` (default:
    every bound vector of every body, in the order of the spec)."""
    robot.forward(q)
    pin.updateFramePlacements(robot.model, robot.data)
    oMf = robot.data.oMf
    if names is not None:
        return np.array([oMf[robot.model.getFrameId(n)].translation for n in names])
    out = []
    for body, fid in zip(robot.system.bodies, robot.frame_ids):
        M = oMf[fid]
        out += [M.act(np.asarray(b.pos, dtype=float)) for b in body.bvecs.values()]
    return np.array(out)


def floor_poses(model: Robot, subject: Robot, q_subject: np.ndarray, q_start: np.ndarray,
                tol: float = 1e-6) -> np.ndarray:
    """Per frame, the model's configuration nearest the subject's at the 13 :data:`JOINTS`.
    Where the hinged import's own angles ``q_start`` put every one of those joints where
    the subject's is (to ``tol``, m: CMU's knees and elbows turn about one axis, and the
    joints :data:`FIXED` moves none of the 13), they are the floor; otherwise (a joint made
    fixed that the file moves) the floor is the least-squares fit (:func:`fit_points`)
    started there."""
    out = []
    for qs, qm in zip(q_subject, q_start):
        target = points(subject, qs, JOINTS)
        q = pin.normalize(model.model, np.array(qm, dtype=float))  # unit quaternions
        if float(np.linalg.norm(points(model, q, JOINTS) - target, axis=1).max()) > tol:
            q = fit_points(model, target, q)
        out.append(q)
    return np.array(out)


def fit_points(model: Robot, target: np.ndarray, q: np.ndarray, iterations: int = 100) -> np.ndarray:
    """The configuration near ``q`` whose :data:`JOINTS` come nearest ``target`` (13, 3):
    Levenberg-Marquardt on the joints' world positions (Pinocchio's frame Jacobians,
    world-aligned), steps by ``pin.integrate``, joint limits kept."""
    frames = [model.model.getFrameId(n) for n in JOINTS]
    data, lam = model.data, 1e-6

    def residual(x: np.ndarray) -> np.ndarray:
        return (points(model, x, JOINTS) - target).ravel()

    r = residual(q)
    for _ in range(iterations):
        pin.computeJointJacobians(model.model, data, q)
        J = np.vstack([pin.getFrameJacobian(model.model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in frames])
        g, H = J.T @ r, J.T @ J
        while lam < 1e6:
            step = -np.linalg.solve(H + lam * np.eye(len(H)), g)
            c = model.clamp(pin.integrate(model.model, q, step))
            rc = residual(c)
            if rc @ rc < r @ r:
                q, lam = c, max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        else:
            break
        shrink = r @ r - rc @ rc
        r = rc
        if shrink < 1e-16:
            break
    return q


def mirrored(bvh: BvhFile) -> BvhFile:
    """``bvh`` reflected through the plane across its X axis, left and right exchanged.  A
    reflection P turns a rotation about u by θ into one about P u by -θ: the rotation
    channels about Y and Z change sign, those about X do not (so each joint keeps its
    Euler order), and offsets, End Sites and position channels have x negated.  A joint
    named ``Left*``, ``L*`` or ``l*`` (``Right*``, ``R*``, ``r*``) whose twin is in the file
    takes its twin's name."""
    names = {j.name for j in bvh.joints}

    def twin(name: str) -> str:
        for a, b in (("Left", "Right"), ("Right", "Left"), ("L", "R"), ("R", "L"), ("l", "r"), ("r", "l")):
            if name.startswith(a) and (other := b + name[len(a):]) in names:
                return other
        return name

    def flip(p) -> tuple[float, float, float]:
        return (-float(p[0]), float(p[1]), float(p[2]))

    motion = np.array(bvh.motion, dtype=float)
    joints = []
    for j in bvh.joints:
        for k, c in enumerate(j.channels):
            if c.lower() in ("xposition", "yrotation", "zrotation"):
                motion[:, j.first + k] *= -1.0
        joints.append(replace(j, name=twin(j.name), offset=flip(j.offset),
                              end_sites=tuple(flip(e) for e in j.end_sites)))
    return replace(bvh, joints=tuple(joints), motion=motion)


def load_sequence(path: Path, motion: str, frames: int | None) -> Sequence:
    """The subject, the model and the floor of ``motion`` (:data:`MOTIONS`) of the BVH file."""
    speed, mirror = MOTIONS[motion]
    bvh = mirrored(read_bvh(path)) if mirror else read_bvh(path)
    imp = import_bvh(bvh, ImportOptions(scale=SCALE, fps=FPS / speed, name="subject"))
    model, start = tracking_model(bvh, speed)
    q = imp.q[:frames]
    return Sequence(motion, imp.robot, q, model, floor_poses(model, imp.robot, q, start[:frames]), imp.q[:, :3])


def rig(q_root: np.ndarray, n: int, factor: int) -> list[Camera]:
    """The first ``n`` of :data:`CAMERAS` around the path of the root positions
    ``q_root`` (frames, 3), at 320x240 times ``factor``, all with the least field of view
    that holds the whole path (0.5 m around the root's, 0-1.9 m high) in every view."""
    xz = q_root[:, [0, 2]]
    centre = xz.mean(axis=0)
    _, _, vt = np.linalg.svd(xz - centre)
    main = vt[0]  # the path's main direction on the ground
    lo, hi = xz.min(axis=0) - 0.5, xz.max(axis=0) + 0.5
    target = np.array([(lo[0] + hi[0]) / 2, 0.9, (lo[1] + hi[1]) / 2])
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (0.0, 1.9) for z in (lo[1], hi[1])])
    places = []
    for azimuth, distance, height in CAMERAS[:n]:
        a = np.radians(azimuth)
        d = np.cos(a) * main + np.sin(a) * np.array([-main[1], main[0]])
        places.append(np.array([target[0] + distance * d[0], height, target[2] + distance * d[1]]))
    fov = 0.0
    for p in places:
        c = Camera.look_at(p, target).to_camera(box)
        fov = max(fov, 2 * np.degrees(np.arctan(np.abs(c[:, 1] / c[:, 2]).max())),
                  2 * np.degrees(np.arctan(np.abs(c[:, 0] / c[:, 2]).max() * 3 / 4)))
    return [Camera.look_at(p, target, width=320 * factor, height=240 * factor, fov_deg=1.05 * fov, name=f"cam{i}")
            for i, p in enumerate(places)]


def rendered(robot: Robot, q: np.ndarray, cameras: list[Camera], shape: str, seed: int, cache: Path | None):
    """The masks of ``robot`` moving through ``q`` seen by ``cameras`` (``synth``'s
    rendering and 5 % noise), kept in ``cache`` by a digest of everything they depend on."""
    key = hashlib.sha1(repr((robot.urdf, q.round(9).tobytes(), [c.to_dict() for c in cameras], shape, seed,
                             NOISE)).encode()).hexdigest()[:16]
    path = None if cache is None else cache / f"masks-{key}.npz"
    if path is not None and path.exists():
        packed = np.load(path)["masks"]
        return list(np.unpackbits(packed, axis=-1, count=cameras[0].width).astype(bool))
    masks = [m for _, m in synthesize(robot, q, cameras, noise=NOISE, rng=np.random.default_rng(seed), shape=shape)]
    if path is not None:  # written whole or not at all: a run stopped while writing leaves no broken file
        with replaced(path) as tmp:
            np.savez_compressed(tmp, masks=np.packbits(np.array(masks), axis=-1))
    return masks


def joint_errors(model: Robot, qs, truth: np.ndarray) -> np.ndarray:
    """(frames,) mean distance (mm) of the 13 :data:`JOINTS` at ``qs`` from ``truth`` (frames, 13, 3)."""
    return np.array([np.linalg.norm(points(model, q, JOINTS) - t, axis=1).mean() for q, t in zip(qs, truth)]) * 1e3


def flexion(p: np.ndarray) -> np.ndarray:
    """(frames, 4) knee and elbow flexion (deg) of joint positions ``p`` (frames, 13, 3):
    the angle between the bone above the joint and the one below (0 straight)."""
    out = []
    for j, above, below in FLEXION.values():
        a, b = p[:, j] - p[:, above], p[:, below] - p[:, j]
        cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.array(out).T


def summary(err: np.ndarray, flex_rmse: tuple[float, float]) -> str:
    """One row's figures from the per-frame errors (mm) and the knees' and elbows' flexion RMSE (deg)."""
    m = min(30, len(err))
    return (f"mean {err.mean():6.1f} mm | median {np.median(err):6.1f} | p90 {np.percentile(err, 90):6.1f} | worst "
            f"{err.max():6.1f} (frame {int(err.argmax()):3d}) | last/first 30 {err[-m:].mean() / err[:m].mean():5.2f} | "
            f"flexion RMSE knees {flex_rmse[0]:5.1f} elbows {flex_rmse[1]:5.1f} deg")


def track(seq: Sequence, cameras, masks, options: dict, clock=time.perf_counter, tracks: list | None = None):
    """Track ``masks`` from the floor's first pose; returns (configurations, frames/s by
    ``clock``, flags per frame, the tracker).  ``tracks``, a list, is given each frame's
    ``track_poses`` (every track's own pose, for ``stretches``)."""
    tr = Tracker(seq.model, cameras, q0=seq.floor[0], **options)
    t0 = clock()
    results = []
    for k, m in enumerate(masks):
        results.append(tr.step(m, source=f"frame {k}"))
        if tracks is not None:
            tracks.append(track_poses(tr))
    fps = len(masks) / max(clock() - t0, 1e-9)
    return np.array([r.q for r in results]), fps, [r.flags for r in results], tr


def fits(tracker: Tracker, qs, masks) -> np.ndarray:
    """Each frame's silhouette fit (IoU) at ``qs``, at the tracker's sizes after its track."""
    return np.array([tracker.fit(q, m, source=f"frame {k}") for k, (q, m) in enumerate(zip(qs, masks))])


def ecm_from_floor(seq: Sequence, cameras, masks, options: dict) -> np.ndarray:
    """Each frame's ECM from its floor pose (:meth:`Tracker.refine`, the sizes measured on
    the first frame at its floor pose)."""
    tr = Tracker(seq.model, cameras, q0=seq.floor[0], **options)
    tr.calibrate(masks[0])
    return np.array([tr.refine(q, m, source=f"frame {k}")[0] for k, (q, m) in enumerate(zip(seq.floor, masks))])


#: the probe's lost arm: a wrist this far from the truth's (mm); and the fit (IoU) a pose must
#: gain over another to fit better
LOST_WRIST = 150.0
PROBE_GAIN = 0.003
#: the arms' joints, by their places in JOINTS
ARMS = {"left": (6, 7, 8), "right": (9, 10, 11)}


def arm_probe(seq: Sequence, tracker: Tracker, qs, masks, truth: np.ndarray, every: int = 3) -> dict:
    """Can the silhouettes tell a lost arm from the true one?  On every ``every``-th frame,
    each arm whose wrist the track ``qs`` has more than :data:`LOST_WRIST` from the truth is
    put at the truth (:func:`fit_points` to the true shoulder, elbow and wrist, the other
    joints where the track has them) and one frame's ECM (:meth:`Tracker.refine`) is run
    from there and from the track.  Returns the cases, the share on which the true arm
    ends fitting better by :data:`PROBE_GAIN`, the mean fits and the wrists' mean error
    (mm) before and after."""
    rows = []
    for k in range(0, len(qs), every):
        p = points(seq.model, qs[k], JOINTS)
        lost = [list(idx) for idx in ARMS.values() if np.linalg.norm(p[idx[2]] - truth[k, idx[2]]) * 1e3 > LOST_WRIST]
        if not lost:
            continue
        q_a, f_a = tracker.refine(qs[k], masks[k], source=f"frame {k}")  # the track's, once for both arms
        for idx in lost:
            target = p.copy()
            target[idx] = truth[k, idx]
            q_b, f_b = tracker.refine(fit_points(seq.model, target, qs[k]), masks[k], source=f"frame {k}")
            wrist = [np.linalg.norm(points(seq.model, x, JOINTS)[idx[2]] - truth[k, idx[2]]) * 1e3 for x in (q_a, q_b)]
            rows.append((f_a, f_b, *wrist))
    r = np.array(rows).reshape(-1, 4)
    if not len(r):
        return {"cases": 0}
    return {"cases": len(r), "better": float(np.mean(r[:, 1] > r[:, 0] + PROBE_GAIN)), "fit_track": r[:, 0].mean(),
            "fit_true": r[:, 1].mean(), "wrist_track": r[:, 2].mean(), "wrist_true": r[:, 3].mean()}


#: a frame is lost above this mean error (mm; the issue's two-camera worst frame); a lost
#: ankle or wrist is this far from the truth's (mm); the trunk is twisted when the chest's
#: left/right axis is this far from the pelvis's (deg; the truth's stay within 26 on every case)
LOST_MM = 120.0
LOST_END_MM = 250.0
TWISTED_DEG = 45.0
#: the ankles' and wrists' places in JOINTS
ANKLES, WRISTS = (2, 5), (8, 11)


def losses(model: Robot, qs, truth: np.ndarray, err: np.ndarray) -> dict[str, int]:
    """What the frames above :data:`LOST_MM` (``err``, mm) have lost, each counted once per
    kind: ``twisted``, the chest turned from the pelvis (their sagittal planes'
    normals, :func:`~kms2pin.ecm.limbs.sides`, more than :data:`TWISTED_DEG` apart);
    ``arms_across`` and ``legs_across``, an arm's root across the chest's midline (the
    arms traded through it) or a leg's across the pelvis's; ``ankle`` and ``wrist``, one
    more than :data:`LOST_END_MM` off (a leg, an arm lost); ``other``, none of these."""
    sd = sides(model, hinged_bodies(model))
    out = {"frames": 0, "twisted": 0, "arms_across": 0, "legs_across": 0, "ankle": 0, "wrist": 0, "other": 0}
    if sd is None:
        return out
    joint_of = {a: int(model.model.frames[model.frame_ids[a]].parentJoint) for a in {int(a) for a in sd.anchor}}
    pelvis, chest = sorted(joint_of, key=joint_of.get) if len(joint_of) == 2 else (None, None)
    normals = {int(a): n for a, n in zip(sd.anchor, sd.normal)}
    legs = np.array([int(a) == pelvis for a in sd.anchor])
    for q, t, e in zip(qs, truth, err):
        if e <= LOST_MM:
            continue
        out["frames"] += 1
        poses = model.body_poses(q)
        Rs = np.array([P.rotation for P in poses])
        ts = np.array([P.translation for P in poses])
        side = np.einsum("kij,kj,ki->k", Rs[sd.anchor], sd.normal, ts[sd.body] - ts[sd.anchor]) * sd.sign
        twisted = pelvis is not None and float((Rs[pelvis] @ normals[pelvis]) @ (Rs[chest] @ normals[chest])) < \
            np.cos(np.radians(TWISTED_DEG))
        off = np.linalg.norm(points(model, q, JOINTS) - t, axis=1) * 1e3
        kinds = {"twisted": twisted, "arms_across": bool((side < 0)[~legs].any()),
                 "legs_across": bool((side < 0)[legs].any()), "ankle": off[list(ANKLES)].max() > LOST_END_MM,
                 "wrist": off[list(WRISTS)].max() > LOST_END_MM}
        for k, v in kinds.items():
            out[k] += int(v)
        out["other"] += int(not any(kinds.values()))
    return out


def run_case(name: str, seq: Sequence, seed: int, cache: Path | None, references: bool, options: dict,
             preset: bool = True, probe: bool = False) -> dict:
    """Track one case (with its preset unless not ``preset``: the tracker's defaults) and
    print its rows; returns its figures."""
    motion, n, factor, case_preset = CASES[name]
    options = {**(case_preset if preset else {}), **options}
    cameras = rig(seq.path, n, factor)
    truth = np.array([points(seq.subject, q, JOINTS) for q in seq.q])
    masks = rendered(seq.subject, seq.q, cameras, "capsule", seed, cache)
    tracks = [] if options.get("second_track") else None
    q, fps, flags, tracker = track(seq, cameras, masks, options, tracks=tracks)
    err = joint_errors(seq.model, q, truth)
    flex_true = flexion(truth)

    def flex_rmse(qs) -> tuple[float, float]:  # the knees', the elbows' (FLEXION's order)
        sq = (flexion(np.array([points(seq.model, x, JOINTS) for x in qs])) - flex_true) ** 2
        return float(np.sqrt(sq[:, :2].mean())), float(np.sqrt(sq[:, 2:].mean()))

    flagged = sum(1 for f in flags if f)
    print(f"{name:16s} tracked        | {summary(err, flex_rmse(q))} | {fps:5.1f} fr/s | {flagged} frames flagged",
          flush=True)
    row = {"mean": err.mean(), "worst": err.max(), "flexion": flex_rmse(q), "fps": fps}
    lost = losses(seq.model, q, truth, err)
    print(f"{name:16s} lost frames    | {lost['frames']} above {LOST_MM:g} mm: the chest twisted from the pelvis on "
          f"{lost['twisted']}, an arm's root across the chest's midline on {lost['arms_across']}, a leg's across the "
          f"pelvis's on {lost['legs_across']}, an ankle {LOST_END_MM:g} mm off on {lost['ankle']}, a wrist on "
          f"{lost['wrist']}, none of these on {lost['other']}", flush=True)
    row |= {"lost": lost}
    q_smooth = smooth(seq.model, q, FPS, SMOOTH_HZ)
    err_smooth = joint_errors(seq.model, q_smooth, truth)
    print(f"{name:16s} smoothed {SMOOTH_HZ:g} Hz  | {summary(err_smooth, flex_rmse(q_smooth))}", flush=True)
    row |= {"smoothed": err_smooth.mean(), "flexion_smoothed": flex_rmse(q_smooth)}
    if tracks is not None:  # tracks beside: each stretch from the track that fits it best (track --stretches)
        st = stretches(tracker, masks, np.array(tracks))
        err_st = joint_errors(seq.model, st.q, truth)
        print(f"{name:16s} stretches      | {summary(err_st, flex_rmse(st.q))} | "
              f"{int(np.sum(st.track[1:] != st.track[:-1]))} changes of track", flush=True)
        q_st = smooth(seq.model, st.q, FPS, SMOOTH_HZ)
        print(f"{name:16s} stretches {SMOOTH_HZ:g} Hz | {summary(joint_errors(seq.model, q_st, truth), flex_rmse(q_st))}",
              flush=True)
        row |= {"stretches": err_st.mean()}
    if n == 1:  # one view: how much of the error is depth
        along, side = ray_parts(np.array([points(seq.model, x, JOINTS) for x in q]), truth, cameras[0].centre)
        depth, across = np.abs(along).mean(axis=1) * 1e3, side.mean(axis=1) * 1e3
        print(f"{name:16s} along the ray  | mean {depth.mean():6.1f} mm along the camera's rays, {across.mean():6.1f} "
              f"across them", flush=True)
        row |= {"depth": depth.mean(), "across": across.mean()}
    fit, fit_floor = fits(tracker, q, masks), fits(tracker, seq.floor, masks)
    print(f"{name:16s} fit (IoU)      | tracked {fit.mean():.3f}, floor {fit_floor.mean():.3f}: the floor fits better "
          f"on {np.mean(fit_floor > fit):.0%} of the frames", flush=True)
    row |= {"fit": fit.mean(), "fit_floor": fit_floor.mean()}
    if probe:
        pr = arm_probe(seq, tracker, q, masks, truth)
        if pr["cases"]:
            print(f"{name:16s} arm probe      | {pr['cases']} lost arms (every third frame): from the true arm ECM "
                  f"fits better by {PROBE_GAIN} on {pr['better']:.0%} ({pr['fit_true']:.4f} against "
                  f"{pr['fit_track']:.4f}); wrists {pr['wrist_true']:.0f} against {pr['wrist_track']:.0f} mm", flush=True)
        else:
            print(f"{name:16s} arm probe      | no lost arm", flush=True)
    if references:
        floor = joint_errors(seq.model, seq.floor, truth)
        print(f"{name:16s} floor          | {summary(floor, flex_rmse(seq.floor))}", flush=True)
        from_floor = ecm_from_floor(seq, cameras, masks, options)
        e2 = joint_errors(seq.model, from_floor, truth)
        print(f"{name:16s} ECM from floor | {summary(e2, flex_rmse(from_floor))} | fit "
              f"{fits(tracker, from_floor, masks).mean():.3f}", flush=True)
        own = rendered(seq.model, seq.floor, cameras, "ellipsoid", seed, cache)
        q_own, fps_own, _, _ = track(seq, cameras, own, options)
        e3 = joint_errors(seq.model, q_own, np.array([points(seq.model, x, JOINTS) for x in seq.floor]))
        print(f"{name:16s} own renders    | {summary(e3, flex_rmse(q_own))} | {fps_own:5.1f} fr/s", flush=True)
        print(f"{name:16s} ratios         | tracked / ECM from floor {err.mean() / e2.mean():.2f}x, tracked - floor "
              f"{err.mean() - floor.mean():+.1f} mm, frames/s real / own renders {fps / fps_own:.2f}", flush=True)
        row |= {"floor": floor.mean(), "from_floor": e2.mean(), "own": e3.mean(), "fps_ratio": fps / fps_own}
    return row


def split_items(text: str) -> list[str]:
    """``text`` split at the commas outside quotes (``a=1,b='x=1,y=2'`` -> two items)."""
    items, start, quote = [], 0, ""
    for i, c in enumerate(text):
        if c in "'\"" and quote in ("", c):
            quote = "" if quote else c
        elif c == "," and not quote:
            items.append(text[start:i])
            start = i + 1
    return [x for x in (*items, text[start:]) if x.strip()]


def parse_options(items: list[str], flag: str, error) -> dict:
    """``NAME=VALUE`` items, each a Tracker option (the value a Python literal, else the
    text), as a dict; ``error`` (argparse's) for an item that is not one."""
    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in OPTION_GROUP:
            error(f"{flag} wants NAME=VALUE with a Tracker option's name, not {item!r}")
        try:
            options[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            options[key.strip()] = value.strip()
    return options


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bvh", type=Path, default=BVH, help="the motion capture (default: the shared CMU walk)")
    p.add_argument("--only", help="comma-separated cases: " + ", ".join(CASES))
    p.add_argument("--frames", type=int, help="track only the first N frames")
    p.add_argument("--seed", type=int, default=0, help="the masks' noise seed")
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="a Tracker option for every case (repeatable)")
    p.add_argument("--defaults", action="store_true",
                   help="track with the tracker's defaults, not the cases' presets (PEOPLE, PEOPLE_ONE_CAMERA)")
    p.add_argument("--no-references", dest="references", action="store_false",
                   help="leave out the floor, ECM from the floor and the own renders")
    p.add_argument("--cache", type=Path, default=CACHE,
                   help="where rendered masks are kept between runs")
    p.add_argument("--arm-probe", action="store_true",
                   help="on frames whose wrist is lost, whether the silhouettes prefer the true arm (arm_probe)")
    a = p.parse_args()
    options = parse_options(a.option, "--option", p.error)
    names = a.only.split(",") if a.only else list(CASES)
    bad = [n for n in names if n not in CASES]
    if bad:
        p.error(f"--only: no case {', '.join(bad)}; the cases are {', '.join(CASES)}")
    sequences: dict[str, Sequence] = {}
    rows = {}
    for name in names:
        motion = CASES[name][0]
        if motion not in sequences:
            sequences[motion] = load_sequence(a.bvh, motion, a.frames)
        rows[name] = run_case(name, sequences[motion], a.seed, a.cache, a.references, options, not a.defaults,
                              a.arm_probe)
    print("\ncase             |  mean |  worst | knees, elbows | frames/s | fit: tracked / floor" + (" | floor | ECM from floor | own renders | "
                                                                      "fr/s real / own" if a.references else ""))
    for name, r in rows.items():
        print(f"{name:16s} | {r['mean']:5.1f} | {r['worst']:6.1f} | {r['flexion'][0]:5.1f}, {r['flexion'][1]:5.1f} deg | {r['fps']:8.1f}"
              f" | {r['fit']:.3f} / {r['fit_floor']:.3f}"
              + (f" | {r['floor']:5.1f} | {r['from_floor']:14.1f} | {r['own']:11.1f} | {r['fps_ratio']:.2f}"
                 if a.references else ""))
    if len(rows) > 1:
        print(f"median of {len(rows)} cases: mean error {np.median([r['mean'] for r in rows.values()]):.1f} mm, "
              f"{np.median([r['fps'] for r in rows.values()]):.1f} frames/s")

if __name__ == "__main__":
    main()
