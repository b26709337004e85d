"""meshcat viewer for compiled models: our version of the thesis's ECM GUI (§3.2.3).

* :class:`RobotView` / :func:`show` -- a robot drawn in meshcat (inner ellipsoids
  opaque, outer translucent, joint axes, inertial anchor, world axes), camera
  presets ``front``/``side``/``top``/``iso``, standalone HTML and PNG output.
* :class:`JointControl` -- a page with one slider per joint coordinate beside the
  meshcat viewer (interactive joint manipulation, §4.1).
* :func:`show_static_update` -- static-update pictures as in figures 4.1-4.12.
* :func:`animate`, :func:`write_animation_html` -- trajectories as animations.
* :func:`screenshot` -- headless Chromium on a standalone page.
* :func:`overlay_image` -- the tracking overlay: masks with the projected ellipses.

Frames and views are explained in :mod:`kms2pin.viewer.scene` (the thesis's
y-up world is put under a transform turning it into meshcat's z-up world).
"""

from __future__ import annotations

import warnings

with warnings.catch_warnings():  # meshcat's server module imports a deprecated pyzmq API
    warnings.simplefilter("ignore", DeprecationWarning)
    import meshcat  # noqa: F401
    import meshcat.servers.zmqserver  # noqa: F401

from .animation import animate, write_animation_html
from .control import JointControl
from .errors import PoseError, ViewerError
from .overlay import overlay_image
from .pose import JointSlider, joint_angles_deg, joint_sliders, parse_pose, pose_string, revolute_joints, slider_values
from .render import find_chromium, read_png, screenshot
from .robot_view import RobotView, close_visualizer, new_visualizer, save_html, save_png, show, visualizer
from .scene import VIEWS, CameraSetup, ModelDrawing, frame_camera, projected_box, view_basis
from .springs import StaticUpdateDrawing, draw_static_update, show_static_update, target_poses

__all__ = [
    "VIEWS",
    "CameraSetup",
    "JointControl",
    "JointSlider",
    "ModelDrawing",
    "PoseError",
    "RobotView",
    "StaticUpdateDrawing",
    "ViewerError",
    "animate",
    "close_visualizer",
    "draw_static_update",
    "find_chromium",
    "frame_camera",
    "joint_angles_deg",
    "joint_sliders",
    "new_visualizer",
    "overlay_image",
    "parse_pose",
    "pose_string",
    "projected_box",
    "read_png",
    "revolute_joints",
    "save_html",
    "save_png",
    "screenshot",
    "show",
    "show_static_update",
    "slider_values",
    "target_poses",
    "view_basis",
    "visualizer",
    "write_animation_html",
]
