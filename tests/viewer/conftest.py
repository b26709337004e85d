"""Fixtures for the viewer tests.

Browser tests (``@pytest.mark.browser``) drive headless Chromium.  Without a
Chromium they are skipped locally, but fail when ``CI`` is set.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import kms2pin
from kms2pin.viewer import find_chromium

from ._util import load

HERE = Path(__file__).resolve().parent


def pytest_collection_modifyitems(config, items):
    if find_chromium() is not None or os.environ.get("CI"):  # in CI: failed in pytest_runtest_setup
        return
    for item in items:
        if "browser" in item.keywords and Path(str(item.fspath)).resolve().is_relative_to(HERE):
            item.add_marker(pytest.mark.skip(reason="no Chromium installed (browser tests run in CI)"))


def pytest_runtest_setup(item):  # before any fixture, so the message is this one
    if "browser" in item.keywords and find_chromium() is None and os.environ.get("CI"):
        pytest.fail("CI is set but no Chromium was found: browser tests must run in CI", pytrace=False)


@pytest.fixture(scope="module")
def lowerbody() -> kms2pin.Robot:
    return load("lowerbody")


@pytest.fixture(scope="module")
def puma() -> kms2pin.Robot:
    return load("puma600")
