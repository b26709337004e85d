"""Figure-ground segmentation of a static-camera video (thesis §2.1.2) by adaptive
background subtraction: writes DIR/frame_NNNNN.png (0 background / 255 subject),
one per frame, ready for `kms2pin track --masks DIR`.

VIDEO is a video file (anything OpenCV/FFmpeg reads) or a folder of images
(natural name order, all of one size).  The background model is trained on
--learn-frames frames spread over the whole video (read twice; default) or on
the first ones (--learn-from start); either way every frame, the learning frames
included, gets a mask from the trained model.  Each frame is first divided by its
global per-channel gain against the background when it is more than 10 % off
(automatic exposure and white balance; --no-gain-compensation skips this).  Each mask is cleaned: shadows
dropped (pixels that look like a darker copy of the background; --no-shadows
keeps them, for a subject whose colours are a darker shade of the background's,
e.g. light grey clothes before a white wall); its rim refined on luminance
(lossy codecs blur colour about a pixel around the subject, not brightness;
--no-edge-refinement skips this); opening then closing with small elliptical
kernels, blobs smaller than --min-blob-area removed, holes inside the
silhouette filled.

A warning names any region that is foreground in 90 % or more of the frames (20
or more): a part of the scene the background model never learnt (the subject
stood there while it learnt, the camera moved).

A truncated or corrupt video is segmented up to the last readable frame, with
a warning naming where it stopped; a video with no readable frame is an error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputDataError, UsageError
from ..video.io import MASK_NAME, open_frames, remove_masks_from, write_mask
from ..video.segmentation import (
    DEFAULT_METHOD,
    DEFAULT_THRESHOLD,
    LEARN_FROM,
    METHODS,
    Segmenter,
    SegmentParams,
)
from ._common import count, lighting_notes, number, positive
from ._outputs import owns_output

NAME = "segment"
HELP = "video (or image folder) -> figure-ground masks by adaptive background subtraction"


def add_lighting_arguments(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """``--no-shadows``, ``--shadow-threshold`` and ``--no-gain-compensation``, shared with ``kms2pin track --video`` (``prefix`` starts its help)."""
    p.add_argument("--no-shadows", action="store_true",
                   help=f"{prefix}no shadow detection: pixels that are a darker copy of the background stay foreground "
                        "(default: they are shadows, i.e. background; turn it off when the subject's colours are "
                        "darker shades of the background's, e.g. light grey clothes before a white wall)")
    p.add_argument("--shadow-threshold", type=number(0.0, 1.0, lo_open=True, hi_open=True),
                   default=SegmentParams.shadow_threshold, metavar="T",
                   help=f"{prefix}a shadow keeps at least this fraction of the background's brightness (default "
                        "0.5, OpenCV's; 0.3 also takes deeper cast shadows for background, and with them subjects "
                        "in dark shades of the background's colours)")
    p.add_argument("--no-gain-compensation", action="store_true",
                   help=f"{prefix}do not divide each frame by its per-channel gain against the background (default: "
                        "the gain is measured and divided out, so that a camera's automatic exposure or white "
                        "balance, or a dimmer light, does not turn the whole image into foreground)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", metavar="VIDEO", help="video file, or a folder of images")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder for frame_NNNNN.png masks")
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"OpenCV background model (default: {DEFAULT_METHOD})")
    p.add_argument("--learn-frames", type=count, default=30, metavar="N",
                   help="frames that train the background model (default: 30; 0: learn online only)")
    p.add_argument("--learn-from", choices=LEARN_FROM, default="spread",
                   help="'spread': learning frames spread over the whole video (default); 'start': the first ones")
    p.add_argument("--threshold", type=positive, metavar="T",
                   help="foreground threshold: MOG2 varThreshold (squared Mahalanobis distance, default "
                        f"{DEFAULT_THRESHOLD['mog2']:g}) or KNN dist2Threshold (squared distance in grey levels, "
                        f"default {DEFAULT_THRESHOLD['knn']:g}); larger = fewer foreground pixels")
    p.add_argument("--history", type=number(1, 2**31 - 1, whole=True), default=500, metavar="N",  # OpenCV's int
                   help="adaptation time scale in frames; learning rate 1/N after learning (default: 500)")
    p.add_argument("--min-blob-area", type=count, metavar="PX",
                   help="drop foreground blobs smaller than this (default: 0.1%% of the image)")
    p.add_argument("--keep-holes", action="store_true", help="do not fill holes inside the silhouette")
    add_lighting_arguments(p)
    p.add_argument("--no-edge-refinement", action="store_true",
                   help="keep the rim of each mask as the colour test gives it (default: rim pixels whose "
                        "luminance is closer to the background's are dropped, which takes off the ~1 px colour "
                        "bleed of lossy video around the subject)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


@owns_output
def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    params = SegmentParams(
        method=args.method, learn_frames=args.learn_frames, learn_from=args.learn_from, history=args.history,
        threshold=args.threshold, min_blob_area=args.min_blob_area, fill_holes=not args.keep_holes,
        detect_shadows=not args.no_shadows, shadow_threshold=args.shadow_threshold,
        refine_edges=not args.no_edge_refinement, compensate_gain=not args.no_gain_compensation,
    )
    seg = Segmenter(params)  # checks the parameters
    for note in lighting_notes(args):
        print(f"note: {note}", file=sys.stderr)
    out = Path(args.output)
    if Path(args.video).is_dir() and out.resolve() == Path(args.video).resolve():
        raise UsageError(f"-o {args.output} is the input folder {args.video}: its frames would be replaced by "
                         "their masks; choose another output folder")
    source = open_frames(args.video)  # FileNotFoundError -> exit 2; no images / unreadable -> exit 1
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputDataError(f"{out}: cannot create the output folder: {e.strerror or e}") from None
    if params.learn_from == "spread" and params.learn_frames > 0 and not args.no_progress:
        print(f"{args.video}: learning the background from {params.learn_frames} frames ...", file=sys.stderr)
    n = 0
    bar = tqdm(total=source.len_hint, unit="frame", desc="segment", disable=args.no_progress, file=sys.stderr)
    with bar:
        for n, mask in enumerate(seg.masks(source), start=1):
            try:
                write_mask(out, n - 1, mask)
            except OSError as e:
                raise InputDataError(f"{out}: cannot write masks: {e.strerror or e}") from None
            bar.update(1)
    stale = remove_masks_from(out, n)
    if source.stopped_early:
        print(f"kms2pin segment: warning: {source.stopped_early}; masks written for those frames", file=sys.stderr)
    message = seg.static_foreground()
    if message:
        print(f"kms2pin segment: warning: {message}", file=sys.stderr)
    extra = f" (removed {stale} older mask(s) beyond the sequence)" if stale else ""
    print(f"{out}: {n} masks {MASK_NAME.format(0)}..{MASK_NAME.format(n - 1)}{extra}")
    return 0
