"""Tracking results: one frame's (:class:`FrameResult`) and a sequence's
(:class:`Trajectory`, saved as CSV of joint angles in degrees and NPZ of body poses),
and :class:`TrajectoryCsvWriter`, which writes the CSV a frame at a time."""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputDataError
from ..lang.symbols import MAX_LENGTH
from ..robot import Robot
from ..userfile import MAX_DATA_BYTES, read_user_file

#: the start of a frame's flag that its fit is below the tracker's ``poor_fit``
POOR_FIT = "poor fit"


def poor_fit_flag(fit: float) -> str:
    """The flag of a frame fitting ``fit`` (IoU), below the tracker's ``poor_fit``."""
    return f"{POOR_FIT} ({fit:.2f})"


@dataclass(frozen=True)
class FrameResult:
    """One tracked frame.

    Attributes:
        q: (nq,) Pinocchio configuration; a free-flyer root is
            ``(x, y, z, qx, qy, qz, qw)``, quaternion scalar last.
        body_poses: (n_bodies, 7) maximal coordinates ``(x, y, z, e0, e1, e2, e3)`` at
            ``q``: world position of the body frame (m), then Euler parameters scalar
            first (eq. 2.7).
        iterations: ECM iterations run.
        fit: intersection over union of the model's inner silhouettes with the masks
            (over all cameras).
        converged: whether the configuration stopped changing within the limit.
        flags: notes such as ``"empty mask"`` or ``"mask nearly full"`` (more than 90 %
            of every camera's mask foreground: pose kept from the previous frame),
            ``"poor fit (0.31)"`` (fit below the tracker's ``poor_fit``; the next frame
            is predicted without velocity), ``"lost: kept the last pose"`` (the model's
            silhouettes miss the masks entirely), ``"switched to the mirror
            hypothesis"`` or ``"switched to the left/right-swapped hypothesis"``, and
            the limb search's ``"swung '<joint>' the other way"``, ``"put the joints
            below '<joint>' back at rest"`` and ``"swapped '<left joint>' and '<right
            joint>'"``, the reach search's ``"pointed '<joint>' at the masks"``, and ``"from the
            second track"`` (``second_track``: the second track's pose fitted better).
        timings: seconds spent in the E-step, M-step and static update, and in the size
            refinement (``sizes``; :meth:`step` only).
    """

    q: np.ndarray
    body_poses: np.ndarray
    iterations: int
    fit: float
    converged: bool
    flags: tuple[str, ...] = ()
    timings: dict = field(default_factory=dict)


class Trajectory:
    """Tracked (or true) configurations over frames, with CSV/NPZ input and output.

    Args:
        robot: the model the configurations belong to.
        q: (frames, nq) Pinocchio configurations, or one (nq,) configuration.  A
            free-flyer root is ``(x, y, z, qx, qy, qz, qw)``: quaternion scalar last.
        results: the tracker's :class:`FrameResult` per frame, or none.
        scales: (n_bodies, 3) semi-axis factors of the tracked model, or None.

    Raises :class:`InputDataError` for a ``q`` of another shape, a non-finite ``q``
    (naming the first such frame) or a number of results other than 0 or ``frames``.

    The CSV has a ``frame`` column then the columns :attr:`Robot.coordinate_names`:
    revolute joint angles in degrees and prismatic offsets in spec length units, named
    after the joint; a spherical joint's X-Y-Z angles in degrees (R = Rx Ry Rz, its URDF
    joints ``<joint>_x``, ``_y``, ``_z``); a free-flyer root as ``root_x, root_y, root_z,
    root_qx, root_qy, root_qz, root_qw``.
    """

    def __init__(self, robot: Robot, q: np.ndarray, results: Sequence[FrameResult] = (),
                 scales: np.ndarray | None = None):
        self.robot = robot
        q = np.asarray(q, dtype=float)
        if q.shape == (robot.nq,):
            q = q[None]
        if q.ndim != 2 or q.shape[1] != robot.nq:
            raise InputDataError(f"q must have shape (frames, nq) with nq = {robot.nq}, not {q.shape}")
        bad = np.flatnonzero(~np.isfinite(q).all(axis=1))
        if len(bad):
            raise InputDataError(f"q of frame {bad[0]} is not finite: {q[bad[0]].tolist()}")
        self.q = q
        self.results = list(results)
        if self.results and len(self.results) != len(q):
            raise InputDataError(f"results must be empty or one per frame ({len(q)}), not {len(self.results)}")
        #: (n_bodies, 3) semi-axis factors of the tracked model (:meth:`~kms2pin.ecm.tracker.Tracker.calibrate`)
        self.scales = None if scales is None else np.array(scales, dtype=float)  # a copy: the tracker refines its own

    def __len__(self) -> int:
        return len(self.q)

    def smoothed(self, fps: float, cutoff_hz: float, order: int = 2) -> Trajectory:
        """This trajectory low-pass filtered joint by joint at ``cutoff_hz``, forwards and
        backwards (:func:`kms2pin.ecm.smoothing.smooth`; ``fps`` its frame rate): the
        same scales, no per-frame results (they belong to the tracked poses)."""
        from .smoothing import smooth

        return Trajectory(self.robot, smooth(self.robot, self.q, fps, cutoff_hz, order), scales=self.scales)

    @staticmethod
    def columns(robot: Robot) -> list[str]:
        """The CSV's joint-coordinate columns: :attr:`Robot.coordinate_names`."""
        return list(robot.coordinate_names)

    def table(self) -> np.ndarray:
        """(T, n_coordinates) in CSV units (:meth:`Robot.coordinates`): revolute angles and
        spherical joints' X-Y-Z angles in degrees, prismatic offsets in spec units."""
        return self.robot.coordinates(self.q)

    def to_csv(self, path: str | os.PathLike, frames: Sequence[int] | None = None) -> None:
        """Write the CSV (class docstring), numbering the rows ``frames`` (default 0, 1, ...)."""
        extra = bool(self.results)
        numbers = range(len(self)) if frames is None else list(frames)
        if len(numbers) != len(self):
            raise InputDataError(f"frames must number every frame ({len(self)}), not {len(numbers)}")
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["frame", *self.columns(self.robot), *(["fit", "flags"] if extra else [])])
            for k, row in enumerate(self.table()):
                tail = []
                if extra:
                    r = self.results[k]
                    tail = [f"{r.fit:.4f}", ";".join(r.flags)]
                w.writerow([numbers[k], *(f"{x:.10g}" for x in row), *tail])

    def to_npz(self, path: str | os.PathLike) -> None:
        """Save as NPZ (read back by :meth:`from_npz`), with the arrays

        - ``q`` (T, nq): Pinocchio configurations (free-flyer quaternion scalar last);
        - ``body_poses`` (T, n_bodies, 7): maximal coordinates ``(x, y, z, e0, e1, e2,
          e3)``, Euler parameters scalar first (eq. 2.7);
        - ``bodies``, ``joint_names``: the robot's names;
        - ``fit``, ``iterations``, ``converged`` and ``flags`` (``;``-joined) per frame,
          empty without tracker results;
        - ``body_scales`` (n_bodies, 3): the body-size factors the tracker used (ones
          if none).
        """
        if self.results:  # the tracker's own, at each frame's q
            poses = np.array([r.body_poses for r in self.results], dtype=float)
        else:
            poses = np.array([self.robot.maximal_coordinates(q) for q in self.q])
        poses = poses.reshape(len(self.q), len(self.robot.bodies), 7)
        res = self.results
        np.savez_compressed(
            path,
            q=self.q,
            body_poses=poses,
            bodies=np.array(self.robot.bodies),
            joint_names=np.array(self.robot.joint_names),
            fit=np.array([r.fit for r in res], dtype=float),
            iterations=np.array([r.iterations for r in res], dtype=int),
            converged=np.array([r.converged for r in res], dtype=bool),
            flags=np.array([";".join(r.flags) for r in res], dtype=str),
            body_scales=np.ones((len(self.robot.bodies), 3)) if self.scales is None else self.scales,
        )

    @classmethod
    def from_npz(cls, robot: Robot, path: str | os.PathLike) -> Trajectory:
        """Read a trajectory saved by :meth:`to_npz` (``kms2pin track``'s ``poses.npz``).

        Restores ``q``, ``scales`` and, if the file has them, one :class:`FrameResult`
        per frame (its ``body_poses`` from the file, no ``timings``).  Raises
        :class:`InputDataError` naming the file if it cannot be read or was saved for
        other bodies.
        """
        try:
            z = np.load(path, allow_pickle=False)
        except OSError as err:
            raise InputDataError(f"{path}: cannot read: {err.strerror or err}") from None
        except (ValueError, EOFError):
            z = None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise InputDataError(f"{path}: not an NPZ file")
        with z:
            data = {k: z[k] for k in z.files}
        missing = [k for k in ("q", "body_poses", "bodies") if k not in data]
        if missing:
            raise InputDataError(f"{path}: missing arrays {', '.join(missing)}; the file has {', '.join(data)}")
        if list(data["bodies"]) != list(robot.bodies):
            raise InputDataError(
                f"{path}: saved for the bodies {', '.join(data['bodies'])}, "
                f"not those of '{robot.system.name}': {', '.join(robot.bodies)}"
            )
        q, poses, fit = data["q"], data["body_poses"], data.get("fit", np.zeros(0))
        results = []
        if len(fit):
            if len(fit) != len(q) or len(poses) != len(q):
                raise InputDataError(f"{path}: {len(q)} frames of q but {len(poses)} of body_poses and {len(fit)} fits")
            its = data.get("iterations", np.zeros(len(q), dtype=int))
            conv = data.get("converged", np.zeros(len(q), dtype=bool))
            flags = data.get("flags", np.full(len(q), ""))
            results = [
                FrameResult(q[k].copy(), poses[k], int(its[k]), float(fit[k]), bool(conv[k]),
                            tuple(str(flags[k]).split(";")) if flags[k] else ())
                for k in range(len(q))
            ]
        try:
            return cls(robot, q, results, scales=data.get("body_scales"))
        except InputDataError as err:
            raise InputDataError(f"{path}: {err}") from None

    @classmethod
    def from_csv(cls, robot: Robot, path: str | os.PathLike) -> Trajectory:
        """Read a trajectory CSV (as written by :meth:`to_csv` or ``kms2pin synth``).

        A file with only the header gives an empty trajectory.  Raises
        :class:`InputDataError` naming the file, and the line and column for a bad
        cell (every joint coordinate must be a finite number).
        """
        try:
            text = read_user_file(path, MAX_DATA_BYTES).decode("utf-8-sig")
            reader = csv.reader(io.StringIO(text, newline=""))
            rows = [(reader.line_num, row) for row in reader]
        except OSError as err:
            raise InputDataError(f"{path}: cannot read: {err.strerror}") from None
        except UnicodeDecodeError:
            raise InputDataError(f"{path}: not a text (CSV) file") from None
        except csv.Error as err:
            raise InputDataError(f"{path}:{reader.line_num}: not a valid CSV file: {err}") from None
        if not rows:
            raise InputDataError(f"{path}: empty trajectory file")
        header = rows[0][1]
        cols = cls.columns(robot)
        missing = [c for c in cols if c not in header]
        if missing:
            raise InputDataError(
                f"{path}: missing columns {', '.join(missing)} for '{robot.system.name}' "
                f"(root={robot.root!r}); the file has {', '.join(header)}"
            )
        twice = next((c for c in cols if header.count(c) > 1), None)
        if twice is not None:
            at = [k + 1 for k, h in enumerate(header) if h == twice]
            raise InputDataError(f"{path}:1: column '{twice}' appears {len(at)} times (columns "
                                 f"{', '.join(map(str, at))}): which one holds the joint is not clear")
        idx = [header.index(c) for c in cols]
        body = rows[1:]
        q = np.empty((len(body), len(cols)))  # CSV coordinates, converted to q below
        short = len(body)  # the first malformed row, reported after any bad cell above it
        for k, (_, row) in enumerate(body):
            if len(row) <= max(idx):
                short = k
                break
            for c, i in enumerate(idx):
                try:
                    q[k, c] = float(row[i])
                except ValueError:  # not a number: reported below as a non-finite one, with its text
                    q[k, c] = np.nan
        bad = np.argwhere(~np.isfinite(q[:short]))
        if len(bad):
            k, c = bad[0]
            line, row = body[k]
            raise InputDataError(f"{path}:{line}: column '{cols[c]}': {row[idx[c]]!r} is not a finite number")
        if short < len(body):
            line, row = body[short]
            raise InputDataError(f"{path}:{line}: malformed row: {len(row)} fields, the header has {len(header)}")
        if robot.root == "free":
            _check_root(q, [line for line, _ in body], cols, path)
        return cls(robot, robot.configuration(q))


def _check_root(q: np.ndarray, lines: list[int], cols: list[str], path) -> None:
    """A free root's rows of a CSV: position within +-MAX_LENGTH, quaternion not zero;
    the quaternions are normalized in place (as Robot's methods take them)."""
    far = np.flatnonzero(np.abs(q[:, :3]).max(axis=1, initial=0) > MAX_LENGTH)
    if len(far):
        k = far[0]
        raise InputDataError(f"{path}:{lines[k]}: root position ({', '.join(cols[:3])}) must be within "
                             f"+-{MAX_LENGTH:g}, got {q[k, :3].tolist()}")
    quat = q[:, 3:7]
    scale = np.abs(quat).max(axis=1, initial=0)
    zero = np.flatnonzero(scale == 0)
    if len(zero):
        raise InputDataError(f"{path}:{lines[zero[0]]}: the root quaternion ({', '.join(cols[3:7])}) is zero")
    quat /= scale[:, None]  # scaled first, so that huge or tiny values do not overflow
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)


class TrajectoryCsvWriter:
    """Appends one :class:`Trajectory` CSV row per frame (flushed), so a crash or an
    interruption leaves a complete file up to the last finished frame."""

    def __init__(self, robot: Robot, path: str | os.PathLike):
        self.robot = robot
        self._f = open(path, "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(["frame", *Trajectory.columns(robot), "fit", "flags"])
        self._f.flush()

    def write(self, frame: int, result: FrameResult) -> None:
        row = Trajectory(self.robot, result.q).table()[0]
        self._w.writerow([frame, *(f"{x:.10g}" for x in row), f"{result.fit:.4f}", ";".join(result.flags)])
        self._f.flush()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> TrajectoryCsvWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
