"""The tracker's options on the command line, built from :mod:`kms2pin.ecm.options`.

Each option that ``kms2pin track`` offers declares its flag in its field's metadata
(:class:`kms2pin.ecm.options.Cli`); this module turns those fields into argparse
arguments and the parsed arguments back into :class:`TrackerOptions`.
"""

from __future__ import annotations

import argparse
import dataclasses

from ..ecm.options import Preset, TrackerOptions, as_options, cli_dest, cli_fields, cli_number_range, is_switch
from ..errors import OptionError, UsageError
from ._common import number

__all__ = ["add_tracker_arguments", "tracker_options"]


def _default_words(f: dataclasses.Field) -> str:
    if f.metadata.get("tristate") and f.default is None:
        return ""
    return f" (default {f.default:g})" if isinstance(f.default, float) else f" (default {f.default})"


def add_tracker_arguments(p: argparse.ArgumentParser) -> None:
    """One argument per option with a flag; each defaults to None (not given)."""
    for f in cli_fields():
        cli = f.metadata["cli"]
        help_text = f.metadata["help"]
        if is_switch(f):
            off = cli.flag.startswith("--no-")
            p.add_argument(cli.flag, dest=cli_dest(f), action="store_const", const=not off, default=None,
                           help=("turn off: " if off else "") + help_text)
        elif f.metadata.get("choices") is not None:
            p.add_argument(cli.flag, dest=cli_dest(f), choices=f.metadata["choices"], default=None,
                           help=help_text + _default_words(f))
        elif isinstance(f.default, tuple):
            p.add_argument(cli.flag, dest=cli_dest(f), type=float, nargs=len(f.default), default=None,
                           metavar=tuple("XYZW"[: len(f.default)]),
                           help=f"{help_text} (default {' '.join(f'{x:g}' for x in f.default)})")
        else:
            lo, open_lo, whole = cli_number_range(f)
            rng = f.metadata["range"]
            hi = float("inf") if rng.hi is None else rng.hi
            none = f" ({cli.none:g}: None)" if cli.none is not None else ""
            p.add_argument(cli.flag, dest=cli_dest(f), type=number(lo, hi, whole=whole, lo_open=open_lo),
                           default=None, metavar=cli.metavar, help=help_text + none + _default_words(f))


def tracker_options(args: argparse.Namespace, base: TrackerOptions | Preset | None = None,
                    **fixed) -> TrackerOptions:
    """``base`` with the options given on the command line, then ``fixed`` (set by the
    command itself).  A value the options refuse is a :class:`UsageError` naming its flag."""
    overrides = {}
    for f in cli_fields():
        value = getattr(args, cli_dest(f), None)
        if value is None:
            continue
        if is_switch(f):
            value = bool(value)
        elif isinstance(f.default, tuple):
            value = tuple(value)
        elif f.metadata["cli"].none is not None and value == f.metadata["cli"].none:
            value = None
        try:
            TrackerOptions().replace(**{f.name: value})
        except OptionError as err:
            raise UsageError(f"{f.metadata['cli'].flag}: {err}") from None
        overrides[f.name] = value
    return as_options(base, {**overrides, **fixed})
