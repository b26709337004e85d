"""The tracker's options on the command line, built from :mod:`kms2pin.ecm.options`.

Each option that ``kms2pin track`` offers declares its flag in its field's metadata
(:class:`kms2pin.ecm.options.Cli`); this module turns those fields into argparse
arguments and the parsed arguments back into :class:`TrackerOptions`.
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex

from ..ecm.options import (
    PEOPLE,
    PEOPLE_ONE_CAMERA,
    PEOPLE_TRACKS,
    SEGMENTED_MASKS,
    Preset,
    TrackerOptions,
    as_options,
    cli_dest,
    cli_fields,
    cli_number_range,
    is_switch,
)
from ..errors import OptionError, UsageError
from ._common import number

__all__ = ["PRESETS", "add_tracker_arguments", "tracker_options"]

#: ``--preset``'s names for the presets of :mod:`kms2pin.ecm.options` (docs/tracking.md)
PRESETS = {"people": PEOPLE, "people-tracks": PEOPLE_TRACKS, "people-one-camera": PEOPLE_ONE_CAMERA,
           "segmented-masks": SEGMENTED_MASKS}


def preset_flags(preset: Preset) -> str:
    """A preset as the flags that give the same options (``--prediction learnt --reach-search``),
    quoted for a POSIX shell."""
    fields = {f.name: f for f in cli_fields()}
    words = []
    for name, value in preset.overrides.items():
        flag = fields[name].metadata["cli"].flag
        if is_switch(fields[name]):
            off = flag.startswith("--no-")
            words.append(flag if value == (not off) else f"({name} {value})")
        else:
            words.append(f"{flag} {value:g}" if isinstance(value, float) else f"{flag} {shlex.quote(str(value))}")
    return " ".join(words)


def _default_words(f: dataclasses.Field) -> str:
    if f.metadata.get("tristate") and f.default is None:
        return ""
    return f" (default {f.default:g})" if isinstance(f.default, float) else f" (default {f.default})"


def add_tracker_arguments(p: argparse.ArgumentParser) -> None:
    """``--preset``, and one argument per option with a flag; each defaults to None (not given)."""
    p.add_argument("--preset", choices=PRESETS, default=None,
                   help="start from a preset of options, changed by the other flags (docs/tracking.md): "
                        + "; ".join(f"{name} = {preset_flags(preset)}" for name, preset in PRESETS.items()))
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
        elif isinstance(f.default, str):
            p.add_argument(cli.flag, dest=cli_dest(f), default=None, metavar=cli.metavar, help=help_text)
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
    """``base`` with ``--preset``'s options, then the options given on the command line, then
    ``fixed`` (set by the command itself).  A value the options refuse is a
    :class:`UsageError` naming its flag."""
    preset = getattr(args, "preset", None)
    if preset is not None:
        if base is not None and not isinstance(base, Preset):
            raise TypeError("--preset combines with a preset base only")
        chosen = PRESETS[preset]
        base = chosen if base is None else Preset(f"{base.name}, {chosen.name}", {**base.overrides, **chosen.overrides})
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
        overrides[f.name] = value
    flags = {f.name: f.metadata["cli"].flag for f in cli_fields()}
    for name, value in overrides.items():
        try:  # each flag alone, then (a check across options: --midline-legs needs --midline) with the others
            TrackerOptions().replace(**{name: value})
        except OptionError as err:
            try:
                TrackerOptions().replace(**overrides)
            except OptionError:
                raise UsageError(f"{flags[name]}: {err}") from None
    return as_options(base, {**overrides, **fixed})
