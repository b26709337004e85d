from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType
from typing import NoReturn

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only cost time

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")


@pytest.fixture(params=SPEC_NAMES)
def spec_path(request) -> Path:
    return SPECS / f"{request.param}.kms"


def skip_or_fail_in_ci(reason: str) -> NoReturn:
    """Skip a test for a missing build tool or extension locally (``reason``), but fail it
    when ``CI`` is set: CI installs everything, so nothing may be skipped there."""
    if os.environ.get("CI"):
        pytest.fail(f"CI is set but {reason}: this test must run in CI", pytrace=False)
    pytest.skip(reason)


def require_kernels() -> ModuleType:
    """The C kernels (``kms2pin._kernels``, built from kms2pin/_kernels.c by the install):
    a test needing them is skipped without them locally and fails in CI."""
    from kms2pin.native import kernels

    if kernels is None:
        skip_or_fail_in_ci("kms2pin._kernels is not built (no C compiler at install time)")
    return kernels


@pytest.fixture(params=["native", "numpy"])
def backend(request, monkeypatch) -> str:
    """Run a static-update test with the C kernels (kms2pin/_kernels.c) and with the NumPy
    fallback; in CI the C kernels must have been built by the install."""
    from kms2pin import virtual_work

    if request.param == "native":
        require_kernels()
        monkeypatch.setattr(virtual_work, "NATIVE", True)
    else:
        monkeypatch.setattr(virtual_work, "NATIVE", False)
    return request.param
