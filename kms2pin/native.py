"""The one switch between the C kernels and their NumPy twins.

``kms2pin/_kernels.c`` is compiled by ``pip install`` when a C compiler is present;
:mod:`kms2pin._numpy_kernels` has a NumPy function of the same name, signature and
semantics for each of its functions.  :data:`kernels` holds the chosen one of each: the
C function when the extension is built and ``KMS2PIN_NATIVE`` is not ``"0"`` in the
environment, else the NumPy one.  Callers look a kernel up in it at each call
(``kernels.fit_body(...)``), so :func:`use` switches every caller at once.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import ModuleType, SimpleNamespace

from . import _numpy_kernels

_c: ModuleType | None
try:
    from . import _kernels as _c
except ImportError:  # pragma: no cover - installs without a C compiler
    _c = None

#: The kernels' names: the C module's functions.
NAMES: tuple[str, ...] = tuple(_numpy_kernels.__all__)
#: The backends :func:`use` takes.
BACKENDS = ("c", "numpy")
#: Whether the C extension is built.
BUILT: bool = _c is not None

#: The chosen implementation of each kernel, by name.
kernels = SimpleNamespace()
#: Whether :data:`kernels` are the C ones (:func:`use` changes it).
ENABLED: bool = False


def implementations(name: str) -> dict[str, Callable | None]:
    """Both implementations of kernel ``name``: ``{"c": the C function or None if the
    extension is not built, "numpy": the NumPy function}``."""
    if name not in NAMES:
        raise KeyError(f"no kernel '{name}'; the kernels are: {', '.join(NAMES)}")
    return {"c": getattr(_c, name, None), "numpy": getattr(_numpy_kernels, name)}


def _select(backend: str) -> None:
    global ENABLED
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, not {backend!r}")
    if backend == "c" and not BUILT:
        raise RuntimeError("the C kernels (kms2pin._kernels) are not built: install with a C compiler")
    for name in NAMES:
        impl = implementations(name)
        setattr(kernels, name, impl["c"] if backend == "c" and impl["c"] is not None else impl["numpy"])
    ENABLED = backend == "c"


@contextmanager
def use(backend: str) -> Iterator[SimpleNamespace]:
    """Run the enclosed code with the ``"c"`` or the ``"numpy"`` kernels (for tests and
    benchmarks); the previous choice is restored on exit."""
    before = "c" if ENABLED else "numpy"
    _select(backend)
    try:
        yield kernels
    finally:
        _select(before)


_select("c" if BUILT and os.environ.get("KMS2PIN_NATIVE", "1") != "0" else "numpy")
