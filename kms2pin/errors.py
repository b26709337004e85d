"""One error root for the package, with one subclass per pipeline layer.

Every error a user can cause by their input derives from :class:`Kms2pinError`.
Spec errors carry a list of located :class:`Diagnostic` records so that the
command line can report every mistake of a file in one run, compiler-style::

    fullbody.kms:171:50: error: body 'leftThigh' has no bound vector 'kne' (did you mean 'knee'?)
            constraint revolute(leftShin.knee, leftThigh.kne, 2*postureDelta);
                                                         ^
"""

from __future__ import annotations

import difflib
import re
import unicodedata
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

SHOWN_LINE = 100  # characters of a source line shown around the caret
SHOWN_NAME = 60  # characters of a quoted name shown in a message
# a quoted name has no white space: two apostrophes of possessives ("the root's ... the
# spec's") do not quote one
_QUOTED = re.compile(r"'([^'\s]{" + str(SHOWN_NAME + 1) + r",})'")


def _shown(char: str) -> str:
    """A control or format character (an escape sequence's ESC, a bell, a text-direction
    override) as one harmless character, so that a source line echoed to a terminal cannot
    drive it and the caret stays under its column: ASCII controls as their Unicode control
    pictures, the others as U+FFFD."""
    code = ord(char)
    if code < 0x20:
        return chr(0x2400 + code)
    if code == 0x7F:
        return "\u2421"
    return "\ufffd" if unicodedata.category(char) in ("Cc", "Cf") else char


def excerpt(line: str, column: int) -> tuple[str, int]:
    """``line`` (tabs expanded to 4; control and format characters shown harmlessly) cut to about
    :data:`SHOWN_LINE` characters around the 1-based ``column``, with ``...`` where it was cut, and
    the caret's 0-based offset in it."""
    at = len(line[: max(column, 1) - 1].expandtabs(4))
    text = "".join(map(_shown, line.expandtabs(4)))
    if len(text) <= SHOWN_LINE:
        return text, at
    start = min(max(at - SHOWN_LINE // 2, 0), len(text) - SHOWN_LINE)
    cut = text[start : start + SHOWN_LINE]
    if start > 0:
        cut, at = "..." + cut, at - start + 3
    if start + SHOWN_LINE < len(text):
        cut += "..."
    return cut, at


def shorten_quoted(message: str) -> str:
    """``message`` with every quoted name longer than :data:`SHOWN_NAME` characters cut in its middle."""
    half = SHOWN_NAME // 2
    return _QUOTED.sub(lambda m: f"'{m[1][:half]}...{m[1][-half:]}'", message)


class Kms2pinError(Exception):
    """Root of every error kms2pin raises for a user's mistake."""


class UsageError(Exception):
    """A command was called wrongly (exit status 2), e.g. a bad option value."""


@dataclass(frozen=True)
class Diagnostic:
    """One located message about a spec file (1-based line and column)."""

    path: str
    line: int
    column: int
    message: str
    source_line: str = ""
    severity: str = "error"

    def format(self) -> str:
        head = "".join(map(_shown, f"{self.path}:{self.line}:{self.column}: {self.severity}: "
                                   f"{shorten_quoted(self.message)}"))
        if not self.source_line:
            return head
        text, at = excerpt(self.source_line.rstrip("\n"), self.column)
        return f"{head}\n    {text}\n    {' ' * at}^"


class SpecError(Kms2pinError):
    """A model spec (``.kms``) is malformed: syntax, names, types or kinematics."""

    def __init__(self, diagnostics: Sequence[Diagnostic]):
        self.diagnostics = tuple(diagnostics)
        super().__init__(self.format())

    def format(self) -> str:
        return "\n".join(d.format() for d in self.diagnostics)

    @property
    def first(self) -> Diagnostic:
        return self.diagnostics[0]


class ExportError(Kms2pinError):
    """Writing URDF/SRDF/meshes failed (e.g. the output directory is not writable)."""


class OutputError(Kms2pinError):
    """An output folder cannot be used: another run is writing to it, or it cannot be created."""


class RobotError(Kms2pinError, ValueError):
    """A request to a loaded robot names something it does not have, or passes a
    configuration it cannot use (wrong shape, not finite, a zero root quaternion)."""


class TargetError(Kms2pinError, ValueError):
    """Static-update targets are malformed (NaN, not unit quaternions, wrong shape)."""


class CameraError(Kms2pinError):
    """A camera description is invalid (file, field and reason in the message)."""


class OptionError(Kms2pinError, ValueError):
    """An option of the tracker is out of range or of the wrong type (name, value and range in the message)."""


class InputDataError(Kms2pinError):
    """Images, masks or videos cannot be used (file and frame in the message)."""


class BvhError(Kms2pinError):
    """A BVH motion-capture file cannot be read (``file:line:col`` in the message), its
    skeleton cannot be modelled, or a model cannot be written as BVH."""


def did_you_mean(name: str, candidates: Iterable[str]) -> str:
    """Return `` (did you mean 'x'?)`` for the closest candidate, or ``""`` (also for a
    ``name`` that is not a string)."""
    if not isinstance(name, str):
        return ""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""
