"""A robot in a meshcat visualizer, with its own server (or none) and picture output."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import meshcat
import numpy as np

from ..robot import Robot
from . import render
from ._window import RecordingWindow, ServerWindow
from .errors import ViewerError
from .scene import CameraSetup, ModelDrawing, draw_world_axes, frame_camera, plain_background, union_points


def new_visualizer(serve: bool = True, timeout: float = 20.0, host: str = "127.0.0.1") -> meshcat.Visualizer:
    """A meshcat Visualizer on a fresh server listening on ``host`` (``serve=True``;
    127.0.0.1: this machine only), or on a
    :class:`~kms2pin.viewer._window.RecordingWindow` that needs no process.
    ``vis.close()`` stops the server; ``vis.url()`` is None without one."""
    window = ServerWindow(timeout=timeout, host=host) if serve else RecordingWindow()
    return meshcat.Visualizer(window=window)


def close_visualizer(vis: meshcat.Visualizer | None) -> None:
    """Stop ``vis``'s server if it has one (safe to call twice)."""
    if vis is not None and hasattr(vis.window, "close"):
        vis.window.close()
    elif vis is not None and getattr(vis.window, "server_proc", None) is not None:  # a plain meshcat window
        proc = vis.window.server_proc
        proc.kill()
        proc.wait(timeout=10)


@contextmanager
def visualizer(serve: bool = True) -> Iterator[meshcat.Visualizer]:
    """``with visualizer() as vis:`` -- a fresh server, always shut down."""
    vis = new_visualizer(serve)
    try:
        yield vis
    finally:
        close_visualizer(vis)


def save_html(vis: meshcat.Visualizer, path: str | os.PathLike) -> Path:
    """Write ``vis.static_html()`` (meshcat's standalone export) to ``path``."""
    return render.write_html(vis.static_html(), path)


def save_png(vis: meshcat.Visualizer, path: str | os.PathLike, width: int = 800, height: int = 800,
             timeout: float = 60.0) -> Path:
    """Screenshot ``vis``'s scene with headless Chromium (panel hidden, white page)."""
    return render.render_png(vis.static_html(), path, width, height, timeout=timeout)


class RobotView:
    """A robot drawn in meshcat: inner ellipsoids opaque, outer translucent, joint
    axes, inertial anchor and world axes (see :mod:`kms2pin.viewer.scene`).

    Args:
        robot: the compiled robot.
        q: configuration to show (default ``robot.q_rest``).
        vis: an existing Visualizer to draw into; default a new one, with a
            server if ``serve`` is true, else a server-less recording window.
        camera: ``front``, ``side``, ``top`` or ``iso``.
        aspect: width / height the camera is framed for.
        host: where a new server listens (default 127.0.0.1: this machine only).
        scales: (n_bodies, 3) factors of the bodies' semi-axes (a tracker's measured
            sizes; default the spec's).

    ``close()`` (or ``with RobotView(...)``) stops the server it started.
    """

    def __init__(self, robot: Robot, q=None, vis: meshcat.Visualizer | None = None, *, camera: str = "front",
                 aspect: float = 1.0, serve: bool = False, joint_axes: bool = True, anchor: bool = True,
                 world_axes: bool = True, outer: bool = True, name: str = "model", host: str = "127.0.0.1",
                 scales: np.ndarray | None = None):
        self.robot = robot
        self.owns_vis = vis is None
        self.vis = new_visualizer(serve, host=host) if vis is None else vis
        try:
            plain_background(self.vis)
            self.drawing = ModelDrawing(robot, self.vis, name, joint_axes=joint_axes, anchor=anchor, outer=outer,
                                        scales=scales)
            self.drawing.draw(robot.q_rest if q is None else q)
            self.axes_points = np.zeros((0, 3))
            if world_axes:
                self.axes_points = self._draw_world_axes()
            self.aspect = aspect
            self.camera_setup: CameraSetup | None = None
            self.camera(camera)
        except BaseException:
            if self.owns_vis:
                close_visualizer(self.vis)
            raise

    def _draw_world_axes(self) -> np.ndarray:
        """World axes at the bounding-box corner (min x, y, z) of the first pose shown,
        just outside it, pointing into the box: visible in every preset view."""
        d = self.drawing
        pts = d.frame_points()
        size = d.size
        origin = pts.min(axis=0) - 0.07 * size
        length = 0.22 * size
        draw_world_axes(self.vis, origin, length, 1.3 * d.axis_radius)
        return np.vstack([origin, origin + length * np.eye(3)])

    # ------------------------------------------------------------------ state
    @property
    def q(self) -> np.ndarray:
        return self.drawing.q.copy()

    @property
    def url(self) -> str | None:
        """The meshcat page, or None without a server."""
        return self.vis.window.web_url

    def set_configuration(self, q: np.ndarray) -> None:
        """Move the bodies to ``q`` (one set_transform per body)."""
        self.drawing.set_configuration(self.robot._check_q(q))

    def frame_points(self) -> np.ndarray:
        return union_points([self.drawing.frame_points(), self.axes_points])

    def camera(self, view: str = "front", aspect: float | None = None) -> CameraSetup:
        """Frame the current pose from a preset view."""
        if aspect is not None:
            self.aspect = aspect
        first = self.camera_setup is None
        self.camera_setup = frame_camera(self.vis, view, self.frame_points(), self.aspect, set_lens=first)
        return self.camera_setup

    # ------------------------------------------------------------------ output
    def static_html(self) -> str:
        return self.vis.static_html()

    def write_html(self, path: str | os.PathLike) -> Path:
        return save_html(self.vis, path)

    def write_png(self, path: str | os.PathLike, width: int = 800, height: int = 800) -> Path:
        """Screenshot; the camera is re-framed for ``width/height`` first."""
        if self.camera_setup is not None and abs(self.camera_setup.aspect - width / height) > 1e-9:
            self.camera(self.camera_setup.view, width / height)
        return save_png(self.vis, path, width, height)

    def close(self) -> None:
        if self.owns_vis:
            close_visualizer(self.vis)

    def __enter__(self) -> RobotView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def show(robot: Robot, q: np.ndarray | None = None, vis: meshcat.Visualizer | None = None, camera: str = "front",
         aspect: float = 1.0) -> RobotView:
    """Draw ``robot`` at ``q`` (server-less unless ``vis`` is given)."""
    return RobotView(robot, q, vis, camera=camera, aspect=aspect)


def check_trajectory(robot: Robot, trajectory: np.ndarray) -> np.ndarray:
    traj = np.asarray(trajectory, dtype=float)
    if traj.ndim != 2 or traj.shape[1] != robot.nq or traj.shape[0] < 1:
        raise ViewerError(f"trajectory must have shape (T, {robot.nq}) with T >= 1, not {traj.shape}")
    if not np.all(np.isfinite(traj)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(traj), axis=1))[0])
        raise ViewerError(f"trajectory frame {bad} is not finite")
    return traj
