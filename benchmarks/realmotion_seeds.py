"""Real human motion over many noise seeds, and a variant measured against the preset seed
by seed (issue #31).  One run of ``realmotion.py`` is one draw: with two cameras at
320x240 the seeds' spread (sd 18-19 mm) is larger than most changes to the tracker, so a
change is judged over about twenty seeds, paired.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realmotion_seeds.py --only walk-2cam-320
        --seeds 0-19 [--jobs 2] [--option NAME=VALUE] [--variant NAME=VALUE[,NAME=VALUE...]]
        [--frames N] [--bvh FILE] [--cache DIR] [--both-ways] [--beside] [--stretches] [--temporal]

Per case: the mean joint error of each seed (mm, the 13 joints of ``realmotion.py``), then
over the seeds their mean, median, range and standard deviation; the median over the
seeds of the worst frame (and its range), of the frames above 120 mm, of the legs' (hips, knees, ankles)
and the arms' (shoulders, elbows, wrists) error; the knees' and elbows' flexion RMSE; the
silhouette fit (IoU) of the track and of the floor poses (``realmotion.fits``); the same
track smoothed (``realmotion.SMOOTH_HZ``, as ``track --smooth``): its mean error and
flexion RMSE; with ``--both-ways`` the track made both ways (``track --both-ways``,
:mod:`kms2pin.ecm.bothways`), raw and smoothed, against the forward track, and smoothed
with the whole poses alone (before the parts); with ``--beside`` the forward track's
parts taken from the frames beside, without a backward pass (``track --beside``),
smoothed, against the forward track smoothed; with ``--stretches`` (and tracks beside:
``second_track`` in ``--option`` or ``--variant``) each stretch from the track that fits it
best, then the parts (``track --stretches``, :mod:`kms2pin.ecm.stretches`), raw and
smoothed, against the track as it was tracked, and the whole poses alone; with ``--temporal``
the finished track (the stretches' with ``--stretches``, else the track) refit over time
(``track --temporal``, :mod:`kms2pin.ecm.temporal`), raw and smoothed, against that track
and its process time per frame, each arm's elbow and wrist after it (and which arm is the
farther from the cameras, :func:`far_arm`, and which held nearer the trunk, :func:`lower_arm`),
and against the refit without the limbs searched again
(``--temporal-sweeps 8 --temporal-searches none --temporal-spans none``, the refit of the twenty-ninth
session); frames/s of
process time of the forward track (the median of the seeds; every job has a core to itself only with
``--jobs`` at most the cores).  With ``--variant``: the same for the preset with those
options too, and the paired difference (variant - preset) of the seeds' means with its
standard error, and on how many seeds the variant is better.
"""

from __future__ import annotations

import argparse
import functools
import os
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import realmotion as rm  # noqa: E402

from kms2pin.ecm.bothways import MARGIN, beside, both_ways, choose  # noqa: E402
from kms2pin.ecm.stretches import stretches  # noqa: E402
from kms2pin.ecm.temporal import SEARCHES, SWEEPS, temporal  # noqa: E402

#: the 13 joints' places in realmotion.JOINTS: the legs', the arms'
LEGS, ARMS = slice(0, 6), slice(6, 12)
#: each arm's shoulder, elbow and wrist in realmotion.JOINTS: the left's, the right's
SIDES = tuple(tuple(rm.JOINTS.index(j) for j in arm)
              for arm in (("LeftShoulder", "LeftElbow", "lhand"), ("RightShoulder", "RightElbow", "rhand")))
#: the hips' and the neck's places in realmotion.JOINTS (the trunk's axis)
HIPS, NECK = (rm.JOINTS.index("LeftHip"), rm.JOINTS.index("RightHip")), rm.JOINTS.index("Neck")
#: a flexed joint's place in realmotion.JOINTS -> its column of realmotion.flexion
FLEXED = {joint: k for k, (joint, _, _) in enumerate(rm.FLEXION.values())}


def far_arm(truth: np.ndarray, cameras) -> int:
    """Which arm (0 the left, 1 the right: :data:`SIDES`) is the farther from the cameras: the
    one whose true shoulder is the farther from their centres on average (``truth`` (frames, 13, 3))."""
    centres = np.array([c.centre for c in cameras])
    far = [np.linalg.norm(truth[:, side[0], None, :] - centres[None], axis=2).mean() for side in SIDES]
    return int(far[1] > far[0])


def lower_arm(truth: np.ndarray) -> int:
    """Which arm (0 the left, 1 the right) is held nearer the trunk: the one whose true upper
    arm is the nearer the trunk's downward axis (from the neck to the hips' midpoint), by
    the median angle over the frames."""
    down = (truth[:, HIPS[0]] + truth[:, HIPS[1]]) / 2 - truth[:, NECK]
    down /= np.linalg.norm(down, axis=1, keepdims=True)
    angles = []
    for shoulder, elbow, _ in SIDES:
        bone = truth[:, elbow] - truth[:, shoulder]
        bone /= np.linalg.norm(bone, axis=1, keepdims=True)
        angles.append(np.median(np.arccos(np.clip(np.sum(bone * down, axis=1), -1.0, 1.0))))
    return int(angles[1] < angles[0])


@functools.cache
def _sequence(bvh: Path, motion: str, frames: int | None) -> rm.Sequence:
    return rm.load_sequence(bvh, motion, frames)


def track_seed(job: tuple) -> dict:
    """One case's track on one seed's masks: its figures (module docstring)."""
    name, bvh, frames, seed, cache, options, two_ways, one_beside, stretch, over_time = job
    motion, n, factor, preset = rm.CASES[name]
    seq = _sequence(bvh, motion, frames)
    cameras = rm.rig(seq.path, n, factor)
    masks = rm.rendered(seq.subject, seq.q, cameras, "capsule", seed, cache)
    tracks = [] if stretch and options.get("second_track") else None
    q, fps, _, tracker = rm.track(seq, cameras, masks, {**preset, **options}, clock=time.process_time, tracks=tracks)
    truth = np.array([rm.points(seq.subject, x, rm.JOINTS) for x in seq.q])
    flex_true = rm.flexion(truth)

    def scored(qs) -> tuple[np.ndarray, np.ndarray]:  # (frames, 13) joint errors (mm), (frames, 4) flexion errors
        pts = np.array([rm.points(seq.model, x, rm.JOINTS) for x in qs])
        return np.linalg.norm(pts - truth, axis=2) * 1e3, rm.flexion(pts) - flex_true

    def smoothed(qs) -> tuple[np.ndarray, np.ndarray]:
        return scored(rm.smooth(seq.model, qs, rm.FPS, rm.SMOOTH_HZ))

    err, flex = scored(q)
    fit, fit_floor = rm.fits(tracker, q, masks), rm.fits(tracker, seq.floor, masks)
    frame = err.mean(axis=1)
    err_s, flex_s = smoothed(q)
    row = {"mean": frame.mean(), "worst": frame.max(), "over120": int(np.sum(frame > 120.0)),
           "legs": err[:, LEGS].mean(), "arms": err[:, ARMS].mean(), "knees2": (flex[:, :2] ** 2).mean(),
           "elbows2": (flex[:, 2:] ** 2).mean(), "fit": fit.mean(), "fit_floor": fit_floor.mean(),
           "floor_better": float(np.mean(fit_floor > fit)), "fps": fps,
           "smoothed": err_s.mean(), "knees2_smoothed": (flex_s[:, :2] ** 2).mean(),
           "elbows2_smoothed": (flex_s[:, 2:] ** 2).mean()}
    if one_beside:  # --beside: the forward track's parts from the frames beside, at the sizes it ended with
        bs = beside(tracker, masks, q)
        err_x, flex_x = smoothed(bs.q)
        row |= {"beside_smoothed": err_x.mean(), "elbows2_beside": (flex_x[:, 2:] ** 2).mean(),
                "knees2_beside": (flex_x[:, :2] ** 2).mean(), "beside_only_frames": float(bs.taken.any(axis=1).mean())}
    if tracks is not None:  # --stretches: each stretch from the track that fits it best, then the parts
        tracks = np.array(tracks)
        st = stretches(tracker, masks, tracks)
        err_t, flex_t = scored(st.q)
        err_ts, flex_ts = smoothed(st.q)
        whole = tracks[np.arange(len(masks)), st.track]
        row |= {"stretches": err_t.mean(), "worst_stretches": err_t.mean(axis=1).max(),
                "over120_stretches": int(np.sum(err_t.mean(axis=1) > 120.0)), "stretches_smoothed": err_ts.mean(),
                "worst_stretches_smoothed": err_ts.mean(axis=1).max(),
                "knees2_stretches": (flex_ts[:, :2] ** 2).mean(), "elbows2_stretches": (flex_ts[:, 2:] ** 2).mean(),
                "knees2_stretches_raw": (flex_t[:, :2] ** 2).mean(), "elbows2_stretches_raw": (flex_t[:, 2:] ** 2).mean(),
                "stretches_whole": scored(whole)[0].mean(), "stretches_whole_smoothed": smoothed(whole)[0].mean(),
                "changes": int(np.sum(st.track[1:] != st.track[:-1]))}
    if over_time:  # --temporal: the finished track refit over time
        base = st.q if tracks is not None else q
        t0 = time.process_time()
        tm = temporal(tracker, masks, base)
        seconds = (time.process_time() - t0) / len(masks)
        t0 = time.process_time()
        kept = temporal(tracker, masks, base, sweeps=8, searches=(), spans=())  # the refit before the searches
        row |= {"temporal_kept": scored(kept.q)[0].mean(), "temporal_kept_smoothed": smoothed(kept.q)[0].mean(),
                "temporal_kept_ms": 1e3 * (time.process_time() - t0) / len(masks)}
        (err_m, flex_m), (err_ms, flex_ms) = scored(tm.q), smoothed(tm.q)
        err_b = scored(base)[0]
        row |= {"far_arm": far_arm(truth, cameras), "lower_arm": lower_arm(truth)}
        for side, (_, elbow, wrist) in zip(("left", "right"), SIDES):
            row |= {f"{side}_elbow": err_m[:, elbow].mean(), f"{side}_wrist": err_m[:, wrist].mean(),
                    f"{side}_flexion2": (flex_m[:, FLEXED[elbow]] ** 2).mean()}
        row |= {"temporal": err_m.mean(), "temporal_base": err_b.mean(), "temporal_smoothed": err_ms.mean(),
                "worst_temporal": err_m.mean(axis=1).max(), "over120_temporal": int(np.sum(err_m.mean(axis=1) > 120.0)),
                "knees2_temporal": (flex_m[:, :2] ** 2).mean(), "elbows2_temporal": (flex_m[:, 2:] ** 2).mean(),
                "knees2_temporal_smoothed": (flex_ms[:, :2] ** 2).mean(),
                "elbows2_temporal_smoothed": (flex_ms[:, 2:] ** 2).mean(), "temporal_ms": 1e3 * seconds}
    if two_ways:  # --both-ways: the frames tracked backwards too, the better-fitting pose kept (track --both-ways)
        bw = both_ways(seq.model, cameras, masks, q, **{**preset, **options})
        err_b, flex_b = smoothed(bw.q)
        frame_by_frame = choose(bw.fit_forward, bw.fit_backward, bw.apart, MARGIN, 0.0)
        q_back = np.array([r.q for r in bw.results])
        q_frames = np.where(frame_by_frame[:, None], q_back, q)
        err_bb, _ = scored(q_frames)
        err_bw = scored(bw.q)[0]
        q_whole = np.where(bw.backward[:, None], q_back, q)  # before the limbs' parts
        err_w, flex_w = smoothed(q_whole)
        row |= {"both_ways": err_bw.mean(), "both_smoothed": err_b.mean(),
                "knees2_both": (flex_b[:, :2] ** 2).mean(), "elbows2_both": (flex_b[:, 2:] ** 2).mean(),
                "backward": float(bw.backward.mean()), "both_frames": err_bb.mean(),
                "worst_both": err_bw.mean(axis=1).max(),
                "over120_both": int(np.sum(err_bw.mean(axis=1) > 120.0)),
                "both_frames_smoothed": smoothed(q_frames)[0].mean(),
                "both_whole_smoothed": err_w.mean(), "elbows2_whole": (flex_w[:, 2:] ** 2).mean(),
                "part_frames": float(bw.parts.any(axis=1).mean()),
                "beside_frames": float(bw.beside.any(axis=1).mean())}
    return row


def report(label: str, rows: list[dict]) -> str:
    """The figures over the seeds of one case and option set."""
    means = np.array([r["mean"] for r in rows])
    smoothed = np.array([r["smoothed"] for r in rows])

    def med(key: str) -> float:
        return float(np.median([r[key] for r in rows]))

    sd = f", sd {means.std(ddof=1):.1f}" if len(means) > 1 else ""
    clean = sum(r["over120"] == 0 for r in rows)  # seeds with no frame above 120 mm
    return (f"{label}\n    mean error per seed: {' '.join(f'{m:.1f}' for m in means)}\n"
            f"    over the seeds: mean {means.mean():.1f} mm, median {np.median(means):.1f}, range "
            f"{means.min():.1f}-{means.max():.1f}{sd}; worst frame {med('worst'):.0f} (the seeds' median; "
            f"{min(r['worst'] for r in rows):.0f}-{max(r['worst'] for r in rows):.0f}), frames above 120 mm "
            f"{med('over120'):.0f} (median; none on {clean} of {len(rows)} seeds); legs {med('legs'):.1f}, arms {med('arms'):.1f} mm; flexion RMSE knees "
            f"{np.sqrt(np.mean([r['knees2'] for r in rows])):.1f}, elbows {np.sqrt(np.mean([r['elbows2'] for r in rows])):.1f} "
            f"deg; fit tracked {med('fit'):.3f}, floor {med('fit_floor'):.3f} (the floor better on "
            f"{med('floor_better'):.0%} of the frames); {med('fps'):.1f} frames/s (process time)\n"
            f"    smoothed at {rm.SMOOTH_HZ:g} Hz (track --smooth): mean {smoothed.mean():.1f} mm, median "
            f"{np.median(smoothed):.1f}, the seeds' means {np.mean(smoothed - means):+.1f} mm; flexion RMSE knees "
            f"{np.sqrt(np.mean([r['knees2_smoothed'] for r in rows])):.1f}, elbows "
            f"{np.sqrt(np.mean([r['elbows2_smoothed'] for r in rows])):.1f} deg" + _beside(rows, smoothed)
            + _both(rows, means) + _stretches(rows, means, smoothed) + _temporal(rows))


def _beside(rows: list[dict], smoothed: np.ndarray) -> str:
    """The ``--beside`` line of :func:`report` (empty without it)."""
    if "beside_smoothed" not in rows[0]:
        return ""
    x = np.array([r["beside_smoothed"] for r in rows])
    d = x - smoothed
    se = f" +- {d.std(ddof=1) / np.sqrt(len(d)):.2f}" if len(d) > 1 else ""
    return (f"\n    the frames beside (track --beside, a part taken on {np.median([r['beside_only_frames'] for r in rows]):.0%} "
            f"of the frames, median), smoothed: mean {x.mean():.1f} mm, median {np.median(x):.1f}; against the forward "
            f"track smoothed {d.mean():+.2f}{se} mm, better on {int(np.sum(d < 0))} of {len(d)}; flexion RMSE knees "
            f"{np.sqrt(np.mean([r['knees2_beside'] for r in rows])):.1f}, elbows "
            f"{np.sqrt(np.mean([r['elbows2_beside'] for r in rows])):.1f} deg")


def _against(x: np.ndarray, base: np.ndarray, digits: int) -> str:
    """The seeds' ``x`` against ``base``, paired: the mean difference, its standard error, and
    on how many seeds ``x`` is lower."""
    d = x - base
    se = f" +- {d.std(ddof=1) / np.sqrt(len(d)):.{digits}f}" if len(d) > 1 else ""
    return f"{d.mean():+.{digits}f}{se} mm, better on {int(np.sum(d < 0))} of {len(d)}"


def _both(rows: list[dict], means: np.ndarray) -> str:
    """The ``--both-ways`` line of :func:`report` (empty without it)."""
    if "both_ways" not in rows[0]:
        return ""
    both, smoothed = np.array([r["both_ways"] for r in rows]), np.array([r["both_smoothed"] for r in rows])
    frames, frames_s = np.array([r["both_frames"] for r in rows]), np.array([r["both_frames_smoothed"] for r in rows])
    whole = np.array([r["both_whole_smoothed"] for r in rows])

    def against(x: np.ndarray) -> str:
        return _against(x, means, 1)

    return (f"\n    both ways (track --both-ways): mean {both.mean():.1f} mm, median {np.median(both):.1f} (the backward "
            f"pose kept on {np.median([r['backward'] for r in rows]):.0%} of the frames, median; worst frame "
            f"{np.median([r['worst_both'] for r in rows]):.0f}, none above 120 mm on "
            f"{sum(r['over120_both'] == 0 for r in rows)} of {len(rows)} seeds); against the forward track "
            f"{against(both)}; smoothed too: mean {smoothed.mean():.1f}, median {np.median(smoothed):.1f} "
            f"({against(smoothed)}), flexion RMSE knees "
            f"{np.sqrt(np.mean([r['knees2_both'] for r in rows])):.1f}, elbows "
            f"{np.sqrt(np.mean([r['elbows2_both'] for r in rows])):.1f} deg\n"
            f"    both ways frame by frame (choose with switch 0, before the switch cost): mean {frames.mean():.1f}, "
            f"median {np.median(frames):.1f} ({against(frames)}); smoothed mean {frames_s.mean():.1f}, median "
            f"{np.median(frames_s):.1f} ({against(frames_s)})\n"
            f"    both ways, whole poses only (before the limbs' parts, taken from the other track on "
            f"{np.median([r['part_frames'] for r in rows]):.0%} of the frames and from the frames beside on "
            f"{np.median([r['beside_frames'] for r in rows]):.0%}, medians), smoothed: mean "
            f"{whole.mean():.1f}, median {np.median(whole):.1f} ({against(whole)}; the parts and the frames beside "
            f"{np.mean(smoothed - whole):+.2f} mm), elbows {np.sqrt(np.mean([r['elbows2_whole'] for r in rows])):.1f} deg")


def _stretches(rows: list[dict], means: np.ndarray, smoothed: np.ndarray) -> str:
    """The ``--stretches`` lines of :func:`report` (empty without them)."""
    if "stretches" not in rows[0]:
        return ""

    def col(key: str) -> np.ndarray:
        return np.array([r[key] for r in rows])

    def against(x: np.ndarray, base: np.ndarray) -> str:
        return _against(x, base, 2)

    def rms(key: str) -> float:
        return float(np.sqrt(np.mean(col(key))))

    raw, sm = col("stretches"), col("stretches_smoothed")
    return (f"\n    stretches (track --stretches; {np.median(col('changes')):.0f} changes of track, median): mean "
            f"{raw.mean():.1f} mm, median {np.median(raw):.1f}, worst frame {np.median(col('worst_stretches')):.0f} "
            f"(median; max {col('worst_stretches').max():.0f}), none above 120 mm on "
            f"{sum(r['over120_stretches'] == 0 for r in rows)} of {len(rows)} seeds (frames above 120 mm "
            f"{int(col('over120_stretches').sum())} in all, against {sum(r['over120'] for r in rows)}); against the "
            f"track {against(raw, means)}; flexion RMSE knees {rms('knees2_stretches_raw'):.1f}, elbows "
            f"{rms('elbows2_stretches_raw'):.1f} deg\n"
            f"    stretches smoothed: mean {sm.mean():.1f} mm, median {np.median(sm):.1f}, worst frame "
            f"{np.median(col('worst_stretches_smoothed')):.0f} (median); against the track smoothed "
            f"{against(sm, smoothed)}; flexion RMSE knees {rms('knees2_stretches'):.1f}, elbows "
            f"{rms('elbows2_stretches'):.1f} deg\n"
            f"    stretches, whole poses only (before the parts): mean {col('stretches_whole').mean():.1f} mm "
            f"({against(col('stretches_whole'), means)}), smoothed {col('stretches_whole_smoothed').mean():.1f}")


def _temporal(rows: list[dict]) -> str:
    """The ``--temporal`` lines of :func:`report` (empty without them)."""
    if "temporal" not in rows[0]:
        return ""

    def col(key: str) -> np.ndarray:
        return np.array([r[key] for r in rows])

    def rms(key: str) -> float:
        return float(np.sqrt(np.mean(col(key))))

    raw, sm, base = col("temporal"), col("temporal_smoothed"), col("temporal_base")
    return (f"\n    refit over time (track --temporal, of the {'stretches' if 'stretches' in rows[0] else 'track'}; "
            f"{np.median(col('temporal_ms')):.0f} ms a frame, median): mean {raw.mean():.1f} mm, median "
            f"{np.median(raw):.1f}, worst frame {np.median(col('worst_temporal')):.0f} (median; max "
            f"{col('worst_temporal').max():.0f}), none above 120 mm on {sum(r['over120_temporal'] == 0 for r in rows)} "
            f"of {len(rows)} seeds; against what it refit {_against(raw, base, 2)}; flexion RMSE knees "
            f"{rms('knees2_temporal'):.1f}, elbows {rms('elbows2_temporal'):.1f} deg\n"
            f"    the refit's arms (medians of the seeds): " + "; ".join(
                f"the {side} elbow {np.median(col(side + '_elbow')):.1f} mm, wrist {np.median(col(side + '_wrist')):.1f}, "
                f"flexion RMSE {rms(side + '_flexion2'):.1f} deg" for side in ("left", "right"))
            + f" (the farther from the cameras: the {('left', 'right')[rows[0]['far_arm']]}; held nearer the trunk: "
            f"the {('left', 'right')[rows[0]['lower_arm']]})\n"
            f"    refit over time, smoothed: mean {sm.mean():.1f} mm, median {np.median(sm):.1f}; against the refit "
            f"{_against(sm, raw, 2)}; flexion RMSE knees {rms('knees2_temporal_smoothed'):.1f}, elbows "
            f"{rms('elbows2_temporal_smoothed'):.1f} deg\n"
            f"    refit over time without the limbs searched again, 8 sweeps (--temporal-sweeps 8 --temporal-searches "
            f"none --temporal-spans none; "
            f"{np.median(col('temporal_kept_ms')):.0f} ms a frame): mean {col('temporal_kept').mean():.1f} mm, smoothed "
            f"{col('temporal_kept_smoothed').mean():.1f}; the refit ({SWEEPS} sweeps, the limbs searched again before "
            f"sweeps {', '.join(map(str, SEARCHES))}) against it {_against(raw, col('temporal_kept'), 2)}, smoothed "
            f"{_against(sm, col('temporal_kept_smoothed'), 2)}")


def paired(base: list[dict], variant: list[dict]) -> str:
    """The variant's seeds' means against the preset's, seed by seed."""
    d = np.array([v["mean"] - b["mean"] for b, v in zip(base, variant)])
    se = f" +- {d.std(ddof=1) / np.sqrt(len(d)):.1f} (standard error)" if len(d) > 1 else ""
    return (f"    paired, variant - preset: {d.mean():+.1f} mm{se}; the variant better on {int(np.sum(d < 0))} "
            f"seeds of {len(d)}")


def parse_seeds(text: str) -> list[int]:
    """``0-19`` or ``0,3,5`` (or both: ``0-4,9``)."""
    out = []
    for part in filter(None, text.split(",")):
        lo, sep, hi = part.partition("-")
        out += list(range(int(lo), int(hi) + 1)) if sep else [int(lo)]
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", default="walk-2cam-320", help="comma-separated cases: " + ", ".join(rm.CASES))
    p.add_argument("--seeds", default="0-19", help="the masks' noise seeds: 0-19, or 0,3,5 (default 0-19)")
    p.add_argument("--jobs", type=int, default=1, help="processes (at most the cores, for the frames/s)")
    p.add_argument("--bvh", type=Path, default=rm.BVH, help="the motion capture (default: the shared CMU walk)")
    p.add_argument("--frames", type=int, help="track only the first N frames")
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="a Tracker option for every run, preset and variant (repeatable)")
    p.add_argument("--variant", metavar="NAME=VALUE[,NAME=VALUE...]",
                   help="Tracker options tracked beside the preset on every seed, and compared seed by seed "
                        "(a value with commas in quotes: second_track='midline=1,reach_rest=2')")
    p.add_argument("--both-ways", action="store_true",
                   help="also track each seed backwards and report the better-fitting pose of the two per frame "
                        "(track --both-ways; twice the time)")
    p.add_argument("--beside", action="store_true",
                   help="also take each seed's parts from the frames beside, without a backward pass "
                        "(track --beside; tens of seconds)")
    p.add_argument("--stretches", action="store_true",
                   help="with tracks beside (second_track), also keep each stretch from the track that fits it "
                        "best, then the parts (track --stretches; seconds to tens of seconds)")
    p.add_argument("--temporal", action="store_true",
                   help="also refit the finished track over time (the stretches' with --stretches; track --temporal; "
                        "seconds to a minute)")
    p.add_argument("--cache", type=Path, default=rm.CACHE,
                   help="where rendered masks are kept between runs")
    a = p.parse_args()
    try:
        seeds = parse_seeds(a.seeds)
    except ValueError:
        p.error(f"--seeds wants 0-19 or 0,3,5, not {a.seeds!r}")
    names = a.only.split(",")
    bad = [n for n in names if n not in rm.CASES]
    if bad:
        p.error(f"--only: no case {', '.join(bad)}; the cases are {', '.join(rm.CASES)}")
    options = rm.parse_options(a.option, "--option", p.error)
    sets = {"preset": options}
    if a.variant:
        sets["variant"] = {**options, **rm.parse_options(rm.split_items(a.variant), "--variant", p.error)}
    if a.stretches and not any(opts.get("second_track") for opts in sets.values()):
        p.error("--stretches chooses among tracks beside: give second_track in --option or --variant")
    jobs = [(name, a.bvh, a.frames, seed, a.cache, opts, a.both_ways, a.beside, a.stretches, a.temporal)
            for name in names for opts in sets.values()
            for seed in seeds]
    with Pool(max(1, a.jobs)) as pool:
        out = pool.map(track_seed, jobs, chunksize=1)
    k = 0
    for name in names:
        rows = {}
        for label, opts in sets.items():
            rows[label], k = out[k : k + len(seeds)], k + len(seeds)
            extra = ", ".join(f"{n}={v}" for n, v in opts.items())
            print(report(f"{name} {label}{f' ({extra})' if extra else ''}, seeds {a.seeds}", rows[label]), flush=True)
        if "variant" in rows:
            print(paired(rows["preset"], rows["variant"]), flush=True)


if __name__ == "__main__":
    main()
