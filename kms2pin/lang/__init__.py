"""The model language: Lark grammar, parser (text -> AST) and semantics (AST -> model)."""

from __future__ import annotations

import os

from ..errors import Diagnostic, SpecError
from ..model import ModelSpec
from ..userfile import MAX_SPEC_BYTES, read_user_file
from .parser import parse_text as _parse_ast
from .semantics import analyze


def parse_text(text: str, path: str = "<string>") -> ModelSpec:
    """Compile spec text; ``path`` is only used in messages."""
    return analyze(_parse_ast(text, path), text, path)


def read_spec(path: str | os.PathLike) -> tuple[str, str]:
    """Read a spec file as UTF-8 text; returns (text, path as given).  The file must be
    a regular file of at most :data:`~kms2pin.userfile.MAX_SPEC_BYTES` (else OSError,
    see :func:`~kms2pin.userfile.read_user_file`)."""
    shown = os.fspath(path)
    data = read_user_file(path, MAX_SPEC_BYTES)
    try:
        return data.decode("utf-8"), shown
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        col = err.start - (data.rfind(b"\n", 0, err.start) + 1) + 1
        raise SpecError([Diagnostic(shown, line, col, "the file is not UTF-8 text")]) from None


def looks_like_path(spec: str | os.PathLike) -> bool:
    """True for path objects and for one-line strings naming a .kms file or an existing file."""
    if isinstance(spec, os.PathLike):
        return True
    return "\n" not in spec and "{" not in spec and (spec.endswith(".kms") or os.path.isfile(spec))


def parse(spec: str | os.PathLike) -> ModelSpec:
    """Compile a spec given as a path (``Path`` or ``"x.kms"``) or as text."""
    if looks_like_path(spec):
        text, shown = read_spec(spec)
        return parse_text(text, shown)
    return parse_text(str(spec))


__all__ = ["looks_like_path", "parse", "parse_text", "read_spec"]
