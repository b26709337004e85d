"""Reading a user's JSON file with one set of error messages."""

from __future__ import annotations

import json
import os
from typing import Any

from .userfile import MAX_DATA_BYTES, read_user_file


def read_json(path: str | os.PathLike, error_cls: type[Exception], *, cannot_read: str | None = None) -> Any:
    """The JSON value in the UTF-8 file ``path`` (a regular file of at most
    :data:`~kms2pin.userfile.MAX_DATA_BYTES`).

    Raises ``error_cls`` with ``"PATH: not a text (JSON) file"`` if the file is not
    UTF-8 text, ``"PATH:LINE:COLUMN: not valid JSON: REASON"`` if it is not JSON and
    ``"PATH: not valid JSON: nested too deeply"`` for arrays or objects nested
    beyond Python's recursion limit.  An OSError (no such file, a folder, no
    permission, a FIFO or device, too large: :func:`~kms2pin.userfile.read_user_file`)
    propagates, unless ``cannot_read`` is given: then it becomes ``error_cls`` with
    ``"PATH: <cannot_read>: REASON"``.
    """
    try:
        text = read_user_file(path, MAX_DATA_BYTES).decode("utf-8")
    except UnicodeDecodeError:
        raise error_cls(f"{path}: not a text (JSON) file") from None
    except OSError as e:
        if cannot_read is None:
            raise
        raise error_cls(f"{path}: {cannot_read}: {e.strerror or e}") from e
    return parse_json(text, error_cls, str(path))


def parse_json(text: str, error_cls: type[Exception], where: str) -> Any:
    """``json.loads(text)``; a syntax error or too deep a nesting is ``error_cls`` naming ``where``."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error_cls(f"{where}:{e.lineno}:{e.colno}: not valid JSON: {e.msg}") from e
    except RecursionError:
        raise error_cls(f"{where}: not valid JSON: nested too deeply") from None
