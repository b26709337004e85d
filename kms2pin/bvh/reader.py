"""Reading a BVH (Biovision Hierarchy) motion-capture file: its skeleton and its motion.

The format (M. Meredith and S. Maddock, *Motion capture file formats explained*, 2001)::

    HIERARCHY
    ROOT Hips                      one skeleton (a second ROOT is refused)
    {
        OFFSET 0 0 0               the joint's point in its parent's frame (file units)
        CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
        JOINT LeftHip { OFFSET ...  CHANNELS 3 Zrotation Yrotation Xrotation  ... }
        End Site { OFFSET 0 0 1 }  the end of a bone with no joint below it
    }
    MOTION
    Frames: 994
    Frame Time: .0083333
    5.23 16.9 -33.9 -5.40 9.81 ...  one line a frame: every joint's channels, in the order
                                    the CHANNELS lines come, angles in degrees

A joint name is the rest of its ``ROOT``/``JOINT`` line up to a ``{`` (it may hold spaces).  Keywords
are read without regard to case.  Every mistake is a :class:`~kms2pin.errors.BvhError`
located at ``file:line:col``.  What the channels mean is :mod:`kms2pin.bvh.motion`'s.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BvhError, Diagnostic, did_you_mean
from ..lang.symbols import MAX_LENGTH
from ..userfile import MAX_DATA_BYTES, read_user_file

#: The six channel names of the format.
CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CHANNEL = {c.lower(): c for c in CHANNELS}
_TOKEN = re.compile(r"[{}]|[^\s{}]+")
_FRAMES = re.compile(r"\s*frames\s*:\s*(\S*)\s*$", re.I)
_FRAME_TIME = re.compile(r"\s*frame\s+time\s*:\s*(\S*)\s*$", re.I)

Point = tuple[float, float, float]


@dataclass(frozen=True)
class BvhJoint:
    """One ``ROOT`` or ``JOINT``: ``offset`` (file units) in its parent's frame, its
    channels in file order, the offsets of its ``End Site``\\ s, the line it starts on and
    the line of its ``CHANNELS``, and ``first`` its first channel's place in a frame."""

    name: str
    parent: int | None
    offset: Point
    channels: tuple[str, ...]
    end_sites: tuple[Point, ...]
    line: int
    channels_line: int
    first: int

    @property
    def rotation_order(self) -> str:
        """The axes of the rotation channels in file order, e.g. ``"ZYX"``."""
        return "".join(c[0] for c in self.channels if c.endswith("rotation"))


@dataclass(frozen=True)
class BvhFile:
    """A parsed BVH file: ``joints`` in file order (a parent before its children,
    ``joints[0]`` the root), ``frame_time`` in seconds and ``motion`` (frames, channels)
    as written (file units, degrees)."""

    path: str
    joints: tuple[BvhJoint, ...]
    frame_time: float
    motion: np.ndarray

    def channels(self, joint: BvhJoint) -> np.ndarray:
        """(frames, len(joint.channels)): the values of ``joint``'s channels."""
        return self.motion[:, joint.first : joint.first + len(joint.channels)]


def read_bvh(path: str | os.PathLike) -> BvhFile:
    """Parse the BVH file ``path`` (OSError as :func:`kms2pin.userfile.read_user_file`)."""
    data = read_user_file(path, MAX_DATA_BYTES)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return parse_bvh(text, os.fspath(path))


def parse_bvh(text: str, path: str = "<string>") -> BvhFile:
    """Parse BVH ``text`` (``path`` names it in messages)."""
    lines = text.splitlines()
    motion_at = next((k for k, line in enumerate(lines) if line.split()[:1] and line.split()[0].upper() == "MOTION"),
                     len(lines))
    joints = _Hierarchy(path, lines, motion_at).parse()
    if motion_at == len(lines):
        raise _error(path, lines, len(lines), 1, "no MOTION section after the hierarchy")
    frame_time, motion = _motion(path, lines, motion_at, joints)
    return BvhFile(path, joints, frame_time, motion)


def _error(path: str, lines: list[str], line: int, column: int, message: str) -> BvhError:
    line = max(line, 1)
    source = lines[line - 1] if line <= len(lines) else ""
    return BvhError(Diagnostic(path, line, column, message, source).format())


class _Hierarchy:
    """The HIERARCHY section, token by token (lines ``[0, end)``); a stack, not recursion."""

    def __init__(self, path: str, lines: list[str], end: int):
        self.path, self.lines = path, lines
        self.tokens = [(n, m.start() + 1, m.group()) for n in range(1, end + 1) for m in _TOKEN.finditer(lines[n - 1])]
        self.at = 0
        self.motion = end < len(lines)
        self.end_line = end + 1 if self.motion else max(len(lines), 1)
        self.joints: list[dict] = []
        self.channel_count = 0

    def error(self, token, message: str) -> BvhError:
        line, col = (token[0], token[1]) if token else (self.end_line, 1)
        return _error(self.path, self.lines, line, col, message)

    def next(self, what: str):
        if self.at == len(self.tokens):
            where = "before MOTION" if self.motion else "at the end of the file"
            raise self.error(None, f"expected {what}, but the hierarchy ends {where}")
        self.at += 1
        return self.tokens[self.at - 1]

    def parse(self) -> tuple[BvhJoint, ...]:
        head = self.next("HIERARCHY")
        if head[2].upper() != "HIERARCHY":
            raise self.error(head, f"expected HIERARCHY at the start of a BVH file, found '{head[2]}'")
        token = self.next("ROOT")
        if token[2].upper() != "ROOT":
            raise self.error(token, f"expected ROOT, found '{token[2]}'")
        stack = [self.open_joint(token, None)]
        while stack:
            token = self.next("'}'" if stack[-1]["kind"] == "end" else "OFFSET, CHANNELS, JOINT, End Site or '}'")
            word = token[2].upper()
            block = stack[-1]
            if word == "}":
                self.close(block)
                stack.pop()
            elif word == "OFFSET":
                self.once(block, "offset", token)
                block["offset"] = tuple(self.number(f"a number ({axis} of OFFSET)") for axis in "xyz")
            elif word == "CHANNELS" and block["kind"] == "joint":
                self.once(block, "channels", token)
                block["channels"] = self.channels(token)
                block["first"] = self.channel_count  # frames list the channels in the order of these lines
                self.channel_count += len(block["channels"][0])
            elif word == "JOINT" and block["kind"] == "joint":
                stack.append(self.open_joint(token, block["index"]))
            elif word == "END" and block["kind"] == "joint":
                site = self.next("Site")
                if site[2].upper() != "SITE":
                    raise self.error(site, f"expected 'Site' after 'End', found '{site[2]}'")
                self.brace()
                stack.append({"kind": "end", "line": token[0], "offset": None, "owner": block})
            else:
                expected = "OFFSET or '}' in an End Site" if block["kind"] == "end" else \
                    "OFFSET, CHANNELS, JOINT, End Site or '}'"
                raise self.error(token, f"expected {expected}, found '{token[2]}'")
        if self.at < len(self.tokens):
            token = self.tokens[self.at]
            if token[2].upper() == "ROOT":
                roots = [n for n, _, t in self.tokens if t.upper() == "ROOT"]
                raise self.error(token, f"a second ROOT: this file holds {len(roots)} skeletons (ROOT at lines "
                                 f"{', '.join(map(str, roots))}); kms2pin imports one, so split the file")
            raise self.error(token, f"expected MOTION after the root's closing '}}', found '{token[2]}'")
        return tuple(self.freeze(j) for j in self.joints)

    def open_joint(self, token, parent: int | None) -> dict:
        line = self.lines[token[0] - 1]
        name = line[token[1] - 1 + len(token[2]):].split("{", 1)[0].strip()
        while self.at < len(self.tokens) and self.tokens[self.at][0] == token[0] and self.tokens[self.at][2] != "{":
            self.at += 1  # the words of the name
        kind = "ROOT" if parent is None else "JOINT"
        if not name:
            raise self.error(token, f"{kind} needs a name")
        for j in self.joints:
            if j["name"] == name:
                raise self.error(token, f"a second joint named '{name}' (the first is at line {j['line']})")
        self.brace()
        block = {"kind": "joint", "name": name, "parent": parent, "line": token[0], "offset": None,
                 "channels": None, "ends": [], "index": len(self.joints)}
        self.joints.append(block)
        return block

    def brace(self) -> None:
        token = self.next("'{'")
        if token[2] != "{":
            raise self.error(token, f"expected '{{', found '{token[2]}'")

    def once(self, block: dict, field: str, token) -> None:
        if block[field] is not None:
            raise self.error(token, f"a second {token[2].upper()} in one block")

    def number(self, what: str) -> float:
        token = self.next(what)
        try:
            value = float(token[2])
        except ValueError:
            raise self.error(token, f"expected {what}, found '{token[2]}'") from None
        if not np.isfinite(value):
            raise self.error(token, f"expected {what}, found '{token[2]}' (not finite)")
        if abs(value) > MAX_LENGTH:
            raise self.error(token, f"expected {what}, found '{token[2]}', beyond +-{MAX_LENGTH:g}, the largest "
                                    "value kms2pin takes (file units)")
        return value

    def channels(self, keyword) -> tuple[tuple[str, ...], int]:
        token = self.next("the number of channels")
        if not token[2].isdigit() or int(token[2]) > 6:
            raise self.error(token, f"CHANNELS takes a channel count from 0 to 6, found '{token[2]}'")
        n = int(token[2])
        names: list[str] = []
        for k in range(n):
            token = self.next(f"channel {k + 1} of {n}")
            name = _CHANNEL.get(token[2].lower())
            if name is None and (token[2] in "{}" or token[2].upper() in ("JOINT", "END", "OFFSET", "CHANNELS")):
                raise self.error(token, f"CHANNELS {n} lists {k} channel(s) before '{token[2]}'")
            if name is None:
                raise self.error(token, f"'{token[2]}' is not a channel{did_you_mean(token[2], CHANNELS)}; the "
                                 f"channels are {', '.join(CHANNELS)}")
            if name in names:
                raise self.error(token, f"channel {name} is listed twice")
            names.append(name)
        return tuple(names), keyword[0]

    def close(self, block: dict) -> None:
        if block["offset"] is None:
            what = "this End Site" if block["kind"] == "end" else f"joint '{block['name']}'"
            raise self.error((block["line"], 1, ""), f"{what} has no OFFSET")
        if block["kind"] == "end":
            block["owner"]["ends"].append(block["offset"])
            return
        if block["channels"] is None:
            raise self.error((block["line"], 1, ""), f"joint '{block['name']}' has no CHANNELS line "
                             "(CHANNELS 0 for a joint that does not move)")

    @staticmethod
    def freeze(j: dict) -> BvhJoint:
        names, line = j["channels"]
        return BvhJoint(j["name"], j["parent"], j["offset"], names, tuple(j["ends"]), j["line"], line, j["first"])


def _motion(path: str, lines: list[str], at: int, joints: tuple[BvhJoint, ...]) -> tuple[float, np.ndarray]:
    """Frame time and (frames, channels) values of the MOTION section starting at line ``at`` (0-based)."""
    rest = [(n, lines[n - 1]) for n in range(at + 2, len(lines) + 1) if lines[n - 1].strip()]
    if len(rest) < 2:
        raise _error(path, lines, len(lines), 1, "the MOTION section needs 'Frames: N' and 'Frame Time: T'")
    (nf, frames_line), (nt, time_line) = rest[0], rest[1]
    m = _FRAMES.match(frames_line)
    if not m or not m[1].isdigit():
        raise _error(path, lines, nf, 1, "expected 'Frames: N' (a whole number of frames)")
    frames = int(m[1])
    if frames == 0:
        raise _error(path, lines, nf, 1, "'Frames: 0': the file holds no motion (at least one frame is needed)")
    m = _FRAME_TIME.match(time_line)
    try:
        frame_time = float(m[1]) if m else None
    except ValueError:
        frame_time = None
    if frame_time is None or not 0 < frame_time < np.inf:
        raise _error(path, lines, nt, 1, "expected 'Frame Time: T' (seconds a frame, a number above 0)")
    n = sum(len(j.channels) for j in joints)
    rows = rest[2:]
    if len(rows) < frames:
        last = rows[-1][0] if rows else nt
        raise _error(path, lines, last, 1, f"the motion ends after {len(rows)} of the {frames} frames that "
                     f"'Frames:' (line {nf}) declares: the file is truncated")
    if len(rows) > frames:
        raise _error(path, lines, rows[frames][0], 1, f"more frame lines than the {frames} that 'Frames:' "
                     f"(line {nf}) declares")
    motion = np.empty((frames, n))
    for k, (line, text) in enumerate(rows):
        values = text.split()
        if len(values) != n:
            raise _error(path, lines, line, 1, f"frame {k} has {len(values)} values, but the hierarchy's joints "
                         f"have {n} channels")
        try:
            motion[k] = np.array(values, dtype=float)
        except ValueError:
            motion[k] = np.nan
        if not np.isfinite(motion[k]).all() or (np.abs(motion[k]) > MAX_LENGTH).any():
            _bad_value(path, lines, line, k, joints, motion[k])
    return frame_time, motion


def _bad_value(path: str, lines: list[str], line: int, frame: int, joints, row: np.ndarray):
    """Raise the error for the first value of ``row`` (frame ``frame`` at ``line``) that is not a finite number,
    or is beyond +-MAX_LENGTH."""
    tokens = list(_TOKEN.finditer(lines[line - 1]))
    for c, token in enumerate(tokens):
        try:
            value = float(token.group())
        except ValueError:
            value = np.nan
        if not np.isfinite(value) or abs(value) > MAX_LENGTH:
            joint = next(j for j in joints if j.first <= c < j.first + len(j.channels))
            channel = f"{joint.name} {joint.channels[c - joint.first]}"
            what = "is not a finite number" if not np.isfinite(value) else \
                f"is beyond +-{MAX_LENGTH:g}, the largest value kms2pin takes"
            raise _error(path, lines, line, token.start() + 1, f"frame {frame}, channel {c + 1} ({channel}): "
                                                               f"'{token.group()}' {what}")
    raise AssertionError("a row without a bad value")  # pragma: no cover
