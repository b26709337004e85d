"""The tracker's E-step (union of sharp silhouettes), its buffers, and binned masks."""

from __future__ import annotations

import numpy as np
import pytest

from kms2pin.ecm.estep import UnionEStep
from kms2pin.ecm.loop import FrameECM
from kms2pin.ecm.masks import bin_mask
from kms2pin.ecm.mstep import fit_bodies, fit_packed, pose_arrays
from kms2pin.ecm.springs import pose_springs
from kms2pin.ecm.synth import render
from kms2pin.ecm.tracker import Tracker

from ._tracking import (
    _cams,
    _perturbed,
    _robot,
    centre_error,
)


def test_e_step_scratch_image_leaves_nothing_behind():
    """The E-step reuses a per-camera union image, re-zeroed over the bodies' boxes: an
    E-step after others at different poses gives exactly a fresh tracker's views."""
    robot = _robot("fullbody")
    cams = _cams(robot)
    rng = np.random.default_rng(12)
    qs = [robot.random_configuration(rng, 40) for _ in range(3)]
    masks = render(robot, qs[2], cams)
    used = Tracker(robot, cams)
    for q in qs[:2]:
        used.e_step(q, masks, 1.0)
    scratch = used.ecm.estep.scratch_images()
    assert all(not buf.any() for buf in scratch) and len(scratch) == len(cams)
    _, views = used.e_step(qs[2], masks, 0.7)
    _, fresh = Tracker(robot, cams).e_step(qs[2], masks, 0.7)
    for va, vb in zip(views, fresh):
        assert len(va) == len(vb)
        for a, b in zip(va, vb):
            np.testing.assert_array_equal(a.o, b.o)
            np.testing.assert_array_equal(a.y, b.y)


@pytest.mark.parametrize("shape", [(240, 320), (7, 9), (1, 5)])
def test_bin_mask_gives_each_blocks_set_fraction(shape):
    rng = np.random.default_rng(shape[0])
    mask = rng.random(shape) < 0.4
    h, w = shape[0] // 2, shape[1] // 2
    out = bin_mask(mask)
    assert out.shape == (h, w) and out.dtype == np.float64
    blocks = mask[: 2 * h, : 2 * w].reshape(h, 2, w, 2).sum(axis=(1, 3)) / 4.0
    np.testing.assert_array_equal(out, blocks)


def test_wide_edge_iterations_run_on_binned_masks_and_the_pose_is_recovered(monkeypatch):
    """coarse_delta_px: the iterations whose edge is at least that wide see each camera
    binned 2x2 (half the edge width in binned pixels, the masks' block fractions);
    the narrow-edge ones full resolution.  Both schedules recover the pose."""
    robot = _robot("lowerbody")
    rng = np.random.default_rng(21)
    qt = robot.random_configuration(rng, 20)
    cams = _cams(robot)
    q0 = _perturbed(robot, qt, rng)
    masks = render(robot, qt, cams)
    seen = []
    real = FrameECM.iterate

    def spy(self, q, views, delta, timings, *priors):
        seen.append((delta, [c.shape for c in views.cameras], [x.dtype for x in views.masks]))
        if views.cameras[0].shape != masks[0].shape:  # each binned mask is its block fractions of the mask
            for full, binned in zip(masks, views.masks):
                np.testing.assert_array_equal(binned, full.reshape(120, 2, 160, 2).mean(axis=(1, 3)))
        return real(self, q, views, delta, timings, *priors)

    monkeypatch.setattr(FrameECM, "iterate", spy)
    errs = {}
    for coarse in (1.4, None):
        seen.clear()
        tr = Tracker(robot, cams, q0=q0, max_iterations=10, calibrate_sizes=False, coarse_delta_px=coarse)
        r = tr.step(masks)
        errs[coarse] = centre_error(robot, r.q, qt)
        assert r.fit > 0.97
        if coarse is None:
            assert all(shapes == [(240, 320)] * 2 and delta <= 2.8 for delta, shapes, _ in seen)
        else:  # 2.8 and 1.4 px binned (1.4 and 0.7 binned pixels), then 0.7 px at full size
            assert [(d, s) for d, s, _ in seen[:3]] == [(1.4, [(120, 160)] * 2), (0.7, [(120, 160)] * 2),
                                                         (0.7, [(240, 320)] * 2)]
            assert all(dt == np.float64 for _, _, dts in seen[:2] for dt in dts)
            assert all(s == [(240, 320)] * 2 for _, s, _ in seen[2:])
    before = centre_error(robot, q0, qt)
    assert max(errs.values()) < 0.5 and max(errs.values()) < 0.2 * before
    for bad in (0.0, 0.7, -1.0, float("nan")):  # the final, narrow-edge iterations stay at full size
        with pytest.raises(ValueError, match="coarse_delta_px"):
            Tracker(robot, cams, coarse_delta_px=bad)


def _scene(seed: int):
    """The full body at a random pose, its two cameras and masks of another random pose:
    (robot, cameras, masks, body poses, their rotations and centres, inner semi-axes)."""
    robot = _robot("fullbody")
    cams = _cams(robot)
    rng = np.random.default_rng(seed)
    q = robot.random_configuration(rng, 30)
    masks = render(robot, robot.random_configuration(rng, 30), cams)
    poses = robot.body_poses(q)
    Rs, ts = pose_arrays(poses)
    return robot, cams, masks, poses, Rs, ts, np.array([robot.inner(b) for b in robot.bodies])


def test_the_one_call_e_step_gives_the_per_body_kernels_views(backend):
    """UnionEStep runs a camera in one kernel call (estep_camera) unless a body needs the
    per-body path; both give the same views to the last bit, and leave the scratch
    image zeroed."""
    robot, cams, masks, poses, Rs, ts, inner = _scene(5)
    for ms, cs, delta in ((masks, cams, 0.7), ([bin_mask(m) for m in masks], [c.binned(2) for c in cams], 1.4)):
        one = UnionEStep(10**6)
        fused = one(poses, Rs, ts, inner, cs, ms, delta)
        assert one.fused_cameras == 2 and all(not b.any() for b in one.scratch_images())
        per_body = UnionEStep(10**6, fused=False)
        ref = per_body(poses, Rs, ts, inner, cs, ms, delta)
        assert per_body.fused_cameras == 0
        assert sum(len(v) for v in ref) > len(robot.bodies)
        for va, vb in zip(fused, ref):
            assert len(va) == len(vb)
            for a, b in zip(va, vb):
                assert a.image.box == b.image.box and a.image.delta == b.image.delta
                for x, y in ((a.y, b.y), (a.o, b.o), (a.image.s, b.image.s), (a.image.dirs, b.image.dirs)):
                    np.testing.assert_array_equal(x, y)


def test_the_packed_m_step_gives_the_per_body_fits_to_the_last_bit(backend):
    """The E-step's views left packed (UnionEStep.packed) and fitted in one kernel call
    (fit_packed) give every body the pose, curvature, evidence and cost that the per-body
    views and fit_body give, and the same springs; the scratch images are left zeroed.
    Where the per-body path is needed (an outlier class, a view above max_pixels) there
    is no packed E-step."""
    robot, cams, masks, poses, Rs, ts, inner = _scene(7)
    for ms, cs, delta in ((masks, cams, 0.7), ([bin_mask(m) for m in masks], [c.binned(2) for c in cams], 1.4)):
        one = UnionEStep(10**6)
        packed = one.packed(Rs, ts, inner, cs, ms, delta)
        assert packed is not None and all(not b.any() for b in one.scratch_images())
        fits = fit_packed(packed, Rs, ts, inner, iterations=3, damping=1e-3, max_step=0.1)
        ref = fit_bodies(UnionEStep(10**6, fused=False)(poses, Rs, ts, inner, cs, ms, delta), poses, inner,
                         iterations=3, damping=1e-3, max_step=0.1)
        assert len(fits) == len(ref) == len(robot.bodies)
        assert sum(f.evidence > 0 for f in ref) > len(ref) // 2  # most bodies seen and fitted
        for i, f in enumerate(ref):
            np.testing.assert_array_equal(fits.R[i], f.pose.rotation)
            np.testing.assert_array_equal(fits.t[i], f.pose.translation)
            np.testing.assert_array_equal(fits.hessian[i], f.hessian)
            assert (fits.evidence[i], fits.cost[i]) == (f.evidence, f.cost)
        for a, b in zip(pose_springs(fits, inner, 1e-3), pose_springs(ref, inner, 1e-3)):
            np.testing.assert_array_equal(a, b)
    assert UnionEStep(10**6, outlier=0.1).packed(Rs, ts, inner, cams, masks, 0.7) is None
    assert UnionEStep(50).packed(Rs, ts, inner, cams, masks, 0.7) is None
    assert UnionEStep(10**6, pack=False).packed(Rs, ts, inner, cams, masks, 0.7) is None
