"""The tracks beside in worker processes (``Tracker(..., jobs=N)``, ``kms2pin track --jobs N``).

The tracks beside the first (``second_track``, :mod:`~kms2pin.ecm.secondtrack`) never
read each other: each goes on from its own poses, and only each frame's results meet.  So
they can run at once.  :class:`BesideTracks` holds them: with ``jobs`` processes, track
``i`` (0 the tracker's own, 1 the first beside it, ...) runs in process ``i % jobs``,
process 0 being this one and the others forked from it once the trackers are made (each
child starts with its trackers in memory; only the masks go out, and each frame's results
and poses come back).  The frames are tracked in step: a frame is sent to every child
before this process tracks its own part of it.  The results are those of one process to
the last bit (the same code on the same numbers).

A child ignores Ctrl-C (this process handles it) and ends when this process closes it
(:meth:`BesideTracks.close`, or when the tracker is collected or the interpreter exits)
or ends itself; it ends quietly on SIGTERM.  After an interrupt that leaves the children out
of step (Ctrl-C while this process waits for them) they are ended, and the tracker says so
at its next frame.  Forking is done on Linux only; elsewhere every track runs in this process.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import sys
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import OptionError
from .secondtrack import track_name
from .trajectory import FrameResult

if TYPE_CHECKING:
    from .tracker import Tracker

__all__ = ["FORK", "BesideTracks", "RemoteTrack", "usable_cores"]

#: whether child processes are forked here (Linux; elsewhere ``jobs`` is taken as 1: macOS's
#: system libraries are not safe to fork, and Windows cannot)
FORK = sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods()
#: seconds a child waits for a message before it looks whether this process still runs
_PARENT_CHECK_S = 1.0
#: seconds :meth:`BesideTracks.close` waits for a child to end before it stops it
_CLOSE_WAIT_S = 5.0


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - systems without affinity
        return max(1, os.cpu_count() or 1)


class RemoteTrack:
    """A track beside running in a child process, as this process knows it: its pose after
    the last frame (``q``, the child tracker's own :attr:`Tracker.q`) and its name."""

    def __init__(self, index: int, q: np.ndarray):
        self.index = index  # the track's number (1: the first beside the tracker's own)
        self.q = q.copy()

    @property
    def name(self) -> str:
        return track_name(self.index)


def _serve(conn, trackers: list[Tracker], parent: int, inherited: list) -> None:
    """A child's loop: each message ``(what, args)`` done on every one of ``trackers`` in
    order, answered ``("ok", results, poses)`` or ``("error", exception)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle (blocked until here)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the command line's handler: SIGTERM ends the child quietly
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    for c in inherited:  # the parent's pipe ends, forked along (this one's too): not this child's to hold
        c.close()
    while True:
        if not conn.poll(_PARENT_CHECK_S):
            if os.getppid() != parent:  # the parent ended without closing this child
                return
            continue
        try:
            what, args = conn.recv()
        except (EOFError, OSError):
            return
        if what == "close":
            return
        try:
            out = [getattr(t, what)(*args) for t in trackers]
            conn.send(("ok", out, [t.q for t in trackers]))
        except BaseException as err:  # noqa: BLE001 - every error goes back to the parent
            conn.send(("error", _sendable(err)))


def _sendable(err: BaseException) -> BaseException:
    """``err`` if it survives pickling, else a RuntimeError that says what it was."""
    try:
        pickle.loads(pickle.dumps(err))
        return err
    except Exception:  # noqa: BLE001 - any pickling failure
        return RuntimeError(f"{type(err).__name__}: {err}")


class _Child:
    """One child process and the tracks it runs (their numbers and stand-ins)."""

    def __init__(self, ctx, trackers: list[Tracker], tracks: list[int], inherited: list):
        self.tracks = tracks
        self.remote = [RemoteTrack(i, t.q) for i, t in zip(tracks, trackers)]
        self.conn, theirs = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(theirs, trackers, os.getpid(), [*inherited, self.conn]),
                                   name=f"kms2pin {', '.join(track_name(i) for i in tracks)}", daemon=True)
        # the child's mask: no Ctrl-C or SIGTERM until it has set its own handlers
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        theirs.close()  # the child's end lives in the child only: its end closing is seen here

    def send(self, what: str, args: tuple) -> None:
        try:
            self.conn.send((what, args))
        except (BrokenPipeError, EOFError, OSError) as err:
            raise self._ended() from err

    def receive(self) -> tuple[list | None, BaseException | None]:
        """The child's answer to the last message: each of its tracks' result, or the error
        it raised (the child still in step); a child that cannot answer raises."""
        try:
            answer = self.conn.recv()
        except (EOFError, OSError) as err:
            raise self._ended() from err
        if answer[0] == "error":
            return None, answer[1]
        _, out, poses = answer
        for r, q in zip(self.remote, poses):
            r.q = q
        return out, None

    def _ended(self) -> ChildProcessError:
        self.process.join(0.1)
        code = self.process.exitcode
        how = "is still running" if code is None else (f"was killed by signal {-code}" if code < 0 else
                                                        f"ended with exit status {code}")
        return ChildProcessError(f"the process that tracks {', '.join(track_name(i) for i in self.tracks)} "
                                 f"(pid {self.process.pid}) {how}: the tracks beside cannot go on (run with jobs=1, "
                                 "--jobs 1, to track them in one process)")

    def close(self) -> None:
        try:
            self.conn.send(("close", ()))
        except (BrokenPipeError, EOFError, OSError):
            pass
        self.process.join(_CLOSE_WAIT_S)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(_CLOSE_WAIT_S)
        self.conn.close()


def _close_all(children: list[_Child]) -> None:
    for c in children:
        c.close()
    children.clear()


class BesideTracks:
    """The tracks beside a tracker (``trackers``, in order), run in ``jobs`` processes
    (this one and ``jobs - 1`` children; at most one per track; module docstring)."""

    def __init__(self, trackers: Sequence[Tracker], jobs: int = 1):
        if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
            raise OptionError(f"jobs must be a whole number of processes, at least 1, not {jobs!r}")
        jobs = min(int(jobs), len(trackers) + 1) if FORK else 1
        self.jobs = jobs
        # track i (1-based beside the tracker's own, track 0) runs in process i % jobs
        self._here = [(i, t) for i, t in enumerate(trackers, 1) if i % jobs == 0]
        self._children: list[_Child] = []
        ctx = mp.get_context("fork") if jobs > 1 else None
        for p in range(1, jobs):
            mine = [(i, t) for i, t in enumerate(trackers, 1) if i % jobs == p]
            inherited = [c.conn for c in self._children]
            self._children.append(_Child(ctx, [t for _, t in mine], [i for i, _ in mine], inherited))
        self._finalizer = weakref.finalize(self, _close_all, self._children)
        self._broken: str | None = None  # why the tracks beside cannot go on
        order = {i: t for i, t in self._here} | {i: r for c in self._children for i, r in zip(c.tracks, c.remote)}
        #: each track beside as this process sees it: the Tracker, or a RemoteTrack
        self.tracks: tuple[Any, ...] = tuple(order[i] for i in sorted(order))

    def __len__(self) -> int:
        return len(self.tracks)

    def _each(self, what: str, args: tuple, own: Callable[[], Any] | None = None) -> tuple[Any, list]:
        """``what(*args)`` on every track beside, and ``own()`` (this process's track) while
        the children work; returns own's result and the tracks' in track order.  An error
        anywhere is raised once every child has answered (the tracks stay in step)."""
        self.check()
        try:
            for c in self._children:
                c.send(what, args)
        except BaseException as err:  # noqa: BLE001 - some children have the message, some not: out of step
            self._break(err)
            raise
        out: dict[int, Any] = {}
        first: BaseException | None = None
        mine = None
        try:
            for i, t in self._here:
                out[i] = getattr(t, what)(*args)
            mine = own() if own is not None else None
        except BaseException as err:  # noqa: BLE001 - raised below, after the children answer
            first = err
        for c in self._children:
            try:
                theirs, error = c.receive()
            except BaseException as err:  # noqa: BLE001 - an answer unread (Ctrl-C here, a child ended): out of step
                self._break(err)
                raise
            if error is not None:
                first = first or error
            else:
                out.update(zip(c.tracks, theirs))
        if first is not None:
            raise first
        return mine, [out[i] for i in sorted(out)]

    def check(self) -> None:
        """Raise RuntimeError if the tracks beside cannot go on (closed, or out of step)."""
        if self._broken is not None:
            raise RuntimeError(self._broken)

    def _break(self, err: BaseException) -> None:
        """End the children after ``err`` left them out of step with this process."""
        self.close()
        self._broken = (f"the tracks beside were left out of step by {type(err).__name__} ({err}) and their "
                        "processes ended: make a new Tracker to go on")

    def step(self, masks, source: str, own: Callable[[], FrameResult]) -> tuple[FrameResult, list[FrameResult]]:
        """One frame on every track beside (:meth:`Tracker.step`) and on the tracker's own
        (``own``): its result and theirs."""
        return self._each("step", (masks, source), own)

    def calibrate(self, masks, source: str, q) -> None:
        """:meth:`Tracker.calibrate` on every track beside."""
        self._each("calibrate", (masks, source, q))

    def restart(self, q0) -> None:
        """:meth:`Tracker.restart` on every track beside."""
        self._each("restart", (q0,))

    def close(self) -> None:
        """End the children (the tracks beside they ran can no longer step)."""
        if self._children and self._broken is None:
            self._broken = "the tracker's processes were closed (Tracker.close): its tracks beside cannot go on"
        self._finalizer()
