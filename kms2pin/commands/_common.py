"""Helpers shared by sub-commands."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from ..lang import parse_text, read_spec
from ..model import ModelSpec


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
