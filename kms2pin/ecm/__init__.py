"""ECM image geometry (thesis §2.1): cameras, ellipsoid images, densities, E-step.

Independent of the rest of kms2pin: bodies are ``(world_T_body, semi_axes)``
given as ``pin.SE3`` and arrays.
"""

from kms2pin.ecm.camera import Camera
from kms2pin.ecm.density import body_depth, density_region, projected_density
from kms2pin.ecm.estep import EStepResult, e_step
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
from kms2pin.ecm.raycast import render_labels, render_mask

__all__ = [
    "BBox",
    "Camera",
    "EStepResult",
    "Ellipse",
    "ProjectionError",
    "Visibility",
    "body_bbox",
    "body_depth",
    "density_region",
    "e_step",
    "ellipse_parameters",
    "ellipsoid_conic",
    "ellipsoid_visibility",
    "inside_conic",
    "projected_density",
    "render_labels",
    "render_mask",
]
