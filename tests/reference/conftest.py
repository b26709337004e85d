"""Fixtures for the reference-implementation tests (helpers live in _support.py)."""

from __future__ import annotations

import pytest

from kms2pin.reference import symbolic_model

from ._support import ROOTS, SPEC_NAMES, load_system


@pytest.fixture(params=SPEC_NAMES)
def spec_name(request) -> str:
    return request.param


@pytest.fixture(params=ROOTS)
def root(request) -> str:
    return request.param


@pytest.fixture
def system(spec_name):
    return load_system(spec_name)


@pytest.fixture
def model(system, root):
    return symbolic_model(system, root)


@pytest.fixture(autouse=True)
def _one_blas_thread():
    """Small LAPACK calls are much faster single-threaded (see kms2pin.reference._blas)."""
    from kms2pin.reference._blas import single_threaded_blas

    with single_threaded_blas():
        yield
