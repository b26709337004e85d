"""kms2pin: the 1999 kinematic model compiler (Sudderth) on Pinocchio.

Pipeline: language (:mod:`kms2pin.lang`) -> model (:mod:`kms2pin.model`) ->
URDF/SRDF (:mod:`kms2pin.urdf`) -> Pinocchio robot (:mod:`kms2pin.robot`) ->
static update (:mod:`kms2pin.virtual_work`) -> ECM tracking (:mod:`kms2pin.ecm`) ->
viewer (:mod:`kms2pin.viewer`).
"""

from __future__ import annotations

from .errors import (
    BvhError,
    CameraError,
    ExportError,
    InputDataError,
    Kms2pinError,
    OptionError,
    OutputError,
    RobotError,
    SpecError,
    TargetError,
)
from .lang import parse, parse_text
from .model import Body, BoundVector, Joint, ModelSpec, System
from .robot import Robot, euler_parameters, load
from .virtual_work import StaticUpdateResult, static_update

__version__ = "0.1.0"

__all__ = [
    "Body",
    "BoundVector",
    "BvhError",
    "CameraError",
    "ExportError",
    "InputDataError",
    "Joint",
    "Kms2pinError",
    "ModelSpec",
    "OptionError",
    "OutputError",
    "Robot",
    "RobotError",
    "SpecError",
    "StaticUpdateResult",
    "System",
    "TargetError",
    "__version__",
    "euler_parameters",
    "load",
    "parse",
    "parse_text",
    "static_update",
]
