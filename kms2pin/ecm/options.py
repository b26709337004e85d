"""The tracker's options: frozen groups, each option declared once.

Every option is a field of one small frozen group (iteration, silhouette, M-step,
springs, sizes, priors, hypotheses, limb search) with its default, its range and
one line of help.  The groups check themselves in ``__post_init__`` (:class:`OptionError`
names the option, the value and the range); :class:`TrackerOptions` holds one of
each, and :meth:`TrackerOptions.replace` takes the flat keyword spelling
``Tracker(robot, cams, upright=0.1)`` uses.  The command line builds its flags from
the same fields (``cli`` in a field's metadata, :func:`cli_fields`), and ``meta.json``
records :func:`dataclasses.asdict` of the options.

Which options suit which subject: docs/tracking.md; the measurements behind the
defaults: docs/design/tracking-history.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import OptionError, did_you_mean

#: the largest weight of a prior (times the joints' mean stiffness): far stiffer than any spring, and
#: small enough that the springs' products stay finite
MAX_WEIGHT = 1e6


@dataclass(frozen=True)
class Range:
    """The values a numeric option takes: ``lo`` (excluded if ``open_lo``) up to ``hi``
    (None: no bound), whole numbers only if ``whole``, None too if ``none_ok``."""

    lo: float
    hi: float | None = None
    open_lo: bool = False
    whole: bool = False
    none_ok: bool = False

    def check(self, name: str, value: Any) -> None:
        if value is None and self.none_ok:
            return
        kinds = (int, np.integer) if self.whole else (int, float, np.integer, np.floating)
        either = " or None" if self.none_ok else ""
        if isinstance(value, bool) or not isinstance(value, kinds):
            what = "a whole number" if self.whole else "a number"
            raise OptionError(f"{name} must be {what}{either}, not {value!r}")
        low_ok = value > self.lo if self.open_lo else value >= self.lo
        if not (np.isfinite(value) and low_ok and (self.hi is None or value <= self.hi)):
            bound = f"{'>' if self.open_lo else '>='} {self.lo}" + (f" and <= {self.hi}" if self.hi is not None else "")
            raise OptionError(f"{name} must be {bound}{either}, not {value!r}")


@dataclass(frozen=True)
class Cli:
    """How an option appears on ``kms2pin track``'s command line: its flag (``--no-x``
    for a switch that turns it off), a metavar, a lower bound stricter than the
    option's (``lo``) and the value that stands for None (``none``)."""

    flag: str
    metavar: str | None = None
    lo: float | None = None
    none: float | None = None


def option(default: Any, help: str, *, range: Range | None = None, choices: tuple | None = None,
           tristate: bool = False, cli: Cli | None = None) -> Any:
    """A field of an option group: its default, one line of help, and its check
    (a numeric ``range``, ``choices``, or a switch: bool, None too if ``tristate``)."""
    meta = {"help": help, "range": range, "choices": choices, "tristate": tristate, "cli": cli}
    if isinstance(default, (list, tuple)):
        return field(default=tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


class _Group:
    """Base of the option groups: checks every field against its metadata."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            meta = f.metadata
            if meta.get("range") is not None:
                meta["range"].check(f.name, value)
            elif meta.get("choices") is not None:
                if value not in meta["choices"]:
                    words = " or ".join(repr(c) for c in meta["choices"])
                    raise OptionError(f"{f.name} must be {words}, not {value!r}")
            elif isinstance(f.default, bool) or meta.get("tristate"):
                if not (isinstance(value, (bool, np.bool_)) or (value is None and meta.get("tristate"))):
                    raise OptionError(f"{f.name} must be True or False{' or None' if meta['tristate'] else ''}, "
                                      f"not {value!r}")
        self._check()

    def _check(self) -> None:
        """Checks across the group's options (none by default)."""


def _documented(cls):
    """Class decorator: a frozen dataclass whose docstring lists its options' help."""
    cls = dataclass(frozen=True)(cls)
    lines = [f"    {f.name}: {f.metadata['help']}" for f in dataclasses.fields(cls)]
    cls.__doc__ = (cls.__doc__ or "").rstrip() + "\n\n    Attributes:\n" + "\n".join(f"    {x}" for x in lines) + "\n"
    return cls


@_documented
class IterationOptions(_Group):
    """The ECM iterations of a frame: how many, when they stop, the edge annealing."""

    max_iterations: int = option(8, "most ECM iterations per frame", range=Range(1, whole=True))
    min_iterations: int = option(3, "fewest ECM iterations per frame", range=Range(1, whole=True))
    tol_deg: float = option(0.2, "a frame has converged when no joint moves more than this (degrees; the root's "
                                 "translation: 1 % of the model height counts as 1 degree) ...", range=Range(0.0))
    tol_px: float | None = option(
        0.25, "... or no body's outline more than this in any camera (pixels; None: the joints' test alone)",
        range=Range(0.0, open_lo=True, none_ok=True),
        cli=Cli("--tol-px", "PX", none=0.0))
    prediction: str = option("constant_velocity", "each frame starts from the last frame's motion carried on, "
                             "from the share of it that a motion model learnt on the past frames carries on "
                             "('learnt'), or from the last pose", choices=("constant_velocity", "learnt", "previous"),
                             cli=Cli("--prediction", "HOW"))
    prediction_memory: float = option(10.0, "frames the learnt motion model remembers (their weight is multiplied "
                                            "by 1 - 1/memory a frame)", range=Range(1.0, open_lo=True))
    max_prediction_deg: float = option(20.0, "cap on each joint's predicted motion per frame (degrees; the root's "
                                             "translation as in tol_deg)", range=Range(0.0))
    delta_start: float = option(2.8, "edge width of the sharp silhouettes on a frame's first iteration (pixels), "
                                     "halved each iteration ...", range=Range(0.0, open_lo=True))
    delta_final: float = option(0.7, "... down to this (pixels); a body's edge is at most 0.08 of its outline's "
                                     "radius, so a width acts only on outlines of more than 12.5 widths in radius "
                                     "(8.75 pixels for 0.7)", range=Range(0.0, open_lo=True))
    coarse_delta_px: float | None = option(
        None, "iterations whose edge is at least this wide (pixels, above delta_final) run on masks binned 2x2 "
              "(None: off)", range=Range(0.0, open_lo=True, none_ok=True))

    def _check(self) -> None:
        if self.min_iterations > self.max_iterations:
            raise OptionError(f"min_iterations ({self.min_iterations}) must not exceed max_iterations "
                              f"({self.max_iterations})")
        if not self.delta_final <= self.delta_start:
            raise OptionError(f"delta_start ({self.delta_start}) must not be below delta_final ({self.delta_final})")
        if self.coarse_delta_px is not None and not self.coarse_delta_px > self.delta_final:
            raise OptionError(f"coarse_delta_px must be above delta_final ({self.delta_final}) or None, "
                              f"not {self.coarse_delta_px!r}")


@_documented
class SilhouetteOptions(_Group):
    """The masks and the silhouette model of the E-step (thesis §2.1.2)."""

    clean: bool = option(False, "3x3 median-filter the masks first (also removes thin detail such as fingers)")
    outlier: float = option(0.0, "outlier class: a pixel weighs p / (p + outlier), p its probability under the "
                                 "bodies' union (0: off)", range=Range(0.0, 1.0))
    outlier_px: float = option(3.0, "the least edge width (pixels) of the union in the outlier test",
                               range=Range(0.0, open_lo=True))
    max_pixels: int = option(1_000_000, "pixels per body and camera above which the M-step subsamples",
                             range=Range(1, whole=True))
    poor_fit: float = option(0.5, "a frame fitting worse (IoU with the masks) is flagged 'poor fit' and passes "
                                  "no velocity on", range=Range(0.0, 1.0))


@_documented
class MStepOptions(_Group):
    """Each body's 6-DoF refit (:func:`kms2pin.ecm.mstep.fit_body`)."""

    m_iterations: int = option(2, "Gauss-Newton iterations of each body's M-step", range=Range(1, whole=True))
    damping: float = option(5e-2, "pull towards the body's pose from the joints, relative to its largest data "
                                  "curvature: a body the images hardly fix stays put", range=Range(0.0))
    max_step: float | None = option(0.5, "cap on an M-step step (mean semi-axes or radians; None: no cap)",
                                    range=Range(0.0, open_lo=True, none_ok=True))


@_documented
class SpringOptions(_Group):
    """The static update's springs (eq. 2.33) between the M-step's bodies and the joints."""

    static: str = option("full", "a full 6x6 spring per body (its M-step curvature) or the thesis's diagonal "
                                 "one per maximal coordinate", choices=("full", "diagonal"))
    static_iterations: int = option(3, "Gauss-Newton steps of the 'full' static update ('diagonal' runs to "
                                       "convergence)", range=Range(1, whole=True))
    stiffness_floor: float = option(1e-2, "spring stiffness floor, a fraction of the stiffest body's",
                                    range=Range(0.0))


@_documented
class SizeOptions(_Group):
    """The body sizes measured on the first frame and refined as the subject turns."""

    calibrate_sizes: bool = option(True, "measure the body sizes on the first frame, whose pose is q0",
                                   cli=Cli("--no-size-calibration"))
    size_every: int = option(5, "refine the measured sizes on every n-th frame that fits at least as well as the "
                                "running fit (0: keep the first frame's)", range=Range(0, whole=True),
                             cli=Cli("--size-every", "N"))
    size_iterations: int = option(4, "E-step / size-fit rounds of the first frame's measurement",
                                  range=Range(1, whole=True))


@_documented
class PriorOptions(_Group):
    """Springs that hold what the images do not fix (each times a stiffness the data sets)."""

    depth_prior: float = option(0.0, "hold a free root's distance along each camera's ray at the prediction",
                                range=Range(0.0, MAX_WEIGHT), cli=Cli("--depth-prior", "K"))
    upright: float = option(0.0, "hold the free root's tilt from 'up' at the first frame's (0.1 for people "
                                 "walking, one camera)", range=Range(0.0, MAX_WEIGHT), cli=Cli("--upright", "K"))
    up: tuple = option((0.0, 1.0, 0.0), "the world's vertical for 'upright' (normalized)", cli=Cli("--up"))
    rest_prior: float = option(0.0, "pull every joint, not the root, towards the pose 'rest_pose' names (0.01 "
                                    "for people walking, one camera)", range=Range(0.0, MAX_WEIGHT), cli=Cli("--rest-prior", "K"))
    rest_pose: str = option("spec", "the pose 'rest_prior' pulls towards: the spec's rest pose ('spec') or the "
                                    "track's starting pose q0 ('start': for a model whose rest is far from how "
                                    "the subject stands, such as a BVH import's T-pose)", choices=("spec", "start"),
                            cli=Cli("--rest-pose", "WHICH"))
    twist_prior: float = option(0.0, "hold a spherical joint's twist about its child's long axis near rest "
                                     "where that body is nearly round (an upper arm): no silhouette shows it "
                                     "(0: off)",
                                range=Range(0.0, MAX_WEIGHT), cli=Cli("--twist-prior", "K"))
    twist_free: float = option(0.0, "the twist (degrees either way of rest) that twist_prior leaves free: a soft "
                                    "limit past it instead of a pull towards rest (0: the pull)",
                               range=Range(0.0, 180.0), cli=Cli("--twist-free", "DEG"))
    spine_twist: float = option(0.0, "hold the spine's twist (the spherical joints from a free root to the body "
                                     "twin limbs branch from) about its bones near rest: a trunk turned half a "
                                     "turn with its arms exchanged casts the same silhouettes (0.05 for people; "
                                     "0: off)", range=Range(0.0, MAX_WEIGHT), cli=Cli("--spine-twist", "K"))
    spine_free: float = option(0.0, "the twist (degrees either way of rest, each spine joint) that spine_twist "
                                    "leaves free (0: a pull towards rest)",
                               range=Range(0.0, 180.0), cli=Cli("--spine-free", "DEG"))
    midline: float = option(0.0, "keep each arm's root (a collar, an upper arm) on its side of the body it hangs "
                                 "from: a spring that pushes it out once its centre comes within half its offset "
                                 "at rest of that body's midline (the legs, the limbs that hold the feet at the "
                                 "first pose, are left out; 0: off)",
                            range=Range(0.0, MAX_WEIGHT), cli=Cli("--midline", "K"))
    midline_legs: float | None = option(
        None, "with midline, keep each thigh out past this share of its offset at rest from the pelvis's "
              "midline too, so that a kick does not pull the other thigh onto its image (a share in [0, 1]; "
              "None: the legs left out)", range=Range(0.0, 1.0, none_ok=True), cli=Cli("--midline-legs", "SHARE"))
    ground: float = option(0.0, "ground contact: pull the feet's lowest point onto the floor and push any foot "
                                "below it up, which gives one camera the depth (the floor: ground_height along "
                                "'up'; the feet: the bodies lowest at q0; 0: off)",
                           range=Range(0.0, MAX_WEIGHT), cli=Cli("--ground", "K"))
    ground_height: float | None = option(
        None, "the floor's height along 'up' for 'ground' (spec units; None: the feet's lowest point at the "
              "pose the sizes are measured at, q0)", range=Range(-np.inf, none_ok=True),
        cli=Cli("--ground-height", "H"))

    def _check(self) -> None:
        try:
            up = np.asarray(self.up, dtype=float)
        except (TypeError, ValueError):
            up = np.zeros(0)
        norm = float(np.linalg.norm(up)) if up.shape == (3,) else 0.0
        if not (np.isfinite(norm) and norm > 0.0):
            raise OptionError(f"up must be a non-zero 3-vector, not {up.tolist()!r}")
        object.__setattr__(self, "up", tuple(float(x) for x in up / norm))
        if self.midline_legs is not None and not self.midline > 0:
            raise OptionError(f"midline_legs ({self.midline_legs}) is the legs' share of the midline prior, which "
                              f"is off: set midline above 0 too")


@_documented
class HypothesisOptions(_Group):
    """Alternative hypotheses tracked beside the pose (one camera)."""

    mirror_hypothesis: bool | None = option(
        None, "also track the pose's mirror image in the camera (None: with one camera, a free root and "
              "left/right bodies)", tristate=True, cli=Cli("--no-mirror-hypothesis"))
    swap_hypothesis: bool | None = option(
        None, "also track the pose with left/right joints exchanged (None: with one camera and joint limits)",
        tristate=True, cli=Cli("--no-swap-hypothesis"))
    hypothesis_smoothing: float = option(0.2, "a new frame's weight in every hypothesis's running fit (IoU)",
                                         range=Range(0.0, 1.0, open_lo=True))
    mirror_margin: float = option(0.0, "how far the mirror's running fit must lead to replace the pose",
                                  range=Range(0.0))
    swap_margin: float = option(0.01, "how far the swapped pose's running fit must lead to replace the pose",
                                range=Range(0.0))
    hypothesis_iterations: int | None = option(
        None, "ECM iterations of each alternative a frame (None: as max_iterations)",
        range=Range(1, whole=True, none_ok=True))
    binned_hypotheses: bool = option(False, "track the alternatives on masks binned 2x2 (faster, less accurate)",
                                     cli=Cli("--binned-hypotheses"))
    second_track: str = option(
        "", "track the frames a second time beside, with these options changed (NAME=VALUE, comma separated: "
            "midline=1), and report on each frame the pose of the tracks that fits best, each track going on "
            "by itself (twice the time; more tracks: their changes separated by ';'; '': off)",
        cli=Cli("--second-track", "NAME=VALUE,..."))

    def _check(self) -> None:
        track_changes(self.second_track)  # its syntax and names; its values in TrackerOptions


@_documented
class LimbSearchOptions(_Group):
    """The limb search: limbs swung the other way, put back at rest, twins exchanged."""

    limb_search: bool | None = option(
        None, "when the fit falls more than limb_search_drop below the running fit, try every limb swung the "
              "other way or put back at rest and twin limbs exchanged (None: on)",
        tristate=True, cli=Cli("--no-limb-search"))
    limb_search_drop: float = option(0.015, "the fall in fit (IoU) that starts the limb search (in Python also "
                                            "negative: every frame)", range=Range(-np.inf),
                                     cli=Cli("--limb-search-drop", "D", lo=0.0))
    limb_hypothesis: bool | None = option(
        None, "on a smaller fall, track the best candidate beside the pose (None: with one camera and the "
              "limb search)", tristate=True, cli=Cli("--no-limb-hypothesis"))
    limb_hypothesis_drop: float = option(0.005, "the fall in fit that spawns the limb-search hypothesis",
                                         range=Range(-np.inf))
    limb_margin: float = option(0.005, "how far that hypothesis's running fit must lead to replace the pose",
                                range=Range(0.0))
    reach_search: bool = option(False, "re-aim a limb whose body lies over the background in some camera, "
                                       "or next to a blob of the masks the model leaves unexplained, pointing "
                                       "it at the masks (kms2pin.ecm.reach)", cli=Cli("--reach-search"))
    reach_always: str = option(
        "none", "the limbs the reach search also re-aims on frames where they are neither lost nor missed: the "
                "'arms' (the limbs that do not reach the floor at the first pose), every one of the 'limbs' (a "
                "spherical joint with one hinge below), or 'none'", choices=("none", "arms", "limbs"),
        cli=Cli("--reach-always", "WHICH"))
    reach_skip: bool = option(True, "a search whose trials all score below the pose as it is (the coarse score) "
                                    "screens none of them (faster; the screening finds better poses the coarse "
                                    "score ranks lower)", cli=Cli("--no-reach-skip"))
    reach_always_directions: int = option(
        3, "how many of its best-scoring directions the reach search screens for a limb it re-aims on every frame "
           "(reach_always; a lost or missed limb screens 6): 6 is slower and, on real walks, within the runs' "
           "spread of 3", range=Range(1, whole=True), cli=Cli("--reach-always-directions", "N"))
    reach_rest: int = option(
        2, "how many frames a limb whose reach search found nothing waits before it is searched again (0: "
           "searched on every frame it is lost, missed or re-aimed always; slower)",
        range=Range(0, whole=True), cli=Cli("--reach-rest", "N"))


#: the groups of :class:`TrackerOptions`: attribute name -> class
GROUPS: dict[str, type] = {
    "iteration": IterationOptions,
    "silhouette": SilhouetteOptions,
    "mstep": MStepOptions,
    "springs": SpringOptions,
    "sizes": SizeOptions,
    "priors": PriorOptions,
    "hypotheses": HypothesisOptions,
    "limbs": LimbSearchOptions,
}

#: every option's flat name -> its group's attribute name
OPTION_GROUP: dict[str, str] = {f.name: g for g, cls in GROUPS.items() for f in dataclasses.fields(cls)}
#: the options whose values are vectors (tuples)
_VECTORS = {f.name for cls in GROUPS.values() for f in dataclasses.fields(cls) if isinstance(f.default, tuple)}

def _value(text: str) -> Any:
    """An option's value written as text: true/false/none (any case), a number, else the text."""
    low = text.strip().lower()
    if low in ("true", "false", "none"):
        return {"true": True, "false": False, "none": None}[low]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text.strip()


def track_changes(text: str) -> tuple[dict[str, Any], ...]:
    """The option changes of each track beside the first that ``second_track`` asks for
    (``"midline=1; reach_rest=2"`` -> two dicts, each of changes to the options as given;
    ``""`` -> none): :func:`second_changes` of each part between ';'."""
    if not isinstance(text, str):
        raise OptionError(f"second_track must be text such as 'midline=1', not {text!r}")
    parts = text.split(";")
    if len(parts) > 1 and not all(p.strip() for p in parts):
        raise OptionError(f"second_track: a track between ';' changes nothing in {text!r} (it would be the first "
                          f"track again)")
    return tuple(c for c in (second_changes(p) for p in parts) if c)


def second_changes(text: str) -> dict[str, Any]:
    """The option changes of one track of ``second_track`` (``"midline=1,reach_rest=2"`` -> a dict); an
    :class:`OptionError` naming the part that is not NAME=VALUE with an option's name (the
    values are checked with the options they change, by :class:`TrackerOptions`)."""
    changes: dict[str, Any] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, eq, value = part.partition("=")
        name = name.strip()
        if not eq or not name:
            raise OptionError(f"second_track: {part!r} is not NAME=VALUE")
        if name == "second_track":
            raise OptionError("second_track: the second track has no second track of its own")
        if name not in OPTION_GROUP:
            raise OptionError(f"second_track: unknown option '{name}'{did_you_mean(name, list(OPTION_GROUP))}")
        if name in _VECTORS:
            raise OptionError(f"second_track: {name} is a vector, which NAME=VALUE cannot write; give it to both "
                              f"tracks instead")
        changes[name] = _value(value)
    return changes


#: the priors' weights: each a spring of the 'full' static update only
PRIOR_WEIGHTS = ("depth_prior", "upright", "rest_prior", "twist_prior", "spine_twist", "midline", "ground")


@dataclass(frozen=True)
class TrackerOptions:
    """Every option of :class:`~kms2pin.ecm.tracker.Tracker`, one frozen group each.

    ``TrackerOptions().replace(upright=0.1)`` takes the flat names; a misspelt one
    raises TypeError with a did-you-mean, a bad value :class:`OptionError`.
    """

    iteration: IterationOptions = field(default_factory=IterationOptions)
    silhouette: SilhouetteOptions = field(default_factory=SilhouetteOptions)
    mstep: MStepOptions = field(default_factory=MStepOptions)
    springs: SpringOptions = field(default_factory=SpringOptions)
    sizes: SizeOptions = field(default_factory=SizeOptions)
    priors: PriorOptions = field(default_factory=PriorOptions)
    hypotheses: HypothesisOptions = field(default_factory=HypothesisOptions)
    limbs: LimbSearchOptions = field(default_factory=LimbSearchOptions)

    def __post_init__(self) -> None:
        for name, cls in GROUPS.items():
            if not isinstance(getattr(self, name), cls):
                raise OptionError(f"{name} must be a {cls.__name__}, not {getattr(self, name)!r}")
        for changes in track_changes(self.hypotheses.second_track):
            try:  # each further track's options: these with its changes (its own second_track empty)
                self.replace(second_track="", **changes)
            except OptionError as err:
                raise OptionError(f"second_track: {err}") from None
        on = [f"{k}={getattr(self.priors, k)!r}" for k in PRIOR_WEIGHTS if getattr(self.priors, k) > 0]
        if self.springs.static == "diagonal" and on:
            raise OptionError(f"static='diagonal' (the thesis's diagonal springs) has no terms for the priors, "
                              f"but {', '.join(on)} is set: use static='full' (the default) or turn them off")

    def replace(self, **overrides: Any) -> TrackerOptions:
        """These options with some changed, by flat name (``upright=0.1``) or whole group
        (``priors=PriorOptions(...)``)."""
        groups: dict[str, dict] = {}
        whole = {}
        for name, value in overrides.items():
            if name in GROUPS:
                whole[name] = value
            elif name in OPTION_GROUP:
                groups.setdefault(OPTION_GROUP[name], {})[name] = value
            else:
                raise TypeError(f"Tracker got an unknown option '{name}'{did_you_mean(name, list(OPTION_GROUP))}")
        changed = {g: dataclasses.replace(whole.get(g, getattr(self, g)), **kw) for g, kw in groups.items()}
        return dataclasses.replace(self, **{**whole, **changed})

    def flat(self) -> dict[str, Any]:
        """Every option by its flat name."""
        return {name: getattr(getattr(self, g), name) for name, g in OPTION_GROUP.items()}


@dataclass(frozen=True)
class Preset(Mapping):
    """A named set of options for a kind of input: ``Tracker(robot, cams, options=PRESET)``,
    ``PRESET.options.replace(...)``, or, as before presets, ``Tracker(robot, cams, **PRESET)``."""

    name: str
    overrides: Mapping[str, Any]

    @property
    def options(self) -> TrackerOptions:
        return TrackerOptions().replace(**self.overrides)

    def __getitem__(self, key: str) -> Any:
        return self.overrides[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.overrides)

    def __len__(self) -> int:
        return len(self.overrides)


#: masks from a real segmentation (``track --video`` uses it): the fit is noisy, and the
#: limb search on a fall of 0.015 fired on many frames (docs/design/tracking-history.md, video)
SEGMENTED_MASKS = Preset("segmented masks", {"limb_search_drop": 0.03})
#: real people (their shape not the model's ellipsoids, arms thin and fast): the learnt
#: motion model, the reach search (the arms re-aimed on every frame, each search screened:
#: an arm lost in front of the trunk is neither lost nor missed; a limb searched again on
#: the next frame even when its search found nothing), the spine's twist held near rest
#: and the round limbs' within 90° of it, which no silhouette shows (docs/tracking.md,
#: "Real motion")
_PEOPLE = {"prediction": "learnt", "reach_search": True}
PEOPLE = Preset("people", {**_PEOPLE, "reach_always": "arms", "reach_skip": False, "reach_rest": 0, "spine_twist": 0.05,
                           "twist_prior": 1.0, "twist_free": 90.0})
#: :data:`PEOPLE` with three tracks beside it (``second_track``): the thighs held off the
#: midline, that and the legs' midline prior, a shorter motion memory; each frame the
#: best-fitting pose of the four, then each part from the others where that fits better.
#: The most accurate online choice with two or more cameras, at about a fifth of
#: ``PEOPLE``'s frames/s (``jobs`` spreads the tracks over processes); offline add
#: ``track --stretches`` (docs/tracking.md, "Real motion")
PEOPLE_TRACKS = Preset("people, four tracks", {**PEOPLE.overrides,
                                               "second_track": "midline=1; midline=1,midline_legs=0.1; "
                                                               "prediction_memory=3"})
#: a person walking or standing, seen by one camera: :data:`PEOPLE` without the twist
#: priors (they made the one-camera walk worse), and the upright, rest and ground priors
#: hold what one view does not fix (the rest: the starting pose, the way the subject
#: stands; the ground: the floor at the lowest foot of q0, along ``up``; docs/tracking.md,
#: docs/design/tracking-history.md)
PEOPLE_ONE_CAMERA = Preset("people, one camera", {**_PEOPLE, "upright": 0.1, "rest_prior": 0.01, "rest_pose": "start",
                                                  "ground": 0.1})


def resolved(opts: TrackerOptions, robot, n_cameras: int, sagittal, symmetry) -> TrackerOptions:
    """``opts`` with the automatic choices (None) decided for ``robot`` (a
    :class:`~kms2pin.robot.Robot`) seen by ``n_cameras``, its left/right reflection
    ``sagittal`` and twin joints ``symmetry`` (None where it has none): the one-camera
    hypotheses, the limb search."""
    one = n_cameras == 1
    hyp, lim = opts.hypotheses, opts.limbs
    if hyp.mirror_hypothesis and sagittal is None:
        raise ValueError("mirror_hypothesis needs root='free' and left/right bodies (names with left/right)")
    if hyp.swap_hypothesis and symmetry is None:
        raise ValueError(
            "swap_hypothesis needs left/right joints (names such as left*/right*, *_l/*_r) whose exchange mirrors "
            "the body"
        )
    search = True if lim.limb_search is None else bool(lim.limb_search)
    # without joint limits a swapped leg finds a pose (a knee bent backwards) that fits
    # as well, and the swaps did more harm than good on the benchmark
    auto = {
        "mirror_hypothesis": one and sagittal is not None,
        "swap_hypothesis": one and symmetry is not None and robot.has_limits,
        "limb_hypothesis": one,
        "hypothesis_iterations": opts.iteration.max_iterations,
    }
    flat = opts.flat()
    decided = {k: (auto[k] if flat[k] is None else flat[k]) for k in auto}
    decided["mirror_hypothesis"] = bool(decided["mirror_hypothesis"])
    decided["swap_hypothesis"] = bool(decided["swap_hypothesis"])
    decided["limb_hypothesis"] = bool(decided["limb_hypothesis"]) and search
    return opts.replace(limb_search=search, **decided)


def as_options(options: TrackerOptions | Preset | None, overrides: Mapping[str, Any]) -> TrackerOptions:
    """``options`` (default: the defaults; a preset's options) with ``overrides`` by flat name."""
    if options is None:
        base = TrackerOptions()
    elif isinstance(options, Preset):
        base = options.options
    elif isinstance(options, TrackerOptions):
        base = options
    else:
        raise OptionError(f"options must be a TrackerOptions or a preset, not {type(options).__name__}")
    return base.replace(**overrides) if overrides else base


def cli_fields() -> list[dataclasses.Field]:
    """The options that ``kms2pin track`` has a flag for, in declaration order."""
    return [f for cls in GROUPS.values() for f in dataclasses.fields(cls) if f.metadata.get("cli") is not None]


def is_switch(f: dataclasses.Field) -> bool:
    """Whether a field is a switch (bool or tri-state), not a number or a vector."""
    return isinstance(f.default, bool) or bool(f.metadata.get("tristate"))


def cli_dest(f: dataclasses.Field) -> str:
    """The argparse destination of an option's flag: the option's name
    (``--no-size-calibration`` sets ``calibrate_sizes`` to False)."""
    return f.name


def cli_number_range(f: dataclasses.Field) -> tuple[float, bool, bool]:
    """(lowest, excluded, whole) of an option's flag: its range, tightened by ``Cli.lo``
    and opened to include the value that stands for None."""
    rng: Range = f.metadata["range"]
    cli: Cli = f.metadata["cli"]
    lo, open_lo = rng.lo, rng.open_lo
    if cli.lo is not None and cli.lo > lo:
        lo, open_lo = cli.lo, False
    if cli.none is not None and cli.none == lo:
        open_lo = False
    return (lo if math.isfinite(lo) else -math.inf), open_lo, rng.whole
