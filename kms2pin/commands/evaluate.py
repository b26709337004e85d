"""Compare a `kms2pin track` output folder with the true motion (e.g. truth.csv of
`kms2pin synth`): per-joint angle RMSE (degrees), mean body-centre error as a
percentage of the model height, and the worst frame."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..ecm.camera import Camera
from ..ecm.evaluate import evaluate
from ..ecm.tracker import Trajectory
from ..errors import InputDataError, UsageError
from ..jsonfile import read_json
from ..robot import Robot
from ._common import existing_file, read_model

NAME = "evaluate"
HELP = "accuracy of a track output against the true trajectory"


#: the flags that score another of track's outputs, and its file
_WRITTEN = (("smoothed", "smoothed.csv"), ("both_ways", "both_ways.csv"), ("beside", "beside.csv"),
            ("stretches", "stretches.csv"), ("temporal", "temporal.csv"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="OUT", help="folder written by kms2pin track")
    p.add_argument("truth", metavar="TRUTH.csv", help="true trajectory (truth.csv of kms2pin synth)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--smoothed", action="store_true",
                       help="score OUT/smoothed.csv (written by track --smooth) instead of OUT/trajectory.csv")
    which.add_argument("--both-ways", action="store_true",
                       help="score OUT/both_ways.csv (written by track --both-ways) instead of OUT/trajectory.csv")
    which.add_argument("--beside", action="store_true",
                       help="score OUT/beside.csv (written by track --beside) instead of OUT/trajectory.csv")
    which.add_argument("--stretches", action="store_true",
                       help="score OUT/stretches.csv (written by track --stretches) instead of OUT/trajectory.csv")
    which.add_argument("--temporal", action="store_true",
                       help="score OUT/temporal.csv (written by track --temporal) instead of OUT/trajectory.csv")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder (OUT is the folder written by kms2pin track)")
    if not out.is_dir():
        raise FileNotFoundError(2, "no such folder", str(out))
    for name in ("meta.json", "model.kms", "trajectory.csv"):
        if not (out / name).is_file():
            raise InputDataError(f"{out}: not a kms2pin track output (no {name})")
    chosen = [(f, csv) for f, csv in _WRITTEN if getattr(args, f)]
    flag, name = chosen[0] if chosen else ("", "trajectory.csv")
    track_csv = out / name
    if not track_csv.is_file():
        flag = "--smooth HZ" if flag == "smoothed" else "--" + flag.replace("_", "-")
        raise InputDataError(f"{out}: no {track_csv.name} (written by kms2pin track {flag})")
    if Path(args.truth).is_dir():
        raise UsageError(f"{args.truth}: is a directory, not a trajectory CSV file")
    existing_file(args.truth)
    meta_path = out / "meta.json"
    meta = read_json(meta_path, InputDataError)
    first = meta.get("first_frame", 0) if isinstance(meta, dict) else None
    if not isinstance(first, int) or isinstance(first, bool) or first < 0:
        raise InputDataError(f"{meta_path}: not the metadata of kms2pin track (expected an object "
                             "with a frame number 'first_frame')")
    if meta.get("complete") is False:  # interrupted, or stopped by bad input
        print(f"kms2pin evaluate: warning: {out}: the track stopped before its last frame "
              f"({meta_path}: complete false)", file=sys.stderr)
    spec = read_model(str(out / "model.kms"))
    robot = Robot(spec, spec.system(meta.get("system")), meta.get("root", "free"))
    tracked = Trajectory.from_csv(robot, track_csv)
    truth = Trajectory.from_csv(robot, args.truth)
    for path, traj in ((track_csv, tracked), (args.truth, truth)):
        if len(traj) == 0:
            raise InputDataError(f"{path}: no frames to evaluate (only a header)")
    if first >= len(truth):
        raise InputDataError(f"{args.truth}: {len(truth)} frames, but the track starts at frame {first} "
                             f"({meta_path}: first_frame)")
    truth = Trajectory(robot, truth.q[first:])
    # one camera: the error split along and across its viewing rays (depth, and what it sees)
    cameras = Camera.list_from_json(out / "cameras.json") if (out / "cameras.json").is_file() else []
    rep = evaluate(robot, tracked, truth, cameras[0].centre if len(cameras) == 1 else None)
    if rep["tracked_frames"] != rep["truth_frames"]:
        since = f" from frame {first}" if first else ""
        print(f"kms2pin evaluate: warning: {out} has {rep['tracked_frames']} frames, {args.truth} "
              f"{rep['truth_frames']}{since}: evaluating the first {rep['frames']}", file=sys.stderr)
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    print(f"{rep['frames']} frames; model height {robot.height:.4g}")
    for name, v in rep["joint_rmse_deg"].items():
        print(f"  {name:30s} {v:8.2f} deg RMSE")
    for name, v in rep["prismatic_rmse"].items():
        print(f"  {name:30s} {v:8.4g} RMSE (spec length units)")
    print(f"revolute RMSE: {rep['revolute_rmse_deg']:.2f} deg")
    if any(j.kind == "spherical" for j in robot.joints):
        print(f"spherical RMSE: {rep['spherical_rmse_deg']:.2f} deg (the angle between the rotations)")
    print(f"mean body-centre error: {rep['mean_centre_error_pct']:.3f} % of height")
    print(f"worst frame: {rep['worst_frame']} ({rep['worst_frame_error_pct']:.3f} %)")
    print(f"last-30 / first-30 error ratio: {rep['first_vs_last_ratio']:.2f}")
    if "depth_error_pct" in rep:
        print(f"one camera: along its viewing rays (depth) {rep['depth_error_pct']:.3f} % of height; across "
              f"them {rep['centre_error_across_rays_pct']:.3f} %, last-30 / first-30 "
              f"{rep['first_vs_last_ratio_across_rays']:.2f}")
    return 0
