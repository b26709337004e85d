"""Render synthetic silhouette masks of a model moving (exact ray casting of the inner
ellipsoids, or of capsules in their place), with optional noise and body-size mismatch,
for `kms2pin track`.

Writes DIR/camK/frame_NNNNN.png (one folder per camera), DIR/cameras.json,
DIR/truth.csv and DIR/truth.npz.  --motion is a named motion (walk, sweep, random) or a
trajectory CSV of the model (the format track writes and truth.csv has; joint angles in
degrees, a free root as root_x ... root_qw), rendered frame by frame.  --shape capsule
renders each body as a capsule along its inner ellipsoid's longest semi-axis a, end to
end 2a, its radius the mean of the other two semi-axes.  --noise LEVEL (e.g. 0.05 = "5 % noise") drives
ragged boundaries (edge pixels flipped with probability 4 LEVEL), holes
(100 LEVEL discs), false blobs (40 LEVEL discs) and salt-and-pepper (LEVEL/10).
--size-mismatch FRAC renders each body's semi-axes scaled by a random factor in
[1-FRAC, 1+FRAC] (per body and axis).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..ecm.camera import Camera
from ..ecm.motions import MOTIONS, make_motion
from ..ecm.synth import SHAPES, synthesize
from ..ecm.tracker import Trajectory
from ..errors import InputDataError, Kms2pinError, UsageError
from ..robot import Robot
from ..video.io import MASK_NAME, remove_masks_from, write_png_atomically
from ._common import add_spec_argument, count, existing_file, number, read_model
from ._outputs import owns_output, replaced

NAME = "synth"
HELP = "render synthetic silhouette masks of a moving model (for track / evaluate)"

#: the most frames synth renders (an hour at 30 frames/s is 108,000): a mistyped count is refused, not
#: allocated
MAX_SYNTH_FRAMES = 1_000_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_spec_argument(p)
    p.add_argument("--motion", default="walk", metavar="NAME|FILE.csv",
                   help=f"{', '.join(MOTIONS)} (default: walk), or a trajectory CSV of the model "
                   "(as track writes it, or synth's truth.csv)")
    p.add_argument("--frames", type=number(1, MAX_SYNTH_FRAMES, whole=True), metavar="N",
                   help="number of frames (default: 60; with a CSV motion, all its frames; N takes the first N; "
                        f"at most {MAX_SYNTH_FRAMES:,})")
    p.add_argument("--shape", choices=SHAPES, default="ellipsoid",
                   help="render the inner ellipsoids (default), or capsules in their place: along the longest "
                   "semi-axis a, end to end 2a, radius the mean of the other two")
    p.add_argument("--cameras", metavar="CAMS.json", help="camera list (default: one Camera.default())")
    p.add_argument("--root", choices=("spec", "free"), default="free", help="root joint (default: free)")
    p.add_argument("--noise", type=number(0.0, 1.0), default=0.0, metavar="LEVEL", help="noise level, e.g. 0.05 (default 0)")
    p.add_argument("--size-mismatch", type=number(0.0, 1.0, hi_open=True), default=0.0, metavar="FRAC",
                   help="render body sizes off by up to FRAC (e.g. 0.1)")
    p.add_argument("--system", help="rigidBodySystem to use (if the spec has several)")
    p.add_argument("--seed", type=count, default=0, help="random seed (default: 0)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")


@owns_output
def run(args: argparse.Namespace) -> int:
    spec = read_model(args.spec)
    robot = Robot(spec, spec.system(args.system), args.root)
    if args.cameras:
        existing_file(args.cameras)  # a usage error, as for the spec
    cameras = Camera.list_from_json(args.cameras) if args.cameras else [Camera.default()]
    rng = np.random.default_rng(args.seed)
    motion = _motion(robot, args, rng)
    out = Path(args.output)
    dirs = [out / f"cam{c}" for c in range(len(cameras))]
    try:
        for d in dirs:
            d.mkdir(parents=True, exist_ok=True)
        truth = Trajectory(robot, motion)
        for name, write in (("cameras.json", lambda p: Camera.list_to_json(cameras, p)), ("truth.csv", truth.to_csv),
                            ("truth.npz", truth.to_npz)):
            with replaced(out / name) as tmp:
                write(tmp)
        for f, masks in synthesize(robot, motion, cameras, noise=args.noise, size_mismatch=args.size_mismatch,
                                   rng=rng, shape=args.shape):
            for d, m in zip(dirs, masks):
                write_png_atomically(d / MASK_NAME.format(f), m.astype(np.uint8) * 255)
        stale = sum(remove_masks_from(d, len(motion)) for d in dirs)
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None
    extra = f" (removed {stale} older mask(s) beyond the sequence)" if stale else ""
    shape = "" if args.shape == "ellipsoid" else f" ({args.shape}s)"
    print(f"{out}: {len(motion)} frames x {len(cameras)} camera(s){shape}{extra}")
    return 0


def _motion(robot: Robot, args: argparse.Namespace, rng: np.random.Generator) -> np.ndarray:
    """The configurations (frames, nq) to render: a named motion, or a trajectory CSV's
    (its first ``--frames``)."""
    if args.motion in MOTIONS:
        return make_motion(robot, args.motion, args.frames or 60, rng)
    if not Path(args.motion).exists():
        raise UsageError(f"--motion: '{args.motion}' is neither a motion ({', '.join(MOTIONS)}) nor a file")
    if Path(args.motion).is_dir():
        raise UsageError(f"--motion: {args.motion}: is a directory, not a trajectory CSV file")
    q = Trajectory.from_csv(robot, args.motion).q
    if not len(q):
        raise InputDataError(f"{args.motion}: the trajectory has no frames")
    if args.frames is not None and args.frames > len(q):
        raise UsageError(f"--frames {args.frames}: {args.motion} has {len(q)} frames")
    return q[: args.frames]
