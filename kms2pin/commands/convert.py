"""Convert a trajectory CSV of a model (track's trajectory.csv, synth's truth.csv, import's
motion.csv) to BVH: one BVH joint per body at its joint point, the rest pose as the
skeleton's offsets, three rotation channels per joint (Zrotation Xrotation Yrotation:
R = Rz Rx Ry, degrees) and three position channels more on the root; lengths in the spec's
units, +y up.  A model with several joints to the inertial frame or a prismatic joint below
the root cannot be written.  docs/bvh.md.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..bvh import to_bvh
from ..ecm.trajectory import Trajectory
from ..errors import InputDataError, Kms2pinError, UsageError
from ..robot import Robot
from ._common import existing_file, positive, read_model
from ._outputs import replaced

NAME = "convert"
HELP = "write a trajectory CSV of a model as BVH (one joint per body)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("trajectory", metavar="TRAJECTORY.csv", help="trajectory CSV of the model (as track writes it)")
    p.add_argument("--model", required=True, metavar="MODEL.kms", help="the model the trajectory is of")
    p.add_argument("-o", "--output", required=True, metavar="OUT.bvh", help="BVH file to write")
    p.add_argument("--root", choices=("spec", "free"), default="free",
                   help="the trajectory's root joint (default: free, as track and synth write it)")
    p.add_argument("--fps", type=positive, default=30.0, help="frames per second of the trajectory (default 30)")
    p.add_argument("--system", help="rigidBodySystem to use (if the spec has several)")


def run(args: argparse.Namespace) -> int:
    if not args.output.lower().endswith(".bvh"):
        raise UsageError(f"-o {args.output}: convert writes BVH; name a .bvh file")
    existing_file(args.trajectory)
    spec = read_model(args.model)
    robot = Robot(spec, spec.system(args.system), args.root)
    trajectory = Trajectory.from_csv(robot, args.trajectory)
    if not len(trajectory):
        raise InputDataError(f"{args.trajectory}: the trajectory has no frames")
    text = to_bvh(robot, trajectory.q, args.fps)
    out = Path(args.output)
    try:
        with replaced(out) as tmp:
            tmp.write_text(text)
    except OSError as err:
        raise Kms2pinError(f"cannot write {out}: {err.strerror or err}") from None
    print(os.fspath(out))
    print(f"{args.trajectory}: {len(trajectory)} frames of '{robot.system.name}' ({len(robot.bodies)} BVH joints) "
          f"at {args.fps:g} fps")
    return 0
