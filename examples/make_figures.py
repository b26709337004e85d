"""Render the thesis-style figures of the sample models into docs/figures/.

For each spec: the rest pose and one posed configuration, from the front and
from the side (like thesis figures 3.1, 4.3, 4.6, 4.10, 4.11), a 2 x 2 overview
(columns rest / posed, rows front / side), and one static update (like figures
4.1, 4.4, 4.8, 4.12: primary bodies before and after, lighter intermediate
bodies, red spring arrows) if ``kms2pin.static_update`` is available.

    .venv/bin/python examples/make_figures.py [--out docs/figures] [--only puma600 ...]

Needs Chromium (headless) for the PNGs; no meshcat server is started.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import kms2pin
from kms2pin.viewer import RobotView, draw_static_update, parse_pose, read_png, render

ROOT = Path(__file__).resolve().parents[1]
SPECS = ("puma600", "lowerbody", "fullbody", "jplhand", "human", "gantry", "fourbar", "delta", "stewart")
POSES = {
    # thesis fig. 3.1: a second arm position
    "puma600": "base_inertialAnchor=-20 link1_lowerLink=140 link2_lowerLink=45 link3_lowerLink=-70",
    # fig. 4.3: taking a step (hip < 80 swings a thigh forward, a larger knee angle bends the knee)
    "lowerbody": "leftThigh_hip=50 leftShin_knee=35 leftFoot_ankle=75 "
                 "rightThigh_hip=100 rightShin_knee=45 rightFoot_ankle=70",
    # fig. 4.6: midstride, each arm swinging with the opposite leg (shoulder < 90: arm forward)
    "fullbody": "leftThigh_hip=45 leftShin_knee=40 leftFoot_ankle=75 "
                "rightThigh_hip=105 rightShin_knee=60 rightFoot_ankle=70 "
                "leftUpperArm_shoulder=125 leftForeArm_elbow=75 rightUpperArm_shoulder=55 rightForeArm_elbow=85",
    # fig. 4.10: a grasping posture
    "jplhand": "lowFinger1_lowerJoint=90 midFinger1_lowerJoint=60 tip1_joint=60 "
               "lowFinger2_lowerJoint=90 midFinger2_lowerJoint=60 tip2_joint=60 "
               "lowThumb_lowerJoint=90 midThumb_lowerJoint=60 thumbTip_joint=60",
    # ours: out of the sagittal plane (a spherical joint's X-Y-Z angles: x forwards, y about the
    # bone, z towards the subject's right): the right arm raised sideways, the left one
    # forwards, a step with the left leg, the right leg out to the side, trunk and head turned
    "human": "rightUpperArm_shoulder_z=75 rightForeArm_elbow=20 leftUpperArm_shoulder_x=55 "
             "leftForeArm_elbow=70 leftThigh_hip_x=45 leftShin_knee=55 leftFoot_ankle=15 "
             "rightThigh_hip_z=20 torso_waist_y=20 torso_waist_x=8 head_neck_y=-30",
    # ours: every slide moved, the tool turned
    "gantry": "bridge_shoe=0.5 carriage_shoe=-0.3 quill_top=0.5 tool_wrist=60",
    # ours, with kinematic loops (the closing joints follow the joints set): the crank turned on
    "fourbar": "crankLink_base=160",
    # the three arms at different angles: the platform moves off centre, still level
    "delta": "arm0_shoulder=10 arm1_shoulder=50 arm2_shoulder=35",
    # the legs on one side lengthened, on the other shortened: the platform tilts by 22 deg
    "stewart": "pis0_foot=0.25 pis1_foot=0.25 pis2_foot=0.2 pis3_foot=0.12 pis4_foot=0.12 pis5_foot=0.2",
}
# static update: from rest towards the posed configuration, M-step targets perturbed
STATIC_UPDATE_NOISE = {"angle_deg": 12.0, "fraction": 0.06}
# the static-update motion is mostly in the y-z plane (legs, arms, planar PUMA links): look from the side
STATIC_UPDATE_CAMERA = {"puma600": "side", "lowerbody": "side", "fullbody": "side", "jplhand": "iso",
                        "human": "iso", "gantry": "iso", "fourbar": "front", "delta": "iso", "stewart": "iso"}


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = img.copy()
    cv2.putText(out, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (60, 60, 60), 1, cv2.LINE_AA)
    return out


def _caption_halves(png: Path, left: str, right: str) -> None:
    import cv2

    img = read_png(png)
    half = img.shape[1] // 2
    img = np.hstack([_label(img[:, :half], left), _label(img[:, half:], right)])
    cv2.imwrite(str(png), img[:, :, ::-1])


def _grid(paths: list[list[Path]], labels: list[list[str]], out: Path) -> None:
    import cv2

    rows = [np.hstack([_label(read_png(p), t) for p, t in zip(row, lab)]) for row, lab in zip(paths, labels)]
    cv2.imwrite(str(out), np.vstack(rows)[:, :, ::-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    ap.add_argument("--only", nargs="+", choices=SPECS, default=list(SPECS))
    ap.add_argument("--size", default="420x560", help="WIDTHxHEIGHT of each view (default 420x560)")
    ap.add_argument("--jobs", type=int, default=2, help="Chromium processes at a time")
    args = ap.parse_args(argv)
    if render.find_chromium() is None:
        print("make_figures: no Chromium found; cannot render PNGs", file=sys.stderr)
        return 1
    w, h = (int(x) for x in args.size.lower().split("x"))
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        from kms2pin import static_update, virtual_work
    except ImportError:
        static_update = virtual_work = None
        print("note: kms2pin.static_update is not available; skipping the static-update pictures")

    jobs: list[tuple[str, Path, int, int]] = []  # (html, png, width, height)
    grids = []
    labelled = []  # static-update pictures: a caption over each half
    for name in args.only:
        robot = kms2pin.load(ROOT / "specs" / f"{name}.kms")
        posed = parse_pose(robot, POSES[name])
        cells = []
        for view in ("front", "side"):
            row = []
            for tag, q in (("rest", robot.q_rest), ("posed", posed)):
                png = args.out / f"{name}_{tag}_{view}.png"
                with RobotView(robot, q, camera=view, aspect=w / h) as v:
                    jobs.append((v.static_html(), png, w, h))
                row.append(png)
            cells.append(row)
        grids.append((cells, [[f"{name}: rest, front", "posed, front"], ["rest, side", "posed, side"]],
                      args.out / f"{name}_views.png"))
        if static_update is not None:
            rng = np.random.default_rng(1999)
            targets = virtual_work.perturbed_targets(robot, posed, rng, **STATIC_UPDATE_NOISE)
            t0 = time.perf_counter()
            result = static_update(robot, robot.q_rest, targets, 1.0)
            print(f"{name}: static update {result.iterations} iterations, converged={result.converged}, "
                  f"energy {result.energy:.3g} ({time.perf_counter() - t0:.2f} s)")
            d = draw_static_update(robot, robot.q_rest, targets, result, camera=STATIC_UPDATE_CAMERA[name],
                                   aspect=2 * w / h)
            png = args.out / f"{name}_static_update.png"
            jobs.append((d.vis.static_html(), png, 2 * w, h))
            labelled.append((png, [f"{name}: before the static update", "after"]))

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        for png in pool.map(lambda j: render.render_png(j[0], j[1], j[2], j[3]), jobs):
            print(f"wrote {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")
    for cells, labels, out in grids:
        _grid(cells, labels, out)
        print(f"wrote {out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}")
    for png, (left, right) in labelled:
        _caption_halves(png, left, right)
    print(f"{len(jobs)} pictures in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
