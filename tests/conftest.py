from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")


@pytest.fixture(params=SPEC_NAMES)
def spec_path(request) -> Path:
    return SPECS / f"{request.param}.kms"
