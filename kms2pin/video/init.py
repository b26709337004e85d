"""The automatic initialization and the pose file, where ``kms2pin.video.init`` kept them.

The initialization is tracking logic and lives in :mod:`kms2pin.ecm.initialization`;
the pose file reader in :mod:`kms2pin.video.posefile`.
"""

from ..ecm.initialization import InitResult, coarse_search, initial_pose, initial_pose_details, place, scaled_camera
from .posefile import read_pose_json

__all__ = ["InitResult", "coarse_search", "initial_pose", "initial_pose_details", "place", "read_pose_json",
           "scaled_camera"]
