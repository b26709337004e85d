from __future__ import annotations

import importlib
import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import NoReturn

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only cost time

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"
SPEC_NAMES = ("puma600", "lowerbody", "fullbody", "jplhand")  # the thesis's four models
OUR_SPECS = ("human", "gantry")  # with spherical and prismatic joints (kms2pin's)
# every joint type, with misaligned, antiparallel and tilted axes, non-zero rest rotations
# and offsets, a spherical joint to the inertial frame and a prismatic one without limits
MIXED_JOINTS = """
bvec origin { pos(0.5, 1, 3); orient(0, 0, 1); }
rigidBodySystem mixed {
    ellipsoidBody a { innerLam(0.2, 0.3, 0.2); outerLam(0.25, 0.35, 0.25);
        bvec base { pos(0, -0.3, 0); orient(1, 2, 0); }
        bvec ball { pos(0.1, 0.3, 0); orient(0, 1, 1); }
        bvec slide { pos(0.2, 0, 0.1); orient(1, -1, 2); }
        bvec hinge { pos(-0.2, 0, 0); orient(0, 0, 1); } }
    ellipsoidBody b { innerLam(0.1, 0.2, 0.1); outerLam(0.15, 0.25, 0.15);
        bvec ball { pos(0, -0.2, 0.05); orient(1, 0, 0); }
        bvec slide { pos(0, 0.2, 0); orient(0, 0, -1); } }
    ellipsoidBody c { innerLam(0.1, 0.1, 0.2); outerLam(0.15, 0.15, 0.25);
        bvec slide { pos(0.05, 0, -0.2); orient(-1, 1, -2); } }
    ellipsoidBody d { innerLam(0.1, 0.1, 0.1); outerLam(0.15, 0.15, 0.15);
        bvec slide { pos(0, 0, 0.1); orient(0.3, 0.4, 1); } }
    ellipsoidBody e { innerLam(0.1, 0.2, 0.1); outerLam(0.15, 0.25, 0.15);
        bvec hinge { pos(0, 0.2, 0); orient(1, 0, 0); } }
    constraint spherical(a.ball, b.ball, 30, -20, 45);
    constraint prismatic(c.slide, a.slide, 0.15, -0.4, 0.6);
    constraint prismatic(b.slide, d.slide, -0.1);
    constraint revolute(e.hinge, a.hinge, 25, -90, 90);
}
constraint spherical(origin, mixed.a.base, 10, 0, -30);
"""
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe"  # the start of a PNG: not UTF-8


def video_frames(path: Path) -> list[np.ndarray]:
    """Every frame OpenCV decodes from the video file ``path`` (BGR uint8)."""
    import cv2

    video, frames = cv2.VideoCapture(str(path)), []
    try:
        ok, img = video.read()
        while ok:
            frames.append(img)
            ok, img = video.read()
    finally:
        video.release()
    return frames


def page_commands(html: str) -> list[dict]:
    """The meshcat commands embedded in a standalone page, decoded."""
    import base64
    import re

    import umsgpack

    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def drawn_semi_axes(html: str, kind: str = "inner") -> dict[str, np.ndarray]:
    """Each body's ``kind`` ellipsoid's semi-axes as a standalone meshcat page draws it
    (a unit sphere scaled by them), by body name."""
    out = {}
    for c in page_commands(html):
        if c["type"] == "set_object" and c["path"].endswith(f"/{kind}") and "/bodies/" in c["path"]:
            assert c["object"]["geometries"][0]["radius"] == 1.0
            body = c["path"].rsplit("/bodies/", 1)[1].rsplit("/", 1)[0]
            out[body] = np.diag(np.array(c["object"]["object"]["matrix"]).reshape(4, 4))[:3]
    return out


def set_csv_cell(path: Path, line: int, column: str, value: str) -> None:
    """Set the cell of the CSV file ``path`` on (1-based) ``line`` under the header's ``column`` to ``value``."""
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    path.write_text("".join(",".join(r) + "\n" for r in rows))


@pytest.fixture(params=SPEC_NAMES + OUR_SPECS)
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
