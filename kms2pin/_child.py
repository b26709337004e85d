"""Command lines for the helper scripts kms2pin runs in child processes.

A helper (the video decoder, the meshcat server) is run by file, not as a module of
this package, so the child imports only what the helper needs; ``-I`` keeps the
current folder, the user's site-packages and the environment's PYTHONPATH off its
``sys.path`` (a ``cv2.py`` in the folder a command runs from must not shadow
OpenCV), and this process's ``sys.path`` is passed to it instead.
"""

from __future__ import annotations

import json
import os
import sys

_BOOT = ("import json, runpy, sys; sys.path[:0] = json.loads(sys.argv[1]); "
         "sys.exit(runpy.run_path(sys.argv[2])['main'](sys.argv[3:]))")


def helper_command(script: str | os.PathLike, *args: str) -> list[str]:
    """The command that runs ``main(list(args))`` of the Python file ``script`` in a child."""
    return [sys.executable, "-I", "-c", _BOOT, json.dumps([p for p in sys.path if p]), os.fspath(script), *args]
