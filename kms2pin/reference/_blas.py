"""Run small dense linear algebra with one OpenBLAS thread.

The reference solver makes hundreds of LAPACK calls on matrices of about 100 x 100.
Multi-threaded OpenBLAS is slower than one thread at that size, and on a loaded
machine (more runnable processes than cores) it is slower by 10-100x because its
worker threads spin and wait for each other.  :func:`single_threaded_blas` sets every
OpenBLAS already loaded in the process (NumPy's and SciPy's) to one thread and puts
the previous counts back afterwards -- what ``threadpoolctl.threadpool_limits(1)``
does, without the dependency.  Where the libraries cannot be found (not Linux, another
BLAS) it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator


def _openblas_paths() -> list[str]:
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            paths = {line.split(maxsplit=5)[-1].strip() for line in f if "openblas" in line.lower()}
    except OSError:
        return []
    return sorted(p for p in paths if p.startswith("/") and os.path.exists(p))


def _thread_controls() -> list[tuple]:
    controls = []
    mode = getattr(os, "RTLD_NOLOAD", 0) | getattr(os, "RTLD_LOCAL", 0)
    for path in _openblas_paths():
        try:
            lib = ctypes.CDLL(path, mode=mode)
        except OSError:
            continue
        for prefix in ("openblas", "scipy_openblas"):
            for suffix in ("", "64_"):
                get = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                set_ = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                if get is not None and set_ is not None:
                    get.restype = ctypes.c_int
                    set_.argtypes = [ctypes.c_int]
                    controls.append((get, set_))
                    break
            else:
                continue
            break
    return controls


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limit every loaded OpenBLAS to one thread inside the ``with`` block."""
    try:
        controls = _thread_controls()
        saved = [(set_, int(get())) for get, set_ in controls]
        for set_, _ in saved:
            set_(1)
    except (OSError, AttributeError, ValueError):  # pragma: no cover - exotic platforms
        saved = []
    try:
        yield
    finally:
        for set_, n in saved:
            set_(max(n, 1))
