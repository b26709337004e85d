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
