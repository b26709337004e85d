"""How thick a human's body segments are: the cross-sections ``kms2pin import`` gives a BVH
skeleton's bones, as fractions of the skeleton's height H (docs/bvh.md has the table).

A bone's length comes from the file; across it, a segment's two semi-axes are those of
``specs/human.kms`` (whose lengths are Drillis and Contini's table, D. A. Winter,
*Biomechanics and Motor Control of Human Movement*, fig. 4.1, and whose foot and hand
widths are that table's).  A bone is recognised by its joint's name, the usual names of
CMU, Biovision, 3ds Max and Mixamo skeletons: the segment is the bone *below* the joint
(CMU's ``LeftHip`` is the thigh, Mixamo's ``LeftUpLeg`` too).  A name it does not know
gets :data:`OTHER_RATIO` of the bone's length all round.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Segment:
    """A body segment: ``across`` its bone, two semi-axes (fractions of H), the first along
    the lateral axis (x at rest) where the bone allows; ``length`` the semi-axis along it
    (fraction of H) when the bone has no length (a root whose children start at its point)."""

    name: str
    across: tuple[float, float]
    length: float


SEGMENTS = {s.name: s for s in (
    Segment("pelvis", (0.095, 0.06), 0.07),
    Segment("pelvis side", (0.05, 0.06), 0.05),
    Segment("trunk", (0.095, 0.065), 0.08),
    Segment("neck", (0.035, 0.035), 0.035),
    Segment("head", (0.045, 0.055), 0.065),
    Segment("clavicle", (0.025, 0.025), 0.025),
    Segment("upper arm", (0.03, 0.03), 0.03),
    Segment("forearm", (0.024, 0.024), 0.024),
    Segment("hand", (0.011, 0.027), 0.027),
    Segment("finger", (0.006, 0.006), 0.006),
    Segment("thigh", (0.045, 0.045), 0.045),
    Segment("shin", (0.032, 0.032), 0.032),
    Segment("foot", (0.0275, 0.02), 0.02),
    Segment("toes", (0.0275, 0.012), 0.012),
)}
#: Semi-axes across a bone whose name is not in the table, as a fraction of its length.
OTHER_RATIO = 0.15
#: A bone's semi-axis along it, as a fraction of its length (limbs overlap at their joints, as in human.kms).
ALONG = 0.55
#: The outer ellipsoid's semi-axes over the inner one's (as in human.kms).
OUTER = 1.2

# (segment, words): the first segment one of whose words the lower-case name holds
_WORDS = (
    ("finger", ("finger", "thumb", "index", "middle", "ring", "pinky", "little")),
    ("toes", ("toe",)),
    ("foot", ("foot", "ankle")),
    ("pelvis side", ("hipjoint",)),
    ("pelvis", ("pelvis", "hips")),
    ("thigh", ("upleg", "thigh", "femur", "hip")),
    ("shin", ("knee", "shin", "calf", "tibia", "lowleg", "leg")),
    ("forearm", ("forearm", "lowarm", "elbow", "ulna")),
    ("hand", ("hand", "wrist", "palm")),
    ("clavicle", ("collar", "clavicle")),
    ("shoulder", ("shoulder",)),
    ("upper arm", ("arm", "humerus")),
    ("neck", ("neck",)),
    ("head", ("head", "skull")),
    ("trunk", ("spine", "back", "chest", "torso", "abdomen", "thorax", "waist", "lumbar")),
)


def _by_name(name: str) -> str | None:
    key = re.sub(r"[^a-z]", "", name.lower())
    return next((segment for segment, words in _WORDS if any(w in key for w in words)), None)


def segment_of(name: str, children: list[str], root: bool = False) -> Segment | None:
    """The segment of the bone below the joint ``name`` whose child joints are ``children``,
    or None for a name the table does not know.  A "shoulder" is the upper arm when an
    elbow or forearm follows it (CMU), else the clavicle (Mixamo's ``LeftShoulder`` ->
    ``LeftArm``); an unknown root is the pelvis."""
    found = _by_name(name)
    if found == "shoulder":
        found = "upper arm" if any(_by_name(c) == "forearm" for c in children) else "clavicle"
    if found is None and root:
        found = "pelvis"
    return SEGMENTS[found] if found else None
