"""Reading a user's JSON file with one set of error messages."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def read_json(path: str | os.PathLike, error_cls: type[Exception], *, cannot_read: str | None = None) -> Any:
    """The JSON value in the UTF-8 file ``path``.

    Raises ``error_cls`` with ``"PATH: not a text (JSON) file"`` if the file is not
    UTF-8 text and ``"PATH:LINE:COLUMN: not valid JSON: REASON"`` if it is not JSON.
    An OSError (no such file, a folder, no permission) propagates, unless
    ``cannot_read`` is given: then it becomes ``error_cls`` with
    ``"PATH: <cannot_read>: REASON"``.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise error_cls(f"{path}: not a text (JSON) file") from None
    except OSError as e:
        if cannot_read is None:
            raise
        raise error_cls(f"{path}: {cannot_read}: {e.strerror or e}") from e
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error_cls(f"{path}:{e.lineno}:{e.colno}: not valid JSON: {e.msg}") from e
