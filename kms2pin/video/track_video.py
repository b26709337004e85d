"""Video input for ``kms2pin track --video``: segmentation of synchronized videos
(one per camera) into masks, and the joint-angle plot.

:func:`segment_videos` checks every video's frame size against its camera,
segments it (as :func:`kms2pin.video.segment_frames` does) and returns the masks; the
videos are cut to the shortest, and a truncated or partly unreadable video
is used up to its last good frame - both with a note saying so.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..ecm.camera import Camera
from ..errors import InputDataError
from ..robot import Robot
from .io import open_frames
from .segmentation import Segmenter, SegmentParams


def frame_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of the first frame of a video file or image folder."""
    src = open_frames(path)
    if src.frame_size is not None:  # a video: its probe decoded the first frame
        return src.frame_size
    it = iter(src)
    try:
        _, img = next(it)
    except StopIteration:
        raise InputDataError(f"{path}: no frame could be read") from None
    finally:
        it.close()
    return img.shape[1], img.shape[0]


def segment_videos(
    videos: Sequence[str | os.PathLike],
    cameras: Sequence[Camera],
    camera_names: Sequence[str] | None = None,
    method: str = "mog2",
    **segment_kw: Any,
) -> tuple[list[list[np.ndarray]], list[str]]:
    """Masks (per camera, per frame; all cut to the shortest video) and notes for the user.

    Raises :class:`InputDataError` naming the video and the camera if a video's
    frame size is not the camera's.
    """
    if len(videos) != len(cameras):
        raise InputDataError(
            f"{len(videos)} video(s) but {len(cameras)} camera(s): give one --camera per --video, in the same order"
        )
    names = list(camera_names) if camera_names else [c.name or f"camera {k}" for k, c in enumerate(cameras)]
    for k, (v, cam) in enumerate(zip(videos, cameras)):
        w, h = frame_size(v)
        if (w, h) != (cam.width, cam.height):
            raise InputDataError(
                f"{v}: frames are {w}x{h} pixels but camera {k} ({names[k]}) is {cam.width}x{cam.height}; "
                "give the camera of this video (same order as --video) or rescale the video"
            )
    per_cam: list[list[np.ndarray]] = []
    notes: list[str] = []
    for v in videos:
        src = open_frames(v)
        seg = Segmenter(SegmentParams(method=method, **segment_kw))
        masks = [m > 0 for m in seg.masks(src)]
        message = seg.static_foreground()
        if message:
            notes.append(f"{v}: {message}")
        if src.stopped_early:
            notes.append(f"{src.stopped_early}; tracking the {len(masks)} frame(s) read")
        per_cam.append(masks)
    counts = [len(m) for m in per_cam]
    n = min(counts)
    if len(set(counts)) > 1:
        detail = ", ".join(f"{v}: {c}" for v, c in zip(videos, counts))
        shortest = videos[int(np.argmin(counts))]
        notes.append(f"the videos differ in length ({detail} frames); stopping at the shortest ({shortest}): "
                     f"frames 0-{n - 1}")
        per_cam = [m[:n] for m in per_cam]
    return per_cam, notes


def plot_joint_angles(robot: Robot, q: np.ndarray, path: str | os.PathLike, frames: Sequence[int] | None = None,
                      title: str | None = None) -> Path:
    """PNG of every joint angle (degrees: revolute angles and spherical joints' X-Y-Z
    angles, :meth:`Robot.coordinates`) over the frame number, one line each, the legend
    outside the axes (matplotlib, Agg backend)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    q = np.asarray(q, dtype=float).reshape(-1, robot.nq)
    x = np.arange(len(q)) if frames is None else np.asarray(frames)
    fig = Figure(figsize=(9, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    columns = dict(zip(robot.coordinate_names, robot.coordinates(q).T))
    for j in robot.joints:
        if j.kind in ("revolute", "spherical"):
            for name in j.names:
                ax.plot(x, columns[name], label=name, linewidth=1.2)
    ax.set_xlabel("frame")
    ax.set_ylabel("joint angle (degrees)")
    ax.set_title(title or f"{robot.system.name}: joint angles")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, format="png")
    return path
