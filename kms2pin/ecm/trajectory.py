"""Tracking results: one frame's (:class:`FrameResult`) and a sequence's
(:class:`Trajectory`, saved as CSV of joint angles in degrees and NPZ of body poses),
and :class:`TrajectoryCsvWriter`, which writes the CSV a frame at a time."""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputDataError
from ..robot import Robot


@dataclass(frozen=True)
class FrameResult:
    """One tracked frame.

    Attributes:
        q: configuration (Pinocchio ``q``).
        body_poses: (n_bodies, 7) maximal coordinates [mu, theta0..3] at ``q``.
        iterations: ECM iterations run.
        fit: intersection over union of the model's inner silhouettes with the masks
            (over all cameras).
        converged: whether the configuration stopped changing within the limit.
        flags: notes such as ``"empty mask"`` (pose kept from the previous frame),
            ``"poor fit (0.31)"`` (fit below the tracker's ``poor_fit``; the next frame
            is predicted without velocity), ``"lost: kept the last pose"`` (the model's
            silhouettes miss the masks entirely), ``"switched to the mirror
            hypothesis"`` or ``"switched to the left/right-swapped hypothesis"``, and
            the limb search's ``"swung '<joint>' the other way"``, ``"put the joints
            below '<joint>' back at rest"`` and ``"swapped '<left joint>' and '<right
            joint>'"``.
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

    The CSV has a ``frame`` column then one column per joint coordinate: revolute
    joint angles in degrees named after the joint; a free-flyer root as
    ``root_x, root_y, root_z, root_qx, root_qy, root_qz, root_qw``.
    """

    def __init__(self, robot: Robot, q: np.ndarray, results: Sequence[FrameResult] = (), scales=None):
        self.robot = robot
        self.q = np.asarray(q, dtype=float).reshape(-1, robot.nq)
        self.results = list(results)
        #: (n_bodies, 3) semi-axis factors of the tracked model (:meth:`~kms2pin.ecm.tracker.Tracker.calibrate`)
        self.scales = None if scales is None else np.array(scales, dtype=float)  # a copy: the tracker refines its own

    def __len__(self) -> int:
        return len(self.q)

    @staticmethod
    def columns(robot: Robot) -> list[str]:
        cols = []
        for jid in range(1, robot.model.njoints):
            j = robot.model.joints[jid]
            name = robot.model.names[jid]
            if j.nq == 7:
                cols += ["root_x", "root_y", "root_z", "root_qx", "root_qy", "root_qz", "root_qw"]
            elif j.nq == 1:
                cols.append(name)
            else:  # pragma: no cover - the compiler makes only these joints
                cols += [f"{name}_{k}" for k in range(j.nq)]
        return cols

    def table(self) -> np.ndarray:
        """(T, nq) with revolute angles in degrees (CSV units)."""
        out = self.q.copy()
        for jid in range(1, self.robot.model.njoints):
            j = self.robot.model.joints[jid]
            if j.nq == 1:
                out[:, j.idx_q] = np.degrees(out[:, j.idx_q])
        return out

    def to_csv(self, path: str | os.PathLike) -> None:
        extra = bool(self.results)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["frame", *self.columns(self.robot), *(["fit", "flags"] if extra else [])])
            for k, row in enumerate(self.table()):
                tail = []
                if extra:
                    r = self.results[k]
                    tail = [f"{r.fit:.4f}", ";".join(r.flags)]
                w.writerow([k, *(f"{x:.10g}" for x in row), *tail])

    def to_npz(self, path: str | os.PathLike) -> None:
        """Body poses (T, n_bodies, 7) maximal coordinates, q (T, nq), body and joint names,
        fits and the body-size factors (n_bodies, 3) the tracker used."""
        poses = np.array([self.robot.maximal_coordinates(q) for q in self.q])
        np.savez_compressed(
            path,
            q=self.q,
            body_poses=poses,
            bodies=np.array(self.robot.bodies),
            joint_names=np.array(self.robot.joint_names),
            fit=np.array([r.fit for r in self.results]) if self.results else np.zeros(0),
            body_scales=np.ones((len(self.robot.bodies), 3)) if self.scales is None else self.scales,
        )

    @classmethod
    def from_csv(cls, robot: Robot, path: str | os.PathLike) -> Trajectory:
        """Read a trajectory CSV (as written by :meth:`to_csv` or ``kms2pin synth``).

        A file with only the header gives an empty trajectory.  Raises
        :class:`InputDataError` naming the file, and the line and column for a bad
        cell (every joint coordinate must be a finite number).
        """
        try:
            with open(path, newline="", encoding="utf-8-sig") as f:
                reader = csv.reader(f)
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
        idx = [header.index(c) for c in cols]
        q = np.empty((len(rows) - 1, robot.nq))
        for k, (line, row) in enumerate(rows[1:]):
            if len(row) <= max(idx):
                raise InputDataError(f"{path}:{line}: malformed row: {len(row)} fields, the header has {len(header)}")
            for c, (name, i) in enumerate(zip(cols, idx)):
                try:
                    q[k, c] = float(row[i])
                except ValueError:
                    q[k, c] = np.nan
                if not np.isfinite(q[k, c]):
                    raise InputDataError(f"{path}:{line}: column '{name}': {row[i]!r} is not a finite number")
        for jid in range(1, robot.model.njoints):
            j = robot.model.joints[jid]
            if j.nq == 1:
                q[:, j.idx_q] = np.radians(q[:, j.idx_q])
        return cls(robot, q)


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
