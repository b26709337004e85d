"""Import a BVH motion-capture file: DIR/<name>.kms, a model of its skeleton (one ellipsoid
body per bone, sized from the bone lengths and an anthropometric table; spherical joints,
or revolute ones with --hinge; a free root; the file's offsets as the rest pose), and
DIR/motion.csv, its motion as that model's trajectory (the CSV that track writes; a free
root).  Lengths become metres with --scale (metres per file unit); a Z-up file is turned
to the model's +y up.  Every joint's channel order, six-channel roots and End Sites are
read as the file gives them; a file with several roots, a truncated motion, a wrong number
of values or a value that is not a number is refused with its file:line:col.  docs/bvh.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ..bvh import ImportOptions, import_bvh, read_bvh
from ..bvh.builder import identifier
from ..bvh.motion import UPS
from ..ecm.trajectory import Trajectory
from ..errors import Kms2pinError
from ._common import existing_file, positive
from ._outputs import owns_output, replaced

NAME = "import"
HELP = "model a BVH file's skeleton and motion: DIR/<name>.kms and DIR/motion.csv"
#: a human skeleton's height (m) outside this range at the default --scale suggests another unit
PLAUSIBLE_HEIGHT = (0.3, 3.0)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bvh", metavar="FILE.bvh", help="BVH motion-capture file")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    p.add_argument("--scale", type=positive, metavar="S",
                   help="metres per file unit (default 1; 0.01 for centimetres, 0.0254 for inches)")
    p.add_argument("--fps", type=positive, metavar="F",
                   help="resample the motion at F frames per second (default: the file's frame rate)")
    p.add_argument("--hinge", metavar="NAME,...",
                   help="BVH joints to model as revolute joints, about the axis each mostly turns about in the "
                   "motion (knees, elbows)")
    p.add_argument("--up", choices=UPS, default="auto",
                   help="the file's up axis (default auto: y or z, whichever the rest pose is taller along)")
    p.add_argument("--name", help="the model's name (default: the file's name)")


@owns_output
def run(args: argparse.Namespace) -> int:
    existing_file(args.bvh)
    bvh = read_bvh(args.bvh)
    name = identifier(args.name or Path(args.bvh).stem)
    hinges = tuple(h.strip() for h in (args.hinge or "").split(",") if h.strip())
    model = import_bvh(bvh, ImportOptions(args.scale or 1.0, args.up, args.fps, hinges, name))
    out = Path(args.output)
    try:
        with replaced(out / f"{name}.kms") as kms, replaced(out / "motion.csv") as csv:
            kms.write_text(model.text)
            Trajectory(model.robot, model.q).to_csv(csv)
    except OSError as err:
        raise Kms2pinError(f"cannot write to {out}: {err.strerror or err}") from None
    print(os.fspath(out / f"{name}.kms"))
    print(os.fspath(out / "motion.csv"))
    up, why = model.up
    merged = f"; zero-length bones merged: {', '.join(model.merged)}" if model.merged else ""
    skipped = f"; left out: {', '.join(model.skipped)}" if model.skipped else ""
    print(f"{args.bvh}: {len(bvh.joints)} joints -> {len(model.robot.bodies)} bodies{merged}{skipped}; "
          f"{len(model.q)} frames at {model.fps:g} fps; {up.upper()}-up ({why}); rest height {model.height:.3g} m")
    low, high = PLAUSIBLE_HEIGHT
    if args.scale is None and not low <= model.height <= high:
        print(f"note: at --scale 1 (metres per file unit) the skeleton's rest pose is {model.height:.3g} m tall; "
              "give the file's unit with --scale (0.01 for centimetres, 0.0254 for inches)", file=sys.stderr)
    return 0
