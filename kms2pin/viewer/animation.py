"""Trajectories as meshcat animations (one set_transform per body per frame)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import meshcat
import numpy as np
from meshcat.animation import Animation

from ..robot import Robot
from .errors import ViewerError
from .robot_view import RobotView, check_trajectory, save_html
from .scene import union_points

if TYPE_CHECKING:
    from ..ecm.trajectory import Trajectory


def animate(robot: Robot, trajectory: np.ndarray | Trajectory, fps: float = 30.0,
            vis: meshcat.Visualizer | None = None, *, camera: str = "front", aspect: float = 16 / 10,
            repetitions: int = 1, play: bool = True, scales: np.ndarray | None = None) -> meshcat.Visualizer:
    """Draw ``robot`` and load ``trajectory`` as a meshcat animation.

    ``trajectory`` is a ``(T, nq)`` array of configurations or anything with such a
    ``q`` attribute (a :class:`~kms2pin.ecm.Trajectory`).  The bodies are drawn at
    ``scales`` (n_bodies, 3) times the spec's semi-axes: by default the trajectory's own
    ``scales`` (the sizes a tracker measured), else the spec's.

    The model is drawn at frame 0; the camera frames every pose of the
    trajectory.  The animation (``fps`` frames per second) is part of
    ``vis.static_html()``, so a standalone page plays it.  Without ``vis`` the
    scene is recorded without a server.
    """
    traj = check_trajectory(robot, getattr(trajectory, "q", trajectory))
    fps = float(fps)
    if not (fps > 0 and np.isfinite(fps)):
        raise ViewerError(f"fps must be positive, not {fps}")
    if scales is None:
        scales = getattr(trajectory, "scales", None)
    view = RobotView(robot, traj[0], vis, camera=camera, aspect=aspect, serve=False, scales=scales)
    drawing = view.drawing
    stride = max(1, len(traj) // 50)
    pts = union_points([view.frame_points()] + [drawing.frame_points(q) for q in traj[::stride]])
    from .scene import frame_camera

    view.camera_setup = frame_camera(view.vis, camera, pts, aspect)
    # meshcat keys are frame numbers; three.js divides them by the clip's fps
    anim = Animation(default_framerate=fps)
    for i, q in enumerate(traj):
        with anim.at_frame(view.vis, i) as frame:
            for path, T in drawing.transforms(q).items():
                frame[path].set_transform(T)
    view.vis.set_animation(anim, play=play, repetitions=int(repetitions))
    return view.vis


def write_animation_html(robot: Robot, trajectory: np.ndarray | Trajectory, fps: float,
                         path: str | os.PathLike, *, camera: str = "front", repetitions: int = 1,
                         scales: np.ndarray | None = None) -> Path:
    """Write a standalone HTML page playing ``trajectory`` (as for :func:`animate`, the
    bodies at ``scales``; no server needed)."""
    vis = animate(robot, trajectory, fps, camera=camera, repetitions=repetitions, scales=scales)
    return save_html(vis, path)
