"""Video input for the tracker: figure-ground segmentation and camera set-up.

- :func:`read_frames` / :func:`open_frames`: frames of a video file or a folder of images;
- :func:`segment_frames`: adaptive background subtraction -> silhouettes (thesis §2.1.2);
- :func:`make_camera`, :func:`calibrate_chessboard`: cameras for :class:`kms2pin.ecm.Camera`.
"""

from kms2pin.video.calibration import (
    CalibrationResult,
    calibrate_chessboard,
    find_chessboard,
    make_camera,
    undistort_mask,
)
from kms2pin.video.io import FrameSource, TruncatedVideoWarning, list_images, open_frames, read_frames, write_mask
from kms2pin.video.segmentation import METHODS, SegmentParams, StaticForegroundWarning, segment_frames

__all__ = [
    "METHODS",
    "CalibrationResult",
    "FrameSource",
    "SegmentParams",
    "StaticForegroundWarning",
    "TruncatedVideoWarning",
    "calibrate_chessboard",
    "find_chessboard",
    "list_images",
    "make_camera",
    "open_frames",
    "read_frames",
    "segment_frames",
    "undistort_mask",
    "write_mask",
]
