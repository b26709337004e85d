from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only cost time

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")


@pytest.fixture(params=SPEC_NAMES)
def spec_path(request) -> Path:
    return SPECS / f"{request.param}.kms"


@pytest.fixture(params=["native", "numpy"])
def backend(request, monkeypatch) -> str:
    """Run a static-update test with the C kernels (kms2pin/_kernels.c) and with the NumPy
    fallback; in CI the C kernels must have been built by the install."""
    from kms2pin import virtual_work

    if request.param == "native":
        if virtual_work._kernels is None:
            if os.environ.get("CI"):
                pytest.fail("the C kernels (kms2pin._kernels) were not built by the install")
            pytest.skip("kms2pin._kernels not built (no C compiler at install time)")
        monkeypatch.setattr(virtual_work, "NATIVE", True)
    else:
        monkeypatch.setattr(virtual_work, "NATIVE", False)
    return request.param
