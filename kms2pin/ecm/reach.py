"""The reach search: a limb left over the background is pointed back at the masks.

A limb that the motion outran (an arm raised faster than one frame's ECM follows) ends
the frame over the background, or hidden in the trunk's silhouette while its image is
left unexplained, and ECM, whose pull reaches only a few pixels past a body's outline,
does not bring it back.  Such a body is *lost*: in some camera less than
:data:`COVERED` of its silhouette (at least :data:`MIN_PIXELS` pixels) falls on the
mask; and a limb is *missed* when a camera's mask has a blob the model does not cover
(after a 3x3 opening, at least :data:`BLOB` of that camera's foreground) within the
limb's reach of its joint.  The topmost lost body of each chain, and each missed limb
(a body on a spherical joint with one movable joint below it: an upper arm, a thigh),
is re-aimed, its own joint first (with the joint below kept, and put back at rest: a
limb unbent), then its child's (the one movable joint below it): a spherical joint
turned so that its body's bone (from the joint to the body's centre) points along each
of :data:`DIRECTIONS` directions spread over the sphere, the rest of its rotation kept;
a revolute joint set to angles :data:`STEP_DEG` apart within its limits.  A spherical
joint with a hinge below it (an upper arm above an elbow, a thigh above a knee) is also
turned about its bone by each of :data:`TWISTS_DEG`, each turn with the hinge's angles:
the turn sets the plane the hinge bends in, which the round body's own silhouette does
not show.  A choice that puts the root of a twin limb (a collar, an upper arm, a hip's
first bone, a thigh: :func:`~kms2pin.ecm.limbs.sides`) across the sagittal plane of the
body it hangs from is dropped (:data:`SIDES_KEPT`): that is the arms or legs traded, not
a limb re-aimed.  Each choice is scored by the silhouette fit (IoU) with the rest of the body
held, rendering only the moved bodies anew (a coarse score: a trial 20 degrees off a
thin limb scores as one far off).  Unless the body's pose as it is scores best (the
search then found nothing), the :data:`REFINED` best directions, each with its best bend
unturned and (a hinge below) its best bend over the turns, are screened by a few ECM
iterations on the masks binned 2x2 (as the limb search's), the :data:`FINAL` best of
those refined by the frame's ECM (none that screened more than :data:`REFINE_MARGIN`
below the frame's fit), and the best kept if its fit beats by :data:`GAIN`
both the frame's and that of the frame's pose run on by the same ECM (more iterations
gain a little by themselves).  A body whose search found nothing rests for
``rest`` frames (the option ``reach_rest``; by default :data:`REST_FRAMES`).

An arm lost in front of the trunk is neither lost nor missed (its silhouette stays on
the mask and its true image leaves no blob), so the search can also re-aim chosen limbs
on every frame they do not rest (``always``: the limbs with a hinge below, or those of
them that do not reach the floor, the arms; of their trials the ``always_directions``
best directions are screened, by default :data:`ALWAYS_REFINED`); and ``skip=False``
screens every search's best trials even when the pose itself scores best, since the
screening finds better poses that the coarse score ranks below it
(docs/design/tracking-history.md).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import cv2
import numpy as np
import pinocchio as pin

from ..coordinates import JointCoordinates
from ..robot import Robot
from .limbs import Sides, sides
from .limbsearch import SCREEN_ITERATIONS, LimbMove
from .loop import FrameECM
from .masks import Views
from .silhouette import body_coverage, group_counts, model_silhouette

__all__ = ["ALWAYS_REFINED", "BLOB", "COVERED", "DIRECTIONS", "GAIN", "MIN_PIXELS", "REFINED", "REFINE_MARGIN", "SIDES_KEPT",
           "TWISTS_DEG", "ReachSearch", "sphere_directions"]

#: a body with less of its silhouette on the mask than this, in some camera, is lost
COVERED = 0.5
#: the fewest silhouette pixels a body must have in a camera to be judged there
MIN_PIXELS = 12
#: an unexplained blob this share of a camera's foreground pixels calls for a missed limb
BLOB = 0.02
#: the directions a spherical joint's bone is pointed along
DIRECTIONS = 40
#: the spacing of a revolute joint's trial angles (degrees)
STEP_DEG = 20.0
#: the turns about its bone tried for a spherical joint with a hinge below (an upper arm, a
#: thigh), which set the plane the hinge bends in (degrees)
TWISTS_DEG = (45.0, 90.0, 135.0, 180.0, -135.0, -90.0, -45.0)
#: the IoU a re-aimed limb must gain to be kept, over the frame's pose and over that pose
#: run on by as many ECM iterations (which gain a little by themselves); 0.01 until the
#: twelfth session kept too few of the arms' moves (docs/design/tracking-history.md)
GAIN = 0.005
#: by default, a body whose search found nothing is not searched again for this many
#: frames (``ReachSearch(rest=)``, the option ``reach_rest``)
REST_FRAMES = 2
#: how many of the best-scoring trials are screened by ECM on binned masks, and how many
#: of those refined at full resolution
REFINED = 6
FINAL = 2
#: the best-scoring trials screened for a body re-aimed on every frame (``always``) by
#: default (the option ``reach_always_directions``; docs/design/tracking-history.md)
ALWAYS_REFINED = 3
#: a screened trial that fits worse than the frame's pose by more than this (IoU) is not
#: refined: the frame's ECM does not make up that much (docs/design/tracking-history.md)
REFINE_MARGIN = 0.005
#: a trial that puts a body with a left/right twin across the midline (its centre on the
#: other side of the sagittal plane of the body it hangs from: a collar pointed through the
#: chest, the shoulders traded) is not scored
SIDES_KEPT = True


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), z, r * np.sin(phi)])


@dataclass(frozen=True)
class _Reach:
    """A body that can be re-aimed: its index, joint, the bodies that move with it, the
    one movable joint below it (None if it has none or several) and the reach of the
    moved bodies from the joint at rest (m)."""

    body: int
    joint: JointCoordinates
    moved: tuple[int, ...]
    child: JointCoordinates | None
    child_body: int | None
    span: float

    @property
    def hinged(self) -> bool:
        """A spherical joint with a hinge below (an upper arm above its elbow, a thigh above
        its knee): turned about its bone too, and a limb ``always`` may name."""
        return self.joint.kind == "spherical" and self.child is not None and self.child.kind == "revolute"


class ReachSearch:
    """The reach search over ``robot``'s bodies on spherical or revolute joints, refining
    with ``ecm`` (module docstring)."""

    def __init__(self, robot: Robot, ecm: FrameECM, always: str = "none", feet: Collection[int] = (),
                 skip: bool = True, always_directions: int = ALWAYS_REFINED, rest: int = REST_FRAMES):
        self.robot, self.ecm, self.skip, self.always_directions = robot, ecm, skip, always_directions
        self.rest = rest  # frames a body whose search found nothing waits (REST_FRAMES; 0: none)
        m = robot.model
        by_name = {j.name: j for j in robot.joints}
        body_joint = {i: m.frames[f].parentJoint for i, f in enumerate(robot.frame_ids)}
        self.reaches: dict[int, _Reach] = {}
        for i, spec in enumerate(robot.system.joints):
            j = by_name.get(spec.name)
            if j is None or j.kind not in ("spherical", "revolute"):
                continue
            jid = m.getJointId(j.name)
            below = set(m.subtrees[jid])
            moved = tuple(b for b, k in body_joint.items() if k in below)
            kids = [(by_name[c.name], robot.index(c.child)) for c in robot.system.joints
                    if c.parent == spec.child and c.name in by_name and by_name[c.name].kind in ("spherical", "revolute")]
            child, child_body = kids[0] if len(kids) == 1 else (None, None)
            self.reaches[i] = _Reach(i, j, moved, child, child_body, self._span(jid, moved))
        self.directions = sphere_directions(DIRECTIONS)
        self.sides = sides(robot, [r.body for r in self.reaches.values() if r.hinged])
        self._guards: dict[tuple[int, ...], tuple[list[int], Sides | None]] = {}
        self.always = self._always(always, set(feet))
        self.forget()

    def _always(self, which: str, feet: set[int]) -> tuple[int, ...]:
        """The bodies re-aimed on every frame: ``which`` is "limbs" (every spherical joint
        with a hinge below: upper arms, thighs), "arms" (those of them whose bodies hold
        none of ``feet``) or "none"."""
        if which not in ("none", "limbs", "arms"):
            raise ValueError(f"always must be 'none', 'limbs' or 'arms', not {which!r}")
        if which == "none":
            return ()
        return tuple(i for i, r in self.reaches.items() if r.hinged and (which == "limbs" or not feet & set(r.moved)))

    def forget(self) -> None:
        """Start afresh (a restarted track): no body rests after a search that found nothing."""
        self._searches = 0  # calls of search(): the frames
        self._failed: dict[int, int] = {}  # body -> the search that last found nothing for it

    def _span(self, jid: int, moved: tuple[int, ...]) -> float:
        """How far the ``moved`` bodies reach from joint ``jid``'s point at rest (m)."""
        poses = self.robot.body_poses(self.robot.q_rest)
        origin = self.robot.data.oMi[jid].translation
        inner = [self.robot.inner(self.robot.bodies[i]) for i in moved]
        return max(float(np.linalg.norm(poses[i].translation - origin) + np.max(a)) for i, a in zip(moved, inner))

    def _depth(self, i: int) -> int:
        """How many joints lie between body ``i``'s joint and the root."""
        m = self.robot.model
        jid, depth = m.getJointId(self.reaches[i].joint.name), 0
        while jid:
            jid, depth = m.parents[jid], depth + 1
        return depth

    def missed(self, q: np.ndarray, views: Views) -> list[int]:
        """The limbs (module docstring) within reach of a blob the model at ``q`` leaves
        unexplained, the one whose joint is nearest a blob (in pixels) first."""
        poses, Rs, ts = self.ecm.poses(q)
        inner = self.ecm.sizes.inner
        limbs = [i for i, r in self.reaches.items() if r.joint.kind == "spherical" and r.child is not None]
        self.robot.forward(q)
        data = self.robot.data
        near: dict[int, float] = {}
        for cam, mask in zip(views.cameras, views.masks):
            left = (mask & ~model_silhouette(cam, poses, inner, (Rs, ts))).astype(np.uint8)
            left = cv2.morphologyEx(left, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
            n, _, stats, centres = cv2.connectedComponentsWithStats(left)
            big = [centres[k] for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= BLOB * np.count_nonzero(mask)]
            for i in limbs if big else []:
                r = self.reaches[i]
                p = data.oMi[self.robot.model.getJointId(r.joint.name)].translation
                depth = float(cam.depth(p[None])[0])
                if depth <= 0:
                    continue
                d = min(float(np.linalg.norm(c - cam.project(p[None])[0])) for c in big)
                if d <= r.span * cam.K[0, 0] / depth:
                    near[i] = min(near.get(i, np.inf), d)
        return sorted(near, key=near.get)

    def lost(self, q: np.ndarray, views: Views) -> list[int]:
        """The topmost lost bodies at ``q`` (module docstring): none of their ancestors lost."""
        poses, Rs, ts = self.ecm.poses(q)
        lost = set()
        for cam, mask in zip(views.cameras, views.masks):
            counts = body_coverage(cam, poses, self.ecm.sizes.inner, mask, (Rs, ts))
            lost.update(i for i in self.reaches if counts[i, 0] >= MIN_PIXELS and counts[i, 1] < COVERED * counts[i, 0])
        return [i for i in sorted(lost) if not any(i in self.reaches[k].moved and k != i for k in lost)]

    def _aimed(self, q: np.ndarray, j: JointCoordinates, body: int) -> list[np.ndarray]:
        """``q`` with joint ``j`` turned to each trial (module docstring), ``body`` its child body."""
        if j.kind == "revolute":
            lo, hi = self.robot.lower_limits[j.idx_q], self.robot.upper_limits[j.idx_q]
            lo, hi = (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else (-np.pi, np.pi)
            out = []
            for a in np.arange(lo, hi + 1e-9, np.radians(STEP_DEG)):
                c = q.copy()
                c[j.idx_q] = a
                out.append(c)
            return out
        origin, bone = self._bone(q, j, body)
        if bone is None:
            return []
        return self._turned(q, j, origin, [pin.Quaternion.FromTwoVectors(bone, t).toRotationMatrix()
                                           for t in self.directions])

    def _twisted(self, q: np.ndarray, j: JointCoordinates, body: int) -> list[np.ndarray]:
        """``q`` with spherical joint ``j`` turned about its body's bone by each of
        :data:`TWISTS_DEG` (``body`` its child body): the plane a hinge below it bends in."""
        origin, bone = self._bone(q, j, body)
        if bone is None:
            return []
        return self._turned(q, j, origin, [pin.AngleAxis(float(a), bone).toRotationMatrix()
                                           for a in np.radians(TWISTS_DEG)])

    def _bone(self, q: np.ndarray, j: JointCoordinates, body: int) -> tuple[pin.SE3, np.ndarray | None]:
        """Joint ``j``'s placement (world) at ``q`` and the unit vector from its point to
        ``body``'s centre (None if they coincide)."""
        poses = self.robot.body_poses(q)
        origin = self.robot.data.oMi[self.robot.model.getJointId(j.name)].copy()
        bone = poses[body].translation - origin.translation
        norm = float(np.linalg.norm(bone))
        return origin, (bone / norm if norm >= 1e-9 else None)

    @staticmethod
    def _turned(q: np.ndarray, j: JointCoordinates, origin: pin.SE3, turns: list[np.ndarray]) -> list[np.ndarray]:
        """``q`` with spherical joint ``j`` (placed at ``origin`` at ``q``) turned by each
        world rotation of ``turns`` about its point."""
        x = q[j.idx_q : j.idx_q + 4]
        R = pin.Quaternion(x[3], x[0], x[1], x[2]).normalized().toRotationMatrix()
        A = origin.rotation @ R.T  # the joint's frame at zero rotation, world
        out = []
        for turn in turns:
            c = q.copy()
            c[j.idx_q : j.idx_q + 4] = pin.Quaternion(A.T @ turn @ A @ R).normalized().coeffs()
            out.append(c)
        return out

    def _held(self, q: np.ndarray, moved: tuple[int, ...], views: Views) -> list[tuple]:
        """Per camera, the silhouette of the bodies but ``moved`` at ``q`` against the mask:
        its intersection and union counts, and the mask pixels it leaves (foreground and
        background) that the moved bodies may add."""
        inner = self.ecm.sizes.inner
        poses, Rs, ts = self.ecm.poses(q)
        held = [i for i in range(len(poses)) if i not in moved]
        out = []
        for cam, mask in zip(views.cameras, views.masks):
            s = model_silhouette(cam, [poses[i] for i in held], inner[held], (Rs[held], ts[held]))
            out.append((np.count_nonzero(s & mask), np.count_nonzero(s | mask), mask & ~s, ~mask & ~s))
        return out

    def _ranked(self, trials: list[np.ndarray], moved: tuple[int, ...], views: Views, held: list[tuple],
                keep: int) -> list[np.ndarray]:
        """The ``keep`` configurations of ``trials`` that fit best (IoU), best first (ties:
        the earlier), the bodies but ``moved`` as in ``held`` (:meth:`_held`)."""
        inner = self.ecm.sizes.inner
        idx = list(moved)
        read, guard = self._guard(moved)
        frames = [self.robot.frame_ids[i] for i in read]
        oMf = self.robot.data.oMf
        placements: list[np.ndarray] = []
        for c in trials:
            self.robot.forward(c)  # the moved bodies' poses only (and their anchors')
            placements += [oMf[f].homogeneous for f in frames]  # each a fresh 4x4 (``rotation`` is a view)
        H = np.array(placements).reshape(len(trials), len(read), 4, 4)
        Rs, ts = H[:, : len(idx), :3, :3], H[:, : len(idx), :3, 3]
        inter, union = np.zeros(len(trials), dtype=int), np.zeros(len(trials), dtype=int)
        for cam, (i0, u0, fg, bg) in zip(views.cameras, held):
            counts = group_counts(cam, Rs, ts, inner[idx], fg, bg)
            inter += i0 + counts[:, 0]
            union += u0 + counts[:, 1]
        iou = [i / u if u else 1.0 for i, u in zip(inter.tolist(), union.tolist())]
        crossed = guard.crossed(H[:, :, :3, :3], H[:, :, :3, 3]) if guard is not None else np.zeros(len(trials), bool)
        crossed[0] = False  # the pose (or a start already kept; a turn about the bone keeps the guarded centres)
        ranked = [k for k in sorted(range(len(trials)), key=lambda k: (-iou[k], k)) if not crossed[k]]
        return [trials[k] for k in ranked[:keep]]

    def _guard(self, moved: tuple[int, ...]) -> tuple[list[int], Sides | None]:
        """The bodies :meth:`_ranked` reads for ``moved`` (the moved ones, then the anchors
        of those with a twin) and the :class:`~kms2pin.ecm.limbs.Sides` of those, indexed
        into that list (None: no moved body has a twin)."""
        if moved not in self._guards:
            read, guard = list(moved), None
            sd = self.sides if SIDES_KEPT else None
            rows = [k for k in range(len(sd.body)) if sd.body[k] in moved] if sd is not None else []
            if rows:
                read += sorted({int(sd.anchor[k]) for k in rows} - set(moved))
                pos = {b: n for n, b in enumerate(read)}
                guard = Sides(np.array([pos[int(sd.body[k])] for k in rows]), np.array([pos[int(sd.anchor[k])] for k in rows]),
                              sd.normal[rows], sd.sign[rows])
            self._guards[moved] = (read, guard)
        return self._guards[moved]

    def _starts(self, q: np.ndarray, r: _Reach, views: Views) -> list[np.ndarray]:
        """The :data:`REFINED` (a body always re-aimed: ``always_directions``) best trials
        of re-aiming ``r`` from ``q`` (``q`` itself among them if it scores so), each with
        its best bend of the joint below, and for a hinge below also its best turned about
        its bone (module docstring)."""
        trials = self._aimed(q, r.joint, r.body)
        if r.child is not None:  # each direction also with the joint below at rest (a limb unbent)
            sl = slice(r.child.idx_q, r.child.idx_q + r.child.nq)
            for c in list(trials):
                c = c.copy()
                c[sl] = self.robot.q_rest[sl]
                trials.append(c)
        held = self._held(q, r.moved, views)
        starts = self._ranked([q, *trials], r.moved, views, held,
                             self.always_directions if r.body in self.always else REFINED)
        if r.child is None:
            return starts
        out = []
        for c in starts:  # each start's best bend of the joint below; for a hinge also its best turned about its bone
            out += self._ranked([c, *self._aimed(c, r.child, r.child_body)], r.moved, views, held, 1)
            if r.hinged:
                turned = [t for u in self._twisted(c, r.joint, r.body) for t in (u, *self._aimed(u, r.child, r.child_body))]
                out += self._ranked(turned, r.moved, views, held, 1) if turned else []
        return out

    def _refined(self, q: np.ndarray, fit: float, starts: list[np.ndarray], views: Views, binned: Views | None,
                 coarse: Views | None, timings: dict, base: tuple | None) -> tuple[tuple, tuple | None]:
        """The best of ``starts`` after screening and refinement (module docstring) as
        (configuration, fit) if it gains :data:`GAIN`, else (``q``, ``fit``); and ``base``,
        ``q`` run on by the frame's ECM (made when first needed)."""
        best = (q, fit)
        # a start met twice (a limb unbent that was at rest: its trial twice) ends the same:
        # screened and refined once, by the configuration's bytes
        screens: dict[bytes, tuple] = {}
        refined: dict[bytes, tuple] = {}
        screened = []
        for k, c in enumerate(starts):
            if c is q:
                continue
            c = self.robot.clamp(c)
            key = c.tobytes()
            if key not in screens:
                if binned is not None:
                    c, _, _ = self.ecm.run(c, views, timings, SCREEN_ITERATIONS, binned, binned=True)
                screens[key] = (c, self.ecm.fit(c, views))
            c, fc = screens[key]
            screened.append((-fc, k, c))
        for neg_fit, _, c in sorted(screened, key=lambda x: x[:2])[:FINAL]:
            if -neg_fit < fit - REFINE_MARGIN:  # best first: the rest screened lower still
                break
            key = c.tobytes()
            if key not in refined:
                qc, _, _ = self.ecm.run(c, views, timings, coarse=coarse)
                refined[key] = (qc, self.ecm.fit(qc, views))
            qc, fc = refined[key]
            if fc > fit + GAIN and base is None:  # the fair comparison: q run on as long
                qb, _, _ = self.ecm.run(q, views, timings, coarse=coarse)
                base = (qb, self.ecm.fit(qb, views))
            if fc > max(best[1], base[1] if base is not None else -1.0) + GAIN:
                best = (qc, fc)
        return best, base

    def _todo(self, q: np.ndarray, views: Views, tried: set[int]) -> list[int]:
        """The bodies to re-aim at ``q``: the topmost lost ones, the missed limbs, then those
        always re-aimed, none of ``tried``."""
        lost = self.lost(q, views)
        found = lost + [k for k in self.missed(q, views) if k not in lost]
        return [i for i in found + [k for k in self.always if k not in found] if i not in tried]

    def search_once(self, q: np.ndarray, fit: float, views: Views, binned: Views | None, coarse: Views | None,
                    timings: dict) -> tuple[np.ndarray, float, list[LimbMove]]:
        """:meth:`search` on one frame by itself: no body rests after an earlier search
        (``rest``), and the sequence's record of the searches is left as it was."""
        saved = self._searches, self._failed
        self.forget()
        try:
            return self.search(q, fit, views, binned, coarse, timings)
        finally:
            self._searches, self._failed = saved

    def search(self, q: np.ndarray, fit: float, views: Views, binned: Views | None, coarse: Views | None,
               timings: dict) -> tuple[np.ndarray, float, list[LimbMove]]:
        """Re-aim every topmost lost body and missed limb of ``q`` (its ``fit``), each once,
        looking again after each move kept (``binned``: the views binned 2x2 the trials are
        screened on; ``coarse``: the frame's coarse views); returns the configuration, its
        fit and the moves kept."""
        self._searches += 1
        moves: list[LimbMove] = []
        tried = {i for i, k in self._failed.items() if self._searches - k <= self.rest}
        base = None  # (q run on by ECM, its fit), once a trial looks like a gain
        todo = self._todo(q, views, tried)
        while todo:
            i = todo.pop(0)
            tried.add(i)
            r = self.reaches[i]
            starts = self._starts(q, r, views)
            # the pose itself ranked first: no trial scores above it, nothing to refine (with skip)
            (qc, fc), base = ((q, fit), base) if self.skip and starts[0] is q else \
                self._refined(q, fit, starts, views, binned, coarse, timings, base)
            if qc is q:
                self._failed[i] = self._searches
                continue
            joints = (r.joint,) if r.child is None else (r.joint, r.child)
            iq = np.array([k for j in joints for k in range(j.idx_q, j.idx_q + j.nq)], dtype=int)
            q, fit, base = qc, fc, None
            moves.append(LimbMove("reach", (r.joint.name,), iq))
            tried.update(k for k in self.reaches if i in self.reaches[k].moved)  # its chain's joints above
            todo = self._todo(q, views, tried)
        return q, fit, moves
