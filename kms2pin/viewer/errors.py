"""Errors of the viewer package (kept here so the package is self-contained)."""

from __future__ import annotations

from ..errors import Kms2pinError


class ViewerError(Kms2pinError):
    """Drawing, serving or rendering a model failed (meshcat server, chromium, files)."""


class PoseError(ViewerError, ValueError):
    """A ``--pose`` string names an unknown or fixed joint or gives no number."""
