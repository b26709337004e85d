"""Make a camera file for `kms2pin synth --cameras` / `kms2pin track --camera`.

`kms2pin camera make` builds a pinhole camera from the image size and the vertical
field of view, placed at --position and looking at --look-at (default: the thesis
scene, at the world origin looking along +z with +y up - Camera.default's pose).

`kms2pin camera calibrate` estimates the intrinsics and lens distortion from
photographs of a planar chessboard (OpenCV findChessboardCorners + cornerSubPix,
calibrateCamera) and prints the RMS reprojection error.  A calibration does not
know the world frame: the camera frame is the world frame (identity
world_T_camera) unless --position/--look-at are given.  The distortion
coefficients go into the camera's "dist"; kms2pin applies them in projection and
ray casting, so masks segmented from the raw (distorted) video need no undistorting.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from ..errors import CameraError, UsageError
from ..userfile import MAX_IMAGE_SIDE
from ..video.calibration import DISTORTION_MODELS, calibrate_chessboard, make_camera, with_pose
from ..video.io import list_images
from ._common import existing_file, number, positive, write_outputs

_side = number(1, MAX_IMAGE_SIDE, whole=True)
_coordinate = number()  # a finite number (world units)

NAME = "camera"
HELP = "make a camera file from a field of view, or calibrate one from chessboard photos"


def _add_pose(p: argparse.ArgumentParser, default_text: str) -> None:
    p.add_argument("--position", nargs=3, type=_coordinate, metavar=("X", "Y", "Z"),
                   help=f"camera centre in the world (default: {default_text})")
    p.add_argument("--look-at", nargs=3, type=_coordinate, metavar=("X", "Y", "Z"),
                   help="world point on the optical axis (default: position + (0, 0, 1), i.e. looking along +z)")
    p.add_argument("--up", nargs=3, type=_coordinate, default=(0.0, 1.0, 0.0), metavar=("X", "Y", "Z"),
                   help="world direction shown upwards in the image (default: 0 1 0)")
    p.add_argument("--name", default="", help="camera name stored in the file")
    p.add_argument("-o", "--output", required=True, metavar="CAM.json", help="camera file to write")


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="camera_command", metavar="ACTION", required=True)
    m = sub.add_parser("make", help="camera from image size + vertical field of view + pose",
                       description="Pinhole camera from the image size, vertical field of view and pose.")
    m.add_argument("--width", type=_side, required=True, help=f"image width in pixels (1-{MAX_IMAGE_SIDE})")
    m.add_argument("--height", type=_side, required=True, help=f"image height in pixels (1-{MAX_IMAGE_SIDE})")
    m.add_argument("--fov", type=number(0.0, 180.0, lo_open=True, hi_open=True), required=True, metavar="DEG",
                   help="vertical field of view (full image height) in degrees")
    _add_pose(m, "the world origin")
    c = sub.add_parser("calibrate", help="intrinsics + distortion from chessboard photos",
                       description="Chessboard calibration (OpenCV).  IMAGES are files or folders of images.")
    c.add_argument("images", nargs="+", metavar="IMAGE", help="chessboard photos (files or folders)")
    c.add_argument("--board", default="9x6", metavar="COLSxROWS",
                   help="inner corners per row x per column (default 9x6, a board of 10x7 squares)")
    c.add_argument("--square", type=positive, required=True, metavar="METRES", help="side of one square")
    c.add_argument("--distortion", choices=DISTORTION_MODELS, default="standard",
                   help="lens model: none, radial (k1 k2), standard (k1 k2 p1 p2; default), full (+ k3)")
    _add_pose(c, "identity pose: camera frame = world frame")


def _board(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not m:
        raise UsageError(f"--board: expected COLSxROWS inner corners such as 9x6, got '{text}'")
    return int(m.group(1)), int(m.group(2))


def _write(camera, out: str) -> None:
    path = Path(out)
    if path.is_dir():
        raise UsageError(f"-o {out}: a folder; give the camera file's name (such as {path / 'camera.json'})")
    write_outputs({path: json.dumps(camera.to_dict(), indent=2) + "\n"}, path.parent)


def run(args: argparse.Namespace) -> int:
    if args.camera_command == "make":
        try:
            cam = make_camera(args.width, args.height, args.fov, args.position, args.look_at, args.up, name=args.name)
        except CameraError as err:  # the flags' values make no camera: say so in their terms
            raise UsageError(f"camera make --width {args.width} --height {args.height} --fov {args.fov}: "
                             f"{err}") from None
        _write(cam, args.output)
        return 0
    files: list[str] = []
    for item in args.images:
        p = Path(item)
        if p.is_dir():
            found = list_images(p)
            if not found:
                raise CameraError(f"{p}: folder holds no images")
            files.extend(str(f) for f in found)
        else:
            files.append(str(existing_file(p)))
    result = calibrate_chessboard(files, _board(args.board), args.square, args.distortion, name=args.name)
    cam = result.camera
    posed = args.position is not None or args.look_at is not None
    if posed:
        cam = with_pose(cam, args.position, args.look_at, args.up)
    for f in result.rejected:
        print(f"kms2pin camera: warning: {f}: chessboard not found; skipped", file=sys.stderr)
    K = cam.K
    print(f"calibrated from {len(result.used)} of {len(result.used) + len(result.rejected)} images: "
          f"RMS reprojection error {result.rms:.3f} px")
    print(f"  fx {K[0, 0]:.2f}  fy {K[1, 1]:.2f}  cx {K[0, 2]:.2f}  cy {K[1, 2]:.2f}  "
          f"dist {[round(d, 5) for d in cam.dist] if cam.dist is not None else 'none'}")
    if not posed:
        print("  pose: identity world_T_camera (camera frame = world frame); use --position/--look-at to place it")
    _write(cam, args.output)
    return 0
