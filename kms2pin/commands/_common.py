"""Helpers shared by sub-commands."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from ..lang import parse_text, read_spec
from ..model import ModelSpec


def _number(text: str, kind: type) -> float | int:
    try:
        value = kind(text)
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None
    return value


def count(text: str) -> int:
    """argparse type: a whole number >= 0."""
    value = _number(text, int)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got '{text}'")
    return value


def positive_count(text: str) -> int:
    """argparse type: a whole number >= 1."""
    value = _number(text, int)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got '{text}'")
    return value


def non_negative(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = _number(text, float)
    if not 0.0 <= value < float("inf"):  # also rejects nan
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got '{text}'")
    return value


def positive(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _number(text, float)
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number > 0, got '{text}'")
    return value


def in_range(lo: float, hi: float, hi_open: bool = False, lo_open: bool = False):
    """argparse type: a number in [lo, hi] (brackets open as asked)."""

    def parse(text: str) -> float:
        value = _number(text, float)
        ok = (lo < value if lo_open else lo <= value) and (value < hi if hi_open else value <= hi)
        if not ok:
            interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
            raise argparse.ArgumentTypeError(f"expected a number in {interval}, got '{text}'")
        return value

    return parse


class Once(argparse.Action):
    """argparse action: the option may be given once (a second value is a usage error,
    not silently the one that counts)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest, None) not in (None, self.default):
            parser.error(f"argument {option_string}: given twice ({getattr(namespace, self.dest)!r} and {values!r})")
        setattr(namespace, self.dest, values)


def add_spec_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", metavar="MODEL.kms", help="model specification file")


def read_model(path: str) -> ModelSpec:
    """Parse a spec file named on the command line (missing file -> exit 2)."""
    text, shown = read_spec(path)
    return parse_text(text, shown)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_files_atomically(files: dict[Path, str | bytes]) -> None:
    """Write every file to a temporary sibling first, then rename all of them,
    so an error leaves no half-written output."""
    staged: list[tuple[str, Path]] = []
    try:
        for path, content in files.items():
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
            with os.fdopen(fd, "wb") as f:
                f.write(content.encode() if isinstance(content, str) else content)
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give what open() would
            staged.append((tmp, path))
        for tmp, path in staged:
            os.replace(tmp, path)
    finally:
        for tmp, _ in staged:
            if os.path.exists(tmp):
                os.unlink(tmp)


def write_outputs(files: dict[Path, str | bytes], out: Path) -> None:
    """Write ``files`` atomically (all or nothing) and print their paths."""
    from ..errors import ExportError

    try:
        write_files_atomically(files)
    except OSError as err:
        raise ExportError(f"cannot write to {out}: {err.strerror or err}") from None
    for path in files:
        print(os.fspath(path))
