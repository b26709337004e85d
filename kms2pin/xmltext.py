"""Text that is safe inside the XML kms2pin writes (URDF, SRDF, MJCF).

Every name goes through :func:`attr` and every free text (the source file's name in
the header comments) through :func:`comment`, so that no spec or file name can make
the output ill-formed or add markup to it:

- an attribute value is quoted and ``& < > "`` (and tab, newline) escaped; a character
  XML 1.0 cannot hold at all (a control character, a lone surrogate) is refused with
  an :class:`~kms2pin.errors.ExportError` (the compiler's names are identifiers, so
  only a model built by hand through the API can have one);
- a comment cannot be escaped with entities (they are not expanded there), so its text
  is percent-encoded where it would break the comment: ``%`` itself, a ``-`` after a
  ``-`` (``--`` may not appear in a comment), a final ``-``, and characters XML cannot
  hold or that would break the line (``a--b.kms`` is written ``a-%2Db.kms``; a file
  name's undecodable byte 0xFF as ``%FF``).

Numbers are written with 15 significant digits (:func:`num`, :func:`vec`), ``-0`` as ``0``.
"""

from __future__ import annotations

from collections.abc import Iterable
from xml.sax.saxutils import quoteattr

from .errors import ExportError


def xml_char(c: str) -> bool:
    """Whether XML 1.0 can hold the character ``c`` (its ``Char`` production)."""
    o = ord(c)
    return o in (0x9, 0xA, 0xD) or 0x20 <= o <= 0xD7FF or 0xE000 <= o <= 0xFFFD or 0x10000 <= o <= 0x10FFFF


def attr(value: str) -> str:
    """``value`` as a quoted XML attribute value; ExportError for a character XML cannot hold."""
    bad = [c for c in value if not xml_char(c)]
    if bad:
        raise ExportError(
            f"the name {value!r} cannot be written into XML: it holds the character U+{ord(bad[0]):04X}"
        )
    return quoteattr(value, {"\n": "&#10;", "\r": "&#13;", "\t": "&#9;"})


def _percent(c: str) -> str:
    try:
        raw = c.encode("utf-8", "surrogateescape")  # a file name's undecodable byte comes back as itself
    except UnicodeEncodeError:
        raw = c.encode("utf-8", "surrogatepass")
    return "".join(f"%{b:02X}" for b in raw)


def comment_text(text: str) -> str:
    """``text`` percent-encoded where it would break an XML comment (module docstring)."""
    out = []
    for k, c in enumerate(text):
        dash_pair = c == "-" and (k + 1 == len(text) or (k and text[k - 1] == "-"))
        if c == "%" or dash_pair or not xml_char(c) or c in "\t\n\r":
            out.append(_percent(c))
        else:
            out.append(c)
    return "".join(out)


def comment(text: str) -> str:
    """An XML comment holding ``text`` (made safe by :func:`comment_text`)."""
    return f"<!-- {comment_text(text)} -->"


def num(x: float) -> str:
    """A number as attribute text: 15 significant digits, ``-0`` written ``0``."""
    s = f"{x:.15g}"
    return "0" if s in ("-0", "0") else s


def vec(v: Iterable[float]) -> str:
    """Numbers separated by spaces (an XML list attribute such as ``xyz``)."""
    return " ".join(num(float(x)) for x in v)
