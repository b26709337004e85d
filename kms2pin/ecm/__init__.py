"""ECM tracking (thesis §2.1): cameras, ellipsoid images, densities, and the tracker with
its options, synthetic data and evaluation.

The image geometry (:mod:`~kms2pin.ecm.camera`, :mod:`~kms2pin.ecm.projection`,
:mod:`~kms2pin.ecm.density`, :mod:`~kms2pin.ecm.raycast`)
is independent of the rest of kms2pin: bodies are ``(world_T_body, semi_axes)`` given
as ``pin.SE3`` and arrays (the ray casting also takes a :class:`Capsule`).  The tracker
(:mod:`~kms2pin.ecm.tracker`) works on a :class:`kms2pin.Robot`.
"""

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.density import body_depth, density_region, projected_density
from kms2pin.ecm.evaluate import evaluate
from kms2pin.ecm.limbs import limb_joints
from kms2pin.ecm.motions import MOTIONS, make_motion
from kms2pin.ecm.options import (
    PEOPLE,
    PEOPLE_ONE_CAMERA,
    PEOPLE_TRACKS,
    SEGMENTED_MASKS,
    HypothesisOptions,
    IterationOptions,
    LimbSearchOptions,
    MStepOptions,
    PriorOptions,
    SilhouetteOptions,
    SizeOptions,
    SpringOptions,
    TrackerOptions,
)
from kms2pin.ecm.projection import (
    BBox,
    Ellipse,
    ProjectionError,
    Visibility,
    body_bbox,
    ellipse_parameters,
    ellipsoid_conic,
    ellipsoid_visibility,
    inside_conic,
)
from kms2pin.ecm.raycast import Capsule, render_labels, render_mask
from kms2pin.ecm.synth import synthesize
from kms2pin.ecm.tracker import Tracker
from kms2pin.ecm.trajectory import FrameResult, Trajectory, TrajectoryCsvWriter

__all__ = [
    "BBox",
    "Camera",
    "Capsule",
    "Ellipse",
    "FrameResult",
    "HypothesisOptions",
    "IterationOptions",
    "LimbSearchOptions",
    "MOTIONS",
    "MStepOptions",
    "PEOPLE",
    "PEOPLE_ONE_CAMERA",
    "PEOPLE_TRACKS",
    "PriorOptions",
    "ProjectionError",
    "SEGMENTED_MASKS",
    "SilhouetteOptions",
    "SizeOptions",
    "SpringOptions",
    "Tracker",
    "TrackerOptions",
    "Trajectory",
    "TrajectoryCsvWriter",
    "Visibility",
    "body_bbox",
    "body_depth",
    "density_region",
    "ellipse_parameters",
    "ellipsoid_conic",
    "ellipsoid_visibility",
    "evaluate",
    "inside_conic",
    "limb_joints",
    "make_motion",
    "projected_density",
    "render_labels",
    "render_mask",
    "synthesize",
]
