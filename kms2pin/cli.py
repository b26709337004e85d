"""``kms2pin`` command line: one sub-command per module in :mod:`kms2pin.commands`.

Exit status: 0 success, 1 a model/data error (reported compiler-style on stderr),
2 a usage error (bad arguments, missing or unreadable input file), 130 interrupted
(Ctrl-C), 143 terminated (SIGTERM); interrupted or terminated, a command's outputs
are complete up to where it stopped.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from . import __version__, commands
from .commands._outputs import Terminated, sigterm_as_interrupt
from .errors import Kms2pinError, UsageError

EXIT_OK, EXIT_MODEL, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED, EXIT_TERMINATED = 130, 143  # 128 + SIGINT, 128 + SIGTERM, as a shell reports them
__all__ = ["EXIT_INTERRUPTED", "EXIT_MODEL", "EXIT_OK", "EXIT_TERMINATED", "EXIT_USAGE", "UsageError", "build_parser",
           "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kms2pin",
        description="Compile kinematic model specs (.kms) to URDF/Pinocchio; static update; ECM tracking.",
    )
    parser.add_argument("--version", action="version", version=f"kms2pin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.__doc__)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with sigterm_as_interrupt():
            return int(args._run(args) or 0)
    except UsageError as err:
        print(f"kms2pin {args.command}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except FileNotFoundError as err:
        print(f"kms2pin {args.command}: error: {err.filename or err}: no such file", file=sys.stderr)
        return EXIT_USAGE
    except IsADirectoryError as err:
        print(f"kms2pin {args.command}: error: {err.filename}: is a directory", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. `kms2pin check --json x | head`
        sys.stderr.close()
        return EXIT_OK
    except OSError as err:  # an input file named on the command line cannot be read (outputs say "cannot write")
        where = f"{err.filename}: " if err.filename else ""
        print(f"kms2pin {args.command}: error: {where}{err.strerror or err}", file=sys.stderr)
        return EXIT_USAGE if err.filename else EXIT_MODEL
    except Kms2pinError as err:
        print(str(err), file=sys.stderr)
        return EXIT_MODEL
    except Terminated:
        print(f"kms2pin {args.command}: terminated (SIGTERM)", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"kms2pin {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
