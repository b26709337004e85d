from __future__ import annotations

import importlib
import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import NoReturn

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only cost time

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe"  # the start of a PNG: not UTF-8


def set_csv_cell(path: Path, line: int, column: str, value: str) -> None:
    """Set the cell of the CSV file ``path`` on (1-based) ``line`` under the header's ``column`` to ``value``."""
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    path.write_text("".join(",".join(r) + "\n" for r in rows))


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
    from kms2pin import native

    if not native.BUILT:
        skip_or_fail_in_ci("kms2pin._kernels is not built (no C compiler at install time)")
    return importlib.import_module("kms2pin._kernels")


@pytest.fixture(params=["c", "numpy"])
def backend(request) -> Iterator[str]:
    """Run a test with the C kernels (kms2pin/_kernels.c) and with their NumPy twins
    (:func:`kms2pin.native.use`); in CI the C kernels must have been built by the install."""
    from kms2pin import native

    if request.param == "c":
        require_kernels()
    with native.use(request.param):
        yield request.param
