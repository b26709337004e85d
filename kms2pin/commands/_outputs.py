"""Output folders that one run owns, files written whole, and SIGTERM handled as Ctrl-C.

- :func:`owns_output` (a decorator of a command's ``run``) holds ``OUT/.kms2pin.lock``
  for the whole run: an exclusive ``flock`` on a file that names the run (PID and
  command).  A second run into the same folder is refused while the first is alive;
  the kernel drops the lock when its process dies, however it dies, so a lock file
  left by a killed run is taken over, with a note naming that run.
- :func:`replaced` and :func:`write_files_atomically` write to a temporary name in
  the same folder and rename, so a reader (or a run killed half way) never sees half
  a file.  Files that grow a frame at a time (``trajectory.csv``, masks) are not
  written this way.
- :func:`sigterm_as_interrupt`: SIGTERM (what ``timeout``, systemd and schedulers
  send) raises :class:`Terminated`, a KeyboardInterrupt, where Ctrl-C would raise
  one, so the same clean-up runs; the command line exits with status 143 for it
  (130 for Ctrl-C).  :func:`interrupts_deferred` holds both back for a block that
  must finish (a frame written to every output).
"""

from __future__ import annotations

import errno
import fcntl
import functools
import os
import re
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError, UsageError

LOCK_NAME = ".kms2pin.lock"
_TEMPORARY = re.compile(r"^\.[^/]+\.tmp(\.\w+)?$")  # what _temporary and track's overlay name


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM (raised like Ctrl-C's KeyboardInterrupt)."""


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, the first SIGTERM raises :class:`Terminated` (later ones are
    ignored while the run cleans up).  Only in the main thread; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Within the block, Ctrl-C and SIGTERM wait: the KeyboardInterrupt (or
    :class:`Terminated`) is raised when the block ends, so that what the block writes
    is written whole (one frame into every output).  A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            if signal.SIGTERM in caught:
                signal.signal(signal.SIGTERM, signal.SIG_IGN)  # as sigterm_as_interrupt does
                raise Terminated
            raise KeyboardInterrupt


def _holder(fd: int) -> str:
    """What the lock file says of the run that wrote it ("kms2pin track, PID 123"), or ""."""
    os.lseek(fd, 0, os.SEEK_SET)
    words = os.read(fd, 200).decode("utf-8", "replace").split()
    if len(words) >= 2 and words[0].isdigit():
        return f"kms2pin {words[1]}, PID {words[0]}"
    return ""


def _lock(path: Path) -> tuple[int, str]:
    """An exclusive lock on ``path`` (created if missing): (fd, the run named in it
    before, if any).  Raises OutputError if a live process holds it."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd) or "another kms2pin run"
            os.close(fd)
            raise OutputError(f"{path.parent}: {holder} is writing to this folder; wait for it to end or choose "
                              "another output folder") from None
        except OSError as err:
            if err.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                os.close(fd)
                raise
            print(f"note: {path.parent}: this file system does not lock files ({err.strerror}); a second run "
                  "into this folder will not be refused", file=sys.stderr)
            return fd, ""
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:  # not a file that its last owner unlinked between our open and our lock
            return fd, _holder(fd)
        os.close(fd)


@contextmanager
def owned_output(out: str | os.PathLike, command: str) -> Iterator[Path]:
    """Hold ``out``'s lock (module docstring) for the block; ``out`` is created if
    missing, and removed again at the end (with the parents this run made) if it is
    left empty, so a run that fails before writing leaves nothing behind."""
    out = Path(out)
    top = next((p for p in (out, *out.parents) if p.exists()), None)
    created = [p for p in (out, *out.parents) if p != top and not p.exists()]  # the folders this run makes
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, before = _lock(out / LOCK_NAME)
    except OSError as err:
        raise OutputError(f"cannot write to {out}: {err.strerror or err}") from None
    try:
        if before:
            stale = [p for p in out.iterdir() if _TEMPORARY.match(p.name)]
            for p in stale:
                p.unlink()
            removed = f"; removed its {len(stale)} temporary file(s)" if stale else ""
            print(f"note: {out}: taking over the lock of {before}, which is no longer running (its outputs "
                  f"there may be incomplete{removed})", file=sys.stderr)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {command}\n".encode(), 0)
        yield out
    finally:
        try:
            os.unlink(out / LOCK_NAME)  # still locked: no other run can be using this file
        except FileNotFoundError:
            pass
        os.close(fd)
        for folder in created:  # innermost first: what this run made and left empty (it failed early)
            try:
                folder.rmdir()
            except OSError as err:
                if err.errno in (errno.ENOTEMPTY, errno.EEXIST):
                    break
                if err.errno != errno.ENOENT:
                    raise


def owns_output(run: Callable) -> Callable:
    """Decorate a command's ``run(args)`` to hold ``args.output`` (:func:`owned_output`) while it runs."""

    @functools.wraps(run)
    def wrapper(args):
        if not str(args.output).strip():  # Path("") is the current folder: never what was meant
            raise UsageError("-o/--output: the output path is empty; give a folder ('.' for this one)")
        with owned_output(args.output, getattr(args, "command", None) or run.__module__.rsplit(".", 1)[-1]):
            return run(args)

    return wrapper


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _temporary(path: Path) -> str:
    """A new empty file beside ``path`` with its suffix (np.savez and VideoWriter go by it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give what open() would
    return tmp


@contextmanager
def replaced(path: str | os.PathLike) -> Iterator[Path]:
    """``with replaced(p) as tmp: write(tmp)`` - the block writes ``tmp``, a temporary
    file beside ``p`` with its suffix, which then replaces ``p`` in one rename (or is
    deleted if the block raises)."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_files_atomically(files: dict[Path, str | bytes]) -> None:
    """Write every file to a temporary sibling first, then rename all of them,
    so an error leaves no half-written output."""
    staged: list[tuple[str, Path]] = []
    try:
        for path, content in files.items():
            tmp = _temporary(path)
            staged.append((tmp, path))
            with open(tmp, "wb") as f:
                f.write(content.encode() if isinstance(content, str) else content)
        for tmp, path in staged:
            os.replace(tmp, path)
    finally:
        for tmp, _ in staged:
            if os.path.exists(tmp):
                os.unlink(tmp)
