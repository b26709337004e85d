"""ECM tracking benchmark: synthetic sequences (5 % noise, 10 % body-size mismatch,
320x240; the human 640x480) tracked from the rest pose; accuracy and speed (one core).

    .venv/bin/python benchmarks/ecm.py [--frames 300] [--only lowerbody-2cam,...] [--seeds 0,1,2,3,4]
        [--option NAME=VALUE] [--restart -60]
"""

from __future__ import annotations

import argparse
import ast
import copy
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from kms2pin.ecm.camera import Camera  # noqa: E402
from kms2pin.ecm.evaluate import evaluate  # noqa: E402
from kms2pin.ecm.motions import make_motion  # noqa: E402
from kms2pin.ecm.options import OPTION_GROUP  # noqa: E402
from kms2pin.ecm.synth import synthesize  # noqa: E402
from kms2pin.ecm.tracker import Tracker, Trajectory  # noqa: E402
from kms2pin.robot import load  # noqa: E402

SPECS = Path(__file__).resolve().parents[1] / "specs"


def cameras(robot, n, level=False, scale=1.0):
    """Front camera (the default, at the model's mid height) plus, for n > 1, cameras
    raised above the model: right side (20 deg down), left-front oblique, behind-above.
    ``n``: how many of these, in this order, or a tuple of their indices (0 the front).

    ``level=True`` gives the old rig whose side camera is level with the front one:
    two level, orthogonal views share a mirror ambiguity (a turn of the trunk by +a
    or -a, legs swapped, looks alike in both), and near a turn the tracker can take
    the mirrored branch and follow it.  Raising one camera breaks the symmetry.

    ``scale``: the rig shrunk about the model for a smaller model (the human, 1.75 m, is
    0.45 of the thesis's full body and stands half as far from the front camera).
    """
    # the free root's rest position; with the spec's root, the mean of the body centres
    c = robot.q_rest[:3] if robot.root == "free" else np.mean([P.translation for P in robot.body_poses(robot.q_rest)], 0)
    if level:
        cams = [
            Camera.default(),
            Camera.look_at(position=[8, 0, 8], target=c),
            Camera.look_at(position=[-8, 2, 8], target=c),
            Camera.look_at(position=[0, 6, 16], target=c),
        ]
    else:
        cams = [
            Camera.default(),
            Camera.look_at(position=[8, 3, 8], target=c),
            Camera.look_at(position=[-6, 3, 2], target=c),
            Camera.look_at(position=[0, 6, 16], target=c),
        ]
    if scale != 1.0:  # the raised cameras' offsets from the model, scaled
        base = np.array([0.0, 0.0, 8.0])
        cams = cams[:1] + [Camera.look_at(position=c + scale * (cam.centre - base), target=c) for cam in cams[1:]]
    return [cams[i] for i in n] if isinstance(n, tuple) else cams[:n]


CASES = {
    "lowerbody-2cam": ("lowerbody", "walk", 2),
    "lowerbody-1cam": ("lowerbody", "walk", 1),
    "fullbody-2cam": ("fullbody", "walk", 2),
    "fullbody-1cam": ("fullbody", "walk", 1),
    "fullbody-4cam": ("fullbody", "walk", 4),
    "jplhand-2cam": ("jplhand", "random", 2),
    "jplhand-1cam": ("jplhand", "random", 1),
    # the hand with other rigs: the front camera and the one behind and above (which sees
    # the thumb where the right side camera, with the front one, can miss its lower joint),
    # three and four cameras
    "jplhand-2cam-above": ("jplhand", "random", (0, 3)),
    "jplhand-3cam": ("jplhand", "random", 3),
    "jplhand-4cam": ("jplhand", "random", 4),
    # the same models with anatomical joint limits (specs/anatomical)
    "lowerbody-limits-1cam": ("anatomical/lowerbody", "walk", 1),
    "lowerbody-limits-2cam": ("anatomical/lowerbody", "walk", 2),
    "fullbody-limits-1cam": ("anatomical/fullbody", "walk", 1),
    "fullbody-limits-2cam": ("anatomical/fullbody", "walk", 2),
    # one camera, with limits and the upright prior (Tracker(upright=...)): the walkers'
    # pelvis keeps its starting tilt, and turns happen about the vertical
    "lowerbody-upright-1cam": ("anatomical/lowerbody", "walk", 1, {"upright": 0.1}),
    "fullbody-upright-1cam": ("anatomical/fullbody", "walk", 1, {"upright": 0.1}),
    # and the rest prior (Tracker(rest_prior=...)): the joints the one view does not fix,
    # such as a hidden arm's, are held near the rest pose
    "lowerbody-prior-1cam": ("anatomical/lowerbody", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    "fullbody-prior-1cam": ("anatomical/fullbody", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    # the thesis's models as printed (no joint limits) with both priors
    "lowerbody-thesis-prior-1cam": ("lowerbody", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    "fullbody-thesis-prior-1cam": ("fullbody", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    # ours: a 1.75 m adult with spherical hips, shoulders, waist and neck (specs/human.kms),
    # walking with its hips and shoulders also swaying out of the sagittal plane; the rig
    # scaled to its size (cameras())
    "human-2cam": ("human", "walk", 2),
    "human-4cam": ("human", "walk", 4),
    "human-1cam": ("human", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    "human-random-2cam": ("human", "random", 2),
    "human-1cam-320": ("human", "walk", 1, {"upright": 0.1, "rest_prior": 0.01}),
    # a closed chain (issue 33): the Delta robot on its base, its five loops held on every frame
    "delta-2cam": ("delta", "random", 2, {"root": "spec"}),
}

#: the rig's scale per spec (cameras()): the thesis's models' heights are about 3.9 units
RIG_SCALE = {"human": 0.45}
#: the image size per spec, a multiple of 320x240: the human's arms, thin beside the
#: thesis's chunky ellipsoids, are 3-4 pixels wide at 320x240, where 5 % noise on the
#: boundary pixels lost two seeds of three with two cameras (docs/benchmarks.md)
RESOLUTION = {"human": 2, "human-1cam-320": 1}  # by spec, or by case


def upscaled(camera, f):
    """``camera`` with ``f`` times the pixels a side (the same view; pixel centres kept)."""
    if f == 1:
        return camera
    K = camera.K.copy()
    K[:2, 2] = (K[:2, 2] + 0.5) * f - 0.5
    K[0, 0] *= f
    K[1, 1] *= f
    return Camera(K, camera.world_T_camera, camera.width * f, camera.height * f, dist=camera.dist)

_WIDTH = max(map(len, CASES)) + len(" seed 10")  # the name column: every case's rows in line


def run_case(name, frames, noise, mismatch, level=False, seed=0, restart=None, **tracker_kw):
    """Track one case; print its row and return (centre error %, revolute RMSE deg, frames/s,
    last 30 / first 30, the same across one camera's rays, the last 30 frames restarted
    from the truth / as tracked).

    ``restart`` (a frame; negative: from the end): a copy of the tracker also goes on from
    the true pose at that frame (:meth:`Tracker.restart`, the measured sizes kept), and the
    row adds its last 30 frames' error beside the track's.  The same error again means the
    track's last 30 frames owe it to those frames, not to what went before: no drift."""
    spec, motion_name, ncam, *case_kw = CASES[name]
    tracker_kw = {**(case_kw[0] if case_kw else {}), **tracker_kw}
    robot = load(SPECS / f"{spec}.kms", root=tracker_kw.pop("root", "free"))
    rng = np.random.default_rng(seed)
    motion = make_motion(robot, motion_name, frames, rng)
    f = RESOLUTION.get(name, RESOLUTION.get(spec, 1))
    cams = [upscaled(c, f) for c in cameras(robot, ncam, level, RIG_SCALE.get(spec, 1.0))]
    data = [m for _, m in synthesize(robot, motion, cams, noise=noise, size_mismatch=mismatch, rng=rng)]
    tr = Tracker(robot, cams, **tracker_kw)
    k0 = None if restart is None else (restart if restart >= 0 else frames + restart)
    res, fresh, copying = [], None, 0.0
    t0 = time.perf_counter()
    for k, m in enumerate(data):
        if k == k0:  # the copy is not tracking: its time is left out of the frames/s
            t_copy = time.perf_counter()
            fresh = copy.deepcopy(tr)
            fresh.restart(motion[k])
            copying = time.perf_counter() - t_copy
        res.append(tr.step(m, source=f"frame {k}"))
    wall = time.perf_counter() - t0 - copying
    # one camera: the error split along and across its viewing rays (depth, and what it sees)
    centre = cams[0].centre if len(cams) == 1 else None
    rep = evaluate(robot, Trajectory(robot, np.array([r.q for r in res]), res), Trajectory(robot, motion), centre)
    split = {k: sum(r.timings[k] for r in res) for k in ("e_step", "m_step", "static_update", "sizes")}
    iters = np.mean([r.iterations for r in res])
    # the last 30 frames' fit (IoU) of the tracked poses and of the true ones, both at the
    # tracker's final body sizes: a track that fits as well as the truth while off it
    # follows what the silhouettes cannot tell apart
    last = range(max(0, frames - 30), frames)
    fit_tracked = np.mean([tr.fit(res[k].q, data[k]) for k in last])
    fit_truth = np.mean([tr.fit(motion[k], data[k]) for k in last])
    again = ""
    restarted = np.nan
    if fresh is not None:
        q2 = np.array([fresh.step(m, source=f"frame {k}").q for k, m in enumerate(data[k0:], k0)])
        tail = evaluate(robot, Trajectory(robot, q2), Trajectory(robot, motion[k0:]))["per_frame_centre_error_pct"]
        last_tracked = np.mean(rep["per_frame_centre_error_pct"][-30:])
        restarted = np.mean(tail[-30:]) / last_tracked
        again = (f" | from the truth at frame {k0}: last 30 {np.mean(tail[-30:]):.3f} % against "
                 f"{last_tracked:.3f} % ({restarted:.2f}x)")
    rig = "level" if level and len(cams) > 1 else "raised"
    tag = f" seed {seed}" if seed else ""
    if robot.closures:  # every frame's loops closed
        worst = max(float(robot.closure_residual(r.q).max()) for r in res)
        again += f" | loops closed on every frame: largest residual {worst:.1e}"
    print(
        f"{name + tag:{_WIDTH}s} {rig:6s} {frames:4d} fr | centre err {rep['mean_centre_error_pct']:.3f} % | rev RMSE "
        f"{rep['revolute_rmse_deg']:.2f} deg | worst {rep['worst_frame_error_pct']:.3f} % (frame "
        f"{rep['worst_frame']}) | last/first {rep['first_vs_last_ratio']:.2f} | {frames / wall:.1f} fr/s, "
        f"{iters:.1f} it/fr | E {split['e_step'] / wall:.0%} M {split['m_step'] / wall:.0%} "
        f"S {split['static_update'] / wall:.0%} sizes {split['sizes'] / wall:.0%} | last 30 fit {fit_tracked:.3f}, "
        f"true poses' {fit_truth:.3f}"
        + (f" | along the rays {rep['depth_error_pct']:.2f} %, across {rep['centre_error_across_rays_pct']:.2f} % "
           f"(last/first {rep['first_vs_last_ratio_across_rays']:.2f})" if centre is not None else "")
        + again,
        flush=True,
    )
    return (rep["mean_centre_error_pct"], rep["revolute_rmse_deg"], frames / wall, rep["first_vs_last_ratio"],
            rep.get("first_vs_last_ratio_across_rays", np.nan), restarted)


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--noise", type=float, default=0.05)
    p.add_argument("--size-mismatch", type=float, default=0.10)
    p.add_argument("--only", help="comma-separated cases: " + ", ".join(CASES))
    p.add_argument("--level", action="store_true", help="the old rig: side camera level with the front one")
    p.add_argument(
        "--option", action="append", default=[], metavar="NAME=VALUE",
        help="a Tracker option for every case, e.g. mirror_hypothesis=False (repeatable)",
    )
    p.add_argument(
        "--restart", type=int, metavar="FRAME",
        help="also track from the true pose at FRAME (negative: from the end, e.g. -60) and print the last 30 "
        "frames' error of that track beside the track's: the same error means no drift",
    )
    p.add_argument(
        "--seeds", default="0",
        help="comma-separated noise seeds (default 0); with several, a median row per case follows",
    )
    a = p.parse_args()
    options = {}
    for item in a.option:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            p.error(f"--option wants NAME=VALUE, not {item!r}")
        try:
            options[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):  # a bare word: a string (prediction=previous)
            options[key.strip()] = value.strip()
    unknown = [k for k in options if k not in OPTION_GROUP]
    if unknown:
        p.error(f"--option: Tracker has no option {', '.join(unknown)}")
    if a.only:
        bad = [n for n in a.only.split(",") if n not in CASES]
        if bad:
            p.error(f"--only: no case {', '.join(bad)}; the cases are {', '.join(CASES)}")
    seeds = [int(x) for x in a.seeds.split(",")]
    if a.restart is not None and not 0 < (a.restart if a.restart >= 0 else a.frames + a.restart) <= a.frames - 30:
        p.error(f"--restart: frame {a.restart} leaves fewer than the last 30 of the {a.frames} frames after it")
    for name in a.only.split(",") if a.only else CASES:
        rows = [
            run_case(name, a.frames, a.noise, a.size_mismatch, a.level, seed, a.restart, **options) for seed in seeds
        ]
        if len(rows) > 1:
            err, rmse, fps, drift, drift_across, restarted = np.array(rows).T
            print(
                f"{name:{_WIDTH}s} median of {len(rows)} seeds | centre err {np.median(err):.3f} % (max {err.max():.3f}) | "
                f"rev RMSE {np.median(rmse):.2f} deg (max {rmse.max():.2f}) | last/first at most 1.5 on "
                f"{int(np.sum(drift <= 1.5))} of {len(rows)} (max {drift.max():.2f}"
                + (f"; across the rays on {int(np.sum(drift_across <= 1.5))})"
                   if np.isfinite(drift_across).all() else ")")
                + f" | {np.median(fps):.1f} fr/s"
                + (f" | last 30 from the truth at the restart {np.median(restarted):.2f}x the track's "
                   f"({np.min(restarted):.2f}-{np.max(restarted):.2f})" if a.restart is not None else ""),
                flush=True,
            )


if __name__ == "__main__":
    main()
