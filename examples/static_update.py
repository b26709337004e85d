"""A static update like the thesis's figures 4.1, 4.2, 4.4, 4.5, 4.8, 4.9 and 4.12.

A primary pose, noisy intermediate (M-step) bodies, the update, and the poses
before and after, printed; with --html / --png the viewer draws them (primary
bodies before and after, lighter intermediate bodies, red linear springs).

    python examples/static_update.py specs/fullbody.kms --html out/su.html --png out/su.png
"""

from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin

import kms2pin
from kms2pin.virtual_work import perturbed_targets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", help="a .kms spec")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--step-deg", type=float, default=25.0, help="how far the intermediate bodies move the joints")
    ap.add_argument("--noise-deg", type=float, default=15.0, help="orientation noise of the intermediate bodies")
    ap.add_argument("--noise-frac", type=float, default=0.1, help="position noise, fraction of each body's length")
    ap.add_argument("--html", help="write the picture as standalone HTML")
    ap.add_argument("--png", help="write the picture as PNG (headless Chromium)")
    ap.add_argument("--camera", default="side", choices=("front", "side", "top", "iso"))
    args = ap.parse_args(argv)

    robot = kms2pin.load(args.model)
    rng = np.random.default_rng(args.seed)
    q_before = robot.q_rest.copy()
    # the M-step saw the body move on (a step like the thesis's "rest to intermediate
    # position"), with noise and offsets no valid pose can match
    q_moved = pin.integrate(robot.model, q_before, np.radians(rng.uniform(-args.step_deg, args.step_deg, robot.nv)))
    targets = perturbed_targets(robot, q_moved, rng, args.noise_deg, args.noise_frac)
    result = kms2pin.static_update(robot, q_before, targets)

    print(f"{robot.system.name}: {len(robot.bodies)} bodies, {robot.nv} joint coordinates")
    print(f"static update: converged={result.converged} after {result.iterations} iterations, "
          f"||B^T Q|| = {result.residual:.2e}, spring energy {result.energy:.4f}")
    print(f"{'joint':28s} {'before':>9s} {'M-step':>9s} {'after':>9s}  (degrees)")
    for name, a, b, c in zip(robot.joint_names, q_before, q_moved, result.q):
        print(f"{name:28s} {np.degrees(a):9.2f} {np.degrees(b):9.2f} {np.degrees(c):9.2f}")
    before = robot.maximal_coordinates(q_before)
    after = robot.maximal_coordinates(result.q)
    print(f"{'body':14s} {'|spring| before':>16s} {'|spring| after':>15s}  (linear spring length)")
    for i, name in enumerate(robot.bodies):
        print(f"{name:14s} {np.linalg.norm(targets[i, :3] - before[i, :3]):16.4f} "
              f"{np.linalg.norm(targets[i, :3] - after[i, :3]):15.4f}")
    if args.html or args.png:
        from kms2pin import viewer

        vis = viewer.show_static_update(robot, q_before, targets, result, camera=args.camera)
        if args.html:
            print(viewer.save_html(vis, args.html))
        if args.png:
            print(viewer.save_png(vis, args.png, width=1200, height=600))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
