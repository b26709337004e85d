"""``kms2pin track``'s offline passes over a finished track: --both-ways, --beside,
--stretches and --temporal (their arguments, notes, meta.json entries and outputs).

Each pass reads the frames again (:class:`FrameMasks`), writes its CSV atomically and
returns the poses the next pass and the outputs (``--smooth``, motion.bvh) take.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..ecm import temporal as over_time
from ..ecm.bothways import MARGIN, SWEEPS, SWITCH, TOLERANCE, beside, both_ways, parts
from ..ecm.secondtrack import flag as track_flag
from ..ecm.secondtrack import is_part_flag, is_track_flag, part_flag, track_name
from ..ecm.stretches import stretches
from ..ecm.tracker import Tracker, Trajectory
from ..ecm.trajectory import POOR_FIT, poor_fit_flag
from ..ecm.workers import usable_cores
from ..robot import Robot
from ._common import count, non_negative, positive_count
from ._outputs import replaced

if TYPE_CHECKING:
    from .track import _Frames

__all__ = ["FrameMasks", "add_offline_arguments", "frame_names", "offline_meta", "offline_notes", "offline_passes",
           "run_offline"]


def add_offline_arguments(p: argparse.ArgumentParser) -> None:
    """The offline passes' arguments."""
    p.add_argument("--both-ways", action="store_true",
                   help="also track the frames backwards from the last pose and write both_ways.csv, the "
                        "better-fitting stretches of the two tracks, changing track where they agree, then on each frame "
                        "the better-fitting parts of the two (every joint but the root with the joints below it: a "
                        "person's hips, knees, spine, shoulders, elbows, ...), then of the frames beside it (twice the time; "
                        "motion.bvh, animation.html and --smooth then use it)")
    p.add_argument("--beside", action="store_true",
                   help="also write beside.csv, the track with each part (as --both-ways takes them) taken on "
                        "each frame from the frames beside it where that fits better, without the backward pass (seconds "
                        "to tens of seconds for a few hundred frames, not a second track; motion.bvh, animation.html and --smooth then use it; "
                        "--both-ways and --stretches do this themselves)")
    p.add_argument("--stretches", action="store_true",
                   help="with tracks beside (--second-track), also write stretches.csv: each stretch of frames from "
                        "the track that fits it best over the stretch, changing track where the tracks agree, then on "
                        "each frame each part (as --both-ways takes them) from the other tracks and from the frames "
                        "beside it where that fits better (seconds to tens of seconds; motion.bvh, animation.html "
                        "and --smooth then use it)")
    p.add_argument("--temporal", action="store_true",
                   help="also write temporal.csv: the finished track (of --stretches, --both-ways or --beside if "
                        "given) refit on each frame by ECM with a spring towards the frames beside it (its target: "
                        "1/4 the frame before, 1/2 its own pose, 1/4 the frame after), in sweeps over the "
                        "recording, so that what the masks hardly fix (a thin arm, an elbow) follows the frames "
                        "around it; each frame's ECM starts from its pose and from its target, the better fit kept "
                        "(tens of seconds to a minute for a few hundred frames, in --jobs processes; motion.bvh, "
                        "animation.html and --smooth then use it)")
    p.add_argument("--temporal-weight", type=non_negative, metavar="K",
                   help=f"with --temporal, the spring's stiffness, in the frame's mean data stiffness (default "
                        f"{over_time.WEIGHT:g}; 0: ECM alone)")
    p.add_argument("--temporal-sweeps", type=positive_count, metavar="N",
                   help=f"with --temporal, the sweeps over the frames (default {over_time.SWEEPS})")
    p.add_argument("--temporal-starts", type=_starts, metavar="WHICH,...",
                   help=f"with --temporal, where each frame's ECM starts, the best fit kept: any of "
                        f"{', '.join(over_time.START_NAMES)} (its own pose, its target, the midpoint of the frames "
                        f"beside it; default {','.join(over_time.STARTS)}; each start one more ECM a frame)")
    p.add_argument("--temporal-sizes-every", type=count, metavar="N",
                   help=f"with --temporal, measure the body sizes again at the refit's poses (on every second "
                        f"frame) before every N-th sweep after the first N (default {over_time.SIZES_EVERY}; 0: the "
                        f"online track's sizes throughout)")
    p.add_argument("--temporal-searches", type=_searches, metavar="K,...",
                   help=f"with --temporal, before each of these sweeps (counted from 0) search every frame's limbs "
                        f"again from its pose by the reach search (--reach-search; a lost or missed limb, and the "
                        f"arms with --reach-always arms) (default {','.join(map(str, over_time.SEARCHES))}; none: "
                        f"no search; each search costs about as much as 4 sweeps)")
    p.add_argument("--temporal-spans", type=_spans, metavar="H,...",
                   help=f"with --temporal, how many frames away the frames beside are in each of the first "
                        f"sweeps' targets, 1 in the sweeps after them: coarse to fine in time, so that a pull "
                        f"spreads farther in a sweep (default {','.join(map(str, over_time.SPANS))}; none: 1 "
                        f"throughout)")


def offline_notes(args, n_cameras: int) -> None:
    """Notes on offline passes that do nothing as given, or little with one camera."""
    if n_cameras == 1 and args.stretches:
        # the tracks' fits do not see depth: on the real walk with one camera no better (tracking-history.md)
        print("note: --stretches with one camera: the fit that chooses among the tracks does not see depth, "
              "and on a real walk it did not make the track better (docs/tracking.md)", file=sys.stderr)
    if n_cameras == 1 and args.both_ways:
        # the better-fitting pose is not the nearer one in depth: on the real walk with one
        # camera both ways was no better (docs/design/tracking-history.md)
        print("note: --both-ways with one camera: the fit that chooses between the two tracks does not see depth, "
              "and on a real walk it did not make the track better (docs/tracking.md)", file=sys.stderr)
    if args.beside and (args.both_ways or args.stretches):
        which = "both_ways.csv" if args.both_ways else "stretches.csv"
        print(f"note: --beside with --{'both-ways' if args.both_ways else 'stretches'}: {which} already takes the "
              "frames beside, so beside.csv is not written", file=sys.stderr)
    if not args.temporal and any(x is not None for x in (args.temporal_weight, args.temporal_sweeps,
                                                           args.temporal_starts, args.temporal_sizes_every,
                                                           args.temporal_searches, args.temporal_spans)):
        print("note: --temporal-weight, --temporal-sweeps, --temporal-starts, --temporal-sizes-every, "
              "--temporal-searches and --temporal-spans set the refit of --temporal; without it they do nothing",
              file=sys.stderr)


def offline_meta(args, robot: Robot, tracker: Tracker) -> dict:
    """The offline passes' entries of meta.json."""
    meta = {}
    if args.both_ways:
        meta |= {"both_ways": True, "both_ways_margin": MARGIN, "both_ways_switch": SWITCH,
                 "both_ways_tolerance": TOLERANCE, "both_ways_parts": list(parts(robot)), "both_ways_sweeps": SWEEPS}
    if args.beside and not args.both_ways and not args.stretches:
        meta |= {"beside": True, "beside_parts": list(parts(robot)), "beside_sweeps": SWEEPS}
    if args.stretches:
        meta |= {"stretches": True, "stretches_tracks": 1 + len(tracker.tracks_beside), "stretches_switch": SWITCH,
                 "stretches_tolerance": TOLERANCE, "stretches_parts": list(parts(robot)), "stretches_sweeps": SWEEPS}
    if args.temporal:
        meta |= {"temporal": True, "temporal_weight": _weight(args), "temporal_sweeps": _sweeps(args),
                 "temporal_starts": list(_starts_of(args)), "temporal_sizes_every": _sizes_every(args),
                 "temporal_searches": list(_searches_of(args)), "temporal_spans": list(_spans_of(args))}
    return meta


def offline_passes(args) -> bool:
    """Whether any offline pass was asked for (the poses the outputs show are then not the
    online track's)."""
    return bool(args.stretches or args.both_ways or args.beside or args.temporal)


def run_offline(args, out: Path, robot: Robot, options, tracker: Tracker, frames: _Frames, results: list,
                tracks: list) -> tuple[np.ndarray, np.ndarray]:
    """The passes asked for, in order (--stretches, --both-ways or --beside, then
    --temporal), on the tracked ``results``; returns the last pass's poses (the track's
    without any) and the body sizes they were fit at (the tracker's; --temporal's own)."""
    qs, scales = np.array([r.q for r in results]), tracker.scales.copy()
    if args.stretches:
        qs = _keep_stretches(out, robot, tracker, frames, results, tracks)
    elif args.both_ways:
        qs = _track_backwards(args, out, robot, options, frames, results, tracker.jobs)
    elif args.beside:
        qs = _take_beside(out, robot, tracker, frames, results)
    if args.temporal:
        qs, scales = _refit_over_time(args, out, robot, tracker, frames, results, qs)
    return qs, scales


class FrameMasks(Sequence):
    """The frames' masks as a sequence, each read when asked for (the backward pass)."""

    def __init__(self, frames: _Frames):
        self.frames = frames

    def __len__(self) -> int:
        return len(self.frames.numbers)

    def __getitem__(self, k):
        return self.frames.load(k)


def frame_names(frames: _Frames, n: int) -> list[str]:
    """The first ``n`` frames' names in messages: the masks' files and the frame number."""
    return [f"{frames.names[k]}: frame {frames.numbers[k]}" for k in range(n)]


def _row(robot: Robot, r, q: np.ndarray, fit: float, took: list[str]):
    """A tracked frame's :class:`FrameResult` ``r`` as an offline pass left it: its fit
    ``fit`` and, where it ``took`` parts (their flags), the pose ``q``, no longer the track's."""
    if took:
        r = dataclasses.replace(r, q=q.copy(), body_poses=robot.maximal_coordinates(q), flags=(*r.flags, *took))
    return dataclasses.replace(r, fit=fit)


def _track_backwards(args, out: Path, robot: Robot, options, frames: _Frames, results: list,
                     jobs: int) -> np.ndarray:
    """``--both-ways``: the frames tracked backwards from the last pose (in ``jobs``
    processes), both_ways.csv written (:mod:`kms2pin.ecm.bothways`); returns the kept poses."""
    progress = None
    if not args.no_progress:
        from tqdm import tqdm

        def progress(it):
            return tqdm(it, unit="frame", desc="backwards")
    n = len(results)
    names = frame_names(frames, n)
    bw = both_ways(robot, frames.cameras, FrameMasks(frames), np.array([r.q for r in results]), options, margin=MARGIN,
                   switch=SWITCH, tolerance=TOLERANCE, sweeps=SWEEPS, sources=names, progress=progress, jobs=jobs)
    kept = []
    for k, (f, b, back) in enumerate(zip(results, bw.results, bw.backward)):
        r = dataclasses.replace(b, flags=(*b.flags, "kept from the backward track")) if back else f
        if not np.array_equal(bw.q[k], r.q):  # parts replaced: the online track's parts no longer there
            r = dataclasses.replace(r, flags=tuple(x for x in r.flags if not is_part_flag(x)))
        side = "forward" if back else "backward"
        took = [f"'{h}' taken from the {side} track" for h, t in zip(bw.part_names, bw.parts[k]) if t]
        took += [f"'{h}' taken from the frames beside it" for h, t in zip(bw.part_names, bw.beside[k]) if t]
        kept.append(_row(robot, r, bw.q[k], float(bw.fit[k]), took))  # every fit at the backward pass's sizes
    with replaced(out / "both_ways.csv") as tmp:
        Trajectory(robot, bw.q, kept).to_csv(tmp, frames=frames.numbers[:n])
    print(f"note: --both-ways: the backward track's pose kept on {int(bw.backward.sum())} of {n} frames, "
          f"a limb's part taken from the other track on {int(bw.parts.any(axis=1).sum())} and from the frames "
          f"beside on {int(bw.beside.any(axis=1).sum())}", file=sys.stderr)
    return bw.q


def _take_beside(out: Path, robot: Robot, tracker: Tracker, frames: _Frames, results: list) -> np.ndarray:
    """``--beside`` (without ``--both-ways``): beside.csv, the forward track with its
    parts taken from the frames beside (:func:`kms2pin.ecm.bothways.beside`, the
    fits at the last frame's body sizes); returns its poses."""
    n = len(results)
    names = frame_names(frames, n)
    bs = beside(tracker, FrameMasks(frames), np.array([r.q for r in results]), sweeps=SWEEPS, sources=names)
    kept = []
    for k, r in enumerate(results):
        took = [f"'{h}' taken from the frames beside it" for h, t in zip(bs.part_names, bs.taken[k]) if t]
        kept.append(_row(robot, r, bs.q[k], float(bs.fit[k]), took))  # every fit at the last frame's sizes
    with replaced(out / "beside.csv") as tmp:
        Trajectory(robot, bs.q, kept).to_csv(tmp, frames=frames.numbers[:n])
    print(f"note: --beside: a limb's part taken from the frames beside on {int(bs.taken.any(axis=1).sum())} of {n} "
          "frames", file=sys.stderr)
    return bs.q


def _keep_stretches(out: Path, robot: Robot, tracker: Tracker, frames: _Frames, results: list,
                    tracks: list) -> np.ndarray:
    """``--stretches``: stretches.csv, each stretch from the track that fits it best, then
    the parts (:func:`kms2pin.ecm.stretches.stretches`, the fits at the last frame's body
    sizes); returns its poses."""
    n = len(results)
    st = stretches(tracker, FrameMasks(frames), np.array(tracks), switch=SWITCH,
                   tolerance=TOLERANCE, sweeps=SWEEPS, sources=frame_names(frames, n))
    rows = []
    for k, r in enumerate(results):  # a row's other flags are its online pose's (trajectory.csv)
        fit = float(st.fit[k])
        flags = [f for f in r.flags if not is_track_flag(f) and not f.startswith(POOR_FIT)]
        flags += [track_flag(st.track[k] - 1)] if st.track[k] else []
        flags += [part_flag(h, t) for h, t in zip(st.part_names, st.parts[k]) if t >= 0]
        flags += [f"'{h}' taken from the frames beside it" for h, t in zip(st.part_names, st.beside[k]) if t]
        flags += [poor_fit_flag(fit)] if r.iterations and fit < tracker.options.silhouette.poor_fit else []
        rows.append(dataclasses.replace(r, q=st.q[k].copy(), body_poses=robot.maximal_coordinates(st.q[k]), fit=fit,
                                        flags=tuple(flags)))
    with replaced(out / "stretches.csv") as tmp:
        Trajectory(robot, st.q, rows).to_csv(tmp, frames=frames.numbers[:n])
    counts = np.bincount(st.track, minlength=st.fits.shape[1])
    held = ", ".join(f"{c} from {track_name(t)}" for t, c in enumerate(counts))
    print(f"note: --stretches: the poses of {n} frames: {held} ({int(np.sum(st.track[1:] != st.track[:-1]))} "
          f"changes of track); a limb's part taken from another track on {int((st.parts >= 0).any(axis=1).sum())} "
          f"frames and from the frames beside on {int(st.beside.any(axis=1).sum())}", file=sys.stderr)
    return st.q


def _weight(args) -> float:
    """``--temporal-weight``, or the refit's default."""
    return over_time.WEIGHT if args.temporal_weight is None else args.temporal_weight


def _sweeps(args) -> int:
    """``--temporal-sweeps``, or the refit's default."""
    return over_time.SWEEPS if args.temporal_sweeps is None else args.temporal_sweeps


def _sizes_every(args) -> int:
    """``--temporal-sizes-every``, or the refit's default."""
    return over_time.SIZES_EVERY if args.temporal_sizes_every is None else args.temporal_sizes_every


def _whole_numbers(text: str, least: int, what: str) -> tuple[int, ...]:
    """Whole numbers >= ``least``, comma-separated, in the order given, or ``none`` (empty);
    anything else names the first bad one as not ``what``."""
    if text.strip().lower() == "none":
        return ()
    out = []
    for x in text.split(","):
        try:
            k = int(x.strip())
        except ValueError:
            k = least - 1
        if k < least:
            raise argparse.ArgumentTypeError(f"{x.strip()!r} is not {what}: give whole numbers >= {least}, "
                                             "comma-separated, or none")
        out.append(k)
    return tuple(out)


def _searches(text: str) -> tuple[int, ...]:
    """``--temporal-searches``' value: sweeps' numbers (whole, >= 0), comma-separated, or ``none``."""
    return tuple(sorted(set(_whole_numbers(text, 0, "a sweep's number"))))


def _searches_of(args) -> tuple[int, ...]:
    """``--temporal-searches``, or the refit's default."""
    return over_time.SEARCHES if args.temporal_searches is None else args.temporal_searches


def _spans(text: str) -> tuple[int, ...]:
    """``--temporal-spans``' value: distances in frames (whole, >= 1), comma-separated, in
    the sweeps' order, or ``none``."""
    return _whole_numbers(text, 1, "a distance in frames")


def _spans_of(args) -> tuple[int, ...]:
    """``--temporal-spans``, or the refit's default."""
    return over_time.SPANS if args.temporal_spans is None else args.temporal_spans


def _starts(text: str) -> tuple[str, ...]:
    """``--temporal-starts``' value: names of :data:`kms2pin.ecm.temporal.START_NAMES`, comma-separated."""
    names = tuple(x.strip() for x in text.split(","))
    for x in names:
        if x not in over_time.START_NAMES:
            raise argparse.ArgumentTypeError(f"{x!r} is not a start: give any of {', '.join(over_time.START_NAMES)}, "
                                             "comma-separated")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r} names a start twice")
    return names


def _starts_of(args) -> tuple[str, ...]:
    """``--temporal-starts``, or the refit's default."""
    return over_time.STARTS if args.temporal_starts is None else args.temporal_starts


def _refit_over_time(args, out: Path, robot: Robot, tracker: Tracker, frames: _Frames, results: list,
                     qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``--temporal``: temporal.csv and temporal.npz, the finished track ``qs`` refit over time
    (:func:`kms2pin.ecm.temporal.temporal`, from the last frame's body sizes, measured
    again at its poses as it goes); returns its poses and the body sizes they were fit at."""
    progress = None
    if not args.no_progress:
        from tqdm import tqdm

        sweep = iter(range(1, _sweeps(args) + 1))

        def progress(it):
            return tqdm(it, unit="frame", desc=f"over time {next(sweep)}/{_sweeps(args)}", leave=False)
    n = len(results)
    jobs = usable_cores() if args.jobs is None else args.jobs
    tm = over_time.temporal(tracker, FrameMasks(frames), qs, weight=_weight(args), sweeps=_sweeps(args),
                            starts=_starts_of(args), sizes_every=_sizes_every(args), searches=_searches_of(args),
                            spans=_spans_of(args), sources=frame_names(frames, n),
                            progress=progress, jobs=jobs)
    rows = []
    for k, r in enumerate(results):  # the online row's flags about the frame, not about where its pose came from
        fit = float(tm.fit[k])
        flags = [f for f in r.flags if not is_track_flag(f) and not is_part_flag(f) and not f.startswith(POOR_FIT)]
        flags += [poor_fit_flag(fit)] if r.iterations and fit < tracker.options.silhouette.poor_fit else []
        rows.append(dataclasses.replace(r, q=tm.q[k].copy(), body_poses=robot.maximal_coordinates(tm.q[k]), fit=fit,
                                        flags=tuple(flags)))
    refit = Trajectory(robot, tm.q, rows, scales=tm.scales)  # temporal.npz also keeps the sizes it was fit at
    with replaced(out / "temporal.csv") as tmp:
        refit.to_csv(tmp, frames=frames.numbers[:n])
    with replaced(out / "temporal.npz") as tmp:
        refit.to_npz(tmp)
    procs = over_time.processes(jobs, n)
    every = _sizes_every(args)
    sizes = f", the body sizes measured again every {every} sweeps" if every and every < _sweeps(args) else ""
    at = [k for k in _searches_of(args) if k < _sweeps(args)] if tracker.reach is not None else []
    if at:
        sizes += f", the limbs searched again before sweep{'s' if len(at) > 1 else ''} {', '.join(map(str, at))}"
    print(f"note: --temporal: {n} frames refit over {_sweeps(args)} sweeps from {' and '.join(_starts_of(args))} "
          f"({procs} process{'es' if procs > 1 else ''}{sizes}); mean fit (IoU) "
          f"{float(tm.fit.mean()) if n else 0.0:.3f}", file=sys.stderr)
    return tm.q, tm.scales
