"""Helpers shared by sub-commands."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path

from ..lang import parse_text, read_spec
from ..model import ModelSpec
from ..video.segmentation import DEFAULT_METHOD, SegmentParams
from ._outputs import write_files_atomically


def number(lo: float = -math.inf, hi: float = math.inf, *, whole: bool = False, lo_open: bool = False,
           hi_open: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number (``whole``: an integer) in [lo, hi], brackets open
    as asked; the message says the range as ">= lo" when there is no upper bound."""
    word = "a whole number" if whole else "a number"
    if lo == -math.inf and hi == math.inf:
        word, bound = f"a finite {word[2:]}", ""
    elif hi == math.inf:
        bound = f" {'>' if lo_open else '>='} {lo:g}"
    else:
        bound = f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"

    def parse(text: str) -> float:
        try:
            value = int(text) if whole else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {word}, got '{text}'") from None
        above = lo < value if lo_open else lo <= value
        below = value < hi if hi_open or hi == math.inf else value <= hi  # also rejects inf and nan
        if not (above and below):
            raise argparse.ArgumentTypeError(f"expected {word}{bound}, got '{text}'")
        return value

    return parse


count = number(0, whole=True)  # a whole number >= 0
positive_count = number(1, whole=True)  # a whole number >= 1
non_negative = number(0.0)  # a finite number >= 0
positive = number(0.0, lo_open=True)  # a finite number > 0


class Once(argparse.Action):
    """argparse action: the option may be given once (a second value is a usage error,
    not silently the one that counts)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest, None) not in (None, self.default):
            parser.error(f"argument {option_string}: given twice ({getattr(namespace, self.dest)!r} and {values!r})")
        setattr(namespace, self.dest, values)


def add_spec_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", metavar="MODEL.kms", help="model specification file")


def existing_file(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path; FileNotFoundError (exit 2, "PATH: no such file") if nothing is
    there: an input file named on the command line that is missing is a usage error."""
    if not Path(path).exists():
        raise FileNotFoundError(2, "no such file", os.fspath(path))
    return Path(path)


def lighting_notes(args: argparse.Namespace, *, segmenting: bool = True) -> list[str]:
    """Notes (without the "note: " prefix) on the options of :func:`add_lighting_arguments`
    (and ``--method``) that do nothing as given.  ``segmenting``: whether the command
    segments video (``segment``; ``track --video``) - if not (``track --masks``) they all
    do nothing."""
    threshold_set = args.shadow_threshold != SegmentParams.shadow_threshold
    if not segmenting:
        if (getattr(args, "method", DEFAULT_METHOD) != DEFAULT_METHOD or args.no_shadows or threshold_set
                or args.no_gain_compensation):
            return ["--method, --no-shadows, --shadow-threshold and --no-gain-compensation set the segmentation "
                    "of --video; with --masks they do nothing"]
        return []
    if args.no_shadows and threshold_set:
        return ["--shadow-threshold sets the shadow test; with --no-shadows it does nothing"]
    return []


def read_model(path: str) -> ModelSpec:
    """Parse a spec file named on the command line (missing file -> exit 2)."""
    text, shown = read_spec(path)
    return parse_text(text, shown)


def write_outputs(files: dict[Path, str | bytes], out: Path) -> None:
    """Write ``files`` atomically (all or nothing) and print their paths."""
    from ..errors import ExportError

    try:
        write_files_atomically(files)
    except OSError as err:
        raise ExportError(f"cannot write to {out}: {err.strerror or err}") from None
    for path in files:
        print(os.fspath(path))
