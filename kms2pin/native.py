"""The optional C kernels (``kms2pin/_kernels.c``), compiled by ``pip install`` when a
C compiler is present.  Modules that use them keep their NumPy code as the fallback
and a module-level ``NATIVE`` flag; ``KMS2PIN_NATIVE=0`` in the environment turns
them off everywhere."""

from __future__ import annotations

import os

try:
    from . import _kernels as kernels
except ImportError:  # pragma: no cover - installs without a C compiler
    kernels = None

#: Whether the C kernels are built and enabled.
ENABLED: bool = kernels is not None and os.environ.get("KMS2PIN_NATIVE", "1") != "0"
