"""BVH motion capture in and out (docs/bvh.md).

:mod:`~kms2pin.bvh.reader` parses a file; :mod:`~kms2pin.bvh.motion` says what its channels
mean in the model's frame; :mod:`~kms2pin.bvh.builder` models its skeleton (with the
segment sizes of :mod:`~kms2pin.bvh.anthropometry`) and its motion as configurations
(``kms2pin import``); :mod:`~kms2pin.bvh.writer` writes a model's trajectory as BVH
(``motion.bvh`` of ``kms2pin track``, ``kms2pin convert``).
"""

from __future__ import annotations

from .builder import ImportedModel, ImportOptions, import_bvh
from .reader import BvhFile, BvhJoint, parse_bvh, read_bvh
from .writer import check_bvh_model, to_bvh

__all__ = ["BvhFile", "BvhJoint", "ImportOptions", "ImportedModel", "check_bvh_model", "import_bvh", "parse_bvh",
           "read_bvh", "to_bvh"]
