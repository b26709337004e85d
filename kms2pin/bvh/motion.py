"""What a BVH file's channels mean, brought into the model's frame (+y up, metres).

Each joint J has a frame F_J = F_parent Trans(t_J) R_J (the root's parent is the world):

* t_J is J's OFFSET with each component J has a position channel for replaced by that
  channel's value, as Blender's importer and D. Holden's widely copied loader read them
  (a root's position channels are its position; Meredith and Maddock's text adds them to
  the OFFSET instead: the two agree for the usual root OFFSET of 0);
* R_J is the product of J's rotation channels in file order, angles in degrees:
  ``Zrotation Yrotation Xrotation`` is R_J = Rz(z) Ry(y) Rx(x), whatever the order of
  the channels among themselves or next to the position channels.

At rest (the offsets pose) every R_J is the identity.  The model's world has +y up:
W maps a file's coordinates to it, the identity for a Y-up file and (x, y, z) ->
(x, z, -y) (a quarter turn about x) for a Z-up one; then every rotation is W R W^T and
every length W x times the scale (metres per file unit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..errors import BvhError
from .reader import BvhFile

UPS = ("auto", "y", "z")
#: W for each up axis: file coordinates -> the model's (+y up)
_WORLD = {"y": np.eye(3), "z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])}
#: a frame time within this (relative) of 1/N seconds, N whole, is taken as 1/N (".0083333" is 1/120)
FRAME_RATE_SNAP = 1e-5


@dataclass(frozen=True)
class Skeleton:
    """A BVH skeleton and its motion in the model's frame (+y up, metres).

    ``offsets`` (J, 3) and ``ends`` (each joint's End Sites, (k, 3)) are the rest pose's,
    in the parent's frame; ``translations`` (frames, J, 3) are the t_J of each frame and
    ``rotations`` each joint's R_J over the frames (a :class:`Rotation` of length frames).
    ``axes`` are the unit axes of each joint's rotation channels, in order; ``fps`` the
    frame rate, ``up`` the file's up axis and ``height`` the rest pose's vertical extent.
    """

    bvh: BvhFile
    offsets: np.ndarray
    ends: tuple[np.ndarray, ...]
    translations: np.ndarray
    rotations: tuple[Rotation, ...]
    axes: tuple[np.ndarray, ...]
    fps: float
    up: str
    height: float

    @property
    def frames(self) -> int:
        return len(self.translations)

    def parent(self, j: int) -> int | None:
        return self.bvh.joints[j].parent


def rest_points(bvh: BvhFile) -> np.ndarray:
    """(n, 3) every joint's and End Site's point at rest (all R_J = I), file units and axes."""
    points = np.zeros((len(bvh.joints), 3))
    ends = []
    for k, j in enumerate(bvh.joints):
        points[k] = np.asarray(j.offset) + (points[j.parent] if j.parent is not None else 0.0)
        ends += [points[k] + np.asarray(e) for e in j.end_sites]
    return np.vstack([points, *ends]) if ends else points


def choose_up(bvh: BvhFile, up: str) -> tuple[str, str]:
    """The file's up axis (``"y"`` or ``"z"``) and why: given, or (``"auto"``) the axis of the
    two along which the rest pose is taller (a standing skeleton is deeper along neither)."""
    extent = np.ptp(rest_points(bvh), axis=0)
    if up != "auto":
        return up, "as given"
    axis = "z" if extent[2] > extent[1] else "y"
    return axis, f"the rest pose spans {extent[1]:.4g} along y and {extent[2]:.4g} along z file units"


def frame_rate(frame_time: float) -> float:
    """Frames per second of a file's ``Frame Time`` (snapped to a whole rate, :data:`FRAME_RATE_SNAP`)."""
    rate = 1.0 / frame_time
    whole = round(rate)
    return float(whole) if whole >= 1 and abs(rate - whole) <= FRAME_RATE_SNAP * rate else rate


def skeleton(bvh: BvhFile, scale: float = 1.0, up: str = "auto", fps: float | None = None) -> Skeleton:
    """The skeleton and motion of ``bvh`` in the model's frame, lengths times ``scale``, the
    motion resampled at ``fps`` frames per second if given (module docstring)."""
    up, _ = choose_up(bvh, up)
    W = _WORLD[up]
    turn = Rotation.from_matrix(W)
    offsets = scale * np.array([j.offset for j in bvh.joints], dtype=float).reshape(-1, 3) @ W.T
    ends = tuple(scale * np.array(j.end_sites, dtype=float).reshape(-1, 3) @ W.T for j in bvh.joints)
    frames = len(bvh.motion)
    translations = np.repeat(np.array([j.offset for j in bvh.joints], dtype=float)[None], frames, axis=0)
    rotations, axes = [], []
    for k, j in enumerate(bvh.joints):
        values = bvh.channels(j)
        for c, name in enumerate(j.channels):
            if name.endswith("position"):
                translations[:, k, "XYZ".index(name[0])] = values[:, c]
        order = j.rotation_order
        angles = values[:, [c for c, name in enumerate(j.channels) if name.endswith("rotation")]]
        R = Rotation.from_euler(order, angles, degrees=True) if order else Rotation.identity(frames)
        rotations.append(turn * R * turn.inv())
        axes.append(tuple(W[:, "XYZ".index(a)] for a in order))
    translations = scale * translations @ W.T
    height = float(np.ptp((rest_points(bvh) @ W.T)[:, 1])) * scale
    rate = frame_rate(bvh.frame_time)
    sk = Skeleton(bvh, offsets, ends, translations, tuple(rotations), tuple(axes), rate, up, height)
    return sk if fps is None else resample(sk, fps)


def resample(sk: Skeleton, fps: float) -> Skeleton:
    """``sk``'s motion at ``fps`` frames per second from its first frame to no later than its
    last: translations interpolated linearly, rotations by slerp (the shorter arc)."""
    if sk.frames < 2:
        raise BvhError(f"{sk.bvh.path}: --fps resamples a motion, but this one has {sk.frames} frame(s)")
    times = np.arange(sk.frames) / sk.fps
    new = np.arange(int(np.floor(times[-1] * fps + 1e-9)) + 1) / fps
    new = np.minimum(new, times[-1])
    k = np.minimum(np.searchsorted(times, new, side="right") - 1, sk.frames - 2)
    alpha = ((new - times[k]) * sk.fps)[:, None, None]
    translations = (1.0 - alpha) * sk.translations[k] + alpha * sk.translations[k + 1]
    rotations = tuple(Slerp(times, R)(new) for R in sk.rotations)
    return Skeleton(sk.bvh, sk.offsets, sk.ends, translations, rotations, sk.axes, float(fps), sk.up, sk.height)
