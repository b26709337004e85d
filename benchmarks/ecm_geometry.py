"""Micro-benchmark of the ECM image geometry at 320x240.

Prints the median wall and CPU time of ``projected_density`` for one body (whole image
and its outer bounding box) and of one ``e_step`` on a 17-body scene; then the tracker's
per-pixel C kernels (M-step sums with the Jacobian, E-step softplus) on one body's box,
vectorized against their scalar loop in the same run (the C code takes the scalar loop
when the arrays are not contiguous, so a strided copy of the same pixels times it).

    .venv/bin/python benchmarks/ecm_geometry.py
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from kms2pin import native
from kms2pin.ecm import Camera, body_bbox, projected_density, render_mask
from kms2pin.ecm.mstep import body_image
from kms2pin.native import kernels
from kms2pin.reference.occlusion import e_step


def median_time(fn: Callable[[], object], repeat: int = 200) -> tuple[float, float]:
    """Median wall and CPU seconds per call over ``repeat`` calls (after 3 warm-up calls).

    The CPU time (this thread) is the steadier figure on a shared, loaded machine.
    """
    for _ in range(3):
        fn()
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def show(label: str, times: tuple[float, float]) -> None:
    print(f"{label:58s} wall {times[0] * 1e3:7.3f} ms   cpu {times[1] * 1e3:7.3f} ms")


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return pin.Quaternion(*q).toRotationMatrix()


def scene(rng: np.random.Generator, cam: Camera, n: int) -> list[tuple[pin.SE3, np.ndarray, np.ndarray]]:
    """``n`` limb-sized ellipsoids centred on random pixels at 4-7 m."""
    bodies = []
    for _ in range(n):
        px = rng.uniform([40, 30], [280, 210], size=(1, 2))
        d, c = cam.rays(px)
        centre = c + d[0] * rng.uniform(4.0, 7.0) / d[0, 2]
        inner = rng.uniform([0.08, 0.08, 0.2], [0.2, 0.2, 0.45])
        bodies.append((pin.SE3(random_rotation(rng), centre), inner, inner * 1.3))
    return bodies


def main() -> None:
    rng = np.random.default_rng(0)
    cam = Camera.default()
    pose = pin.SE3(random_rotation(rng), np.array([0.2, -0.1, 6.0]))
    inner = np.array([0.3, 0.28, 0.36])
    outer = inner * 1.3
    box = body_bbox(cam, pose, outer)
    projected_density(cam, pose, inner, outer)  # fills the per-camera ray caches
    full = median_time(lambda: projected_density(cam, pose, inner, outer))
    region = median_time(lambda: projected_density(cam, pose, inner, outer, bbox=box))
    with_box = median_time(lambda: projected_density(cam, pose, inner, outer, bbox=body_bbox(cam, pose, outer)))
    bodies = scene(rng, cam, 17)
    mask = render_mask(cam, [(p, i) for p, i, _ in bodies])
    estep = median_time(lambda: e_step(mask, cam, bodies), repeat=50)
    areas = [b.shape[0] * b.shape[1] for b in (body_bbox(cam, p, o) for p, _, o in bodies) if b]
    h, w = box.shape
    show("projected_density, full 320x240 image", full)
    show(f"projected_density, {w}x{h} px bbox region", region)
    show("body_bbox + projected_density on that region", with_box)
    show(f"e_step, 17 bodies (mean bbox {np.mean(areas):.0f} px, {int(mask.sum())} fg px)", estep)
    if native.ENABLED:  # the C kernels' vectorized and scalar loops
        kernel_ratios(cam, pose, inner, rng)


def strided(a: np.ndarray) -> np.ndarray:
    """The same values in a non-contiguous array (every other element of a twice as long one)."""
    big = np.zeros((2 * a.shape[0],) + a.shape[1:])
    big[::2] = a
    return big[::2]


def kernel_ratios(cam: Camera, pose: pin.SE3, inner: np.ndarray, rng: np.random.Generator) -> None:
    img = body_image(cam, pose, inner, 0.7)
    n = len(img.dirs)
    A = (pose.rotation / inner**2) @ pose.rotation.T
    e = cam.centre - pose.translation
    inv = 1.0 / (2.0 * img.delta)
    y = (rng.random(n) < 0.5).astype(float)
    o = rng.random(n) * 0.2
    H, g = np.zeros((6, 6)), np.zeros(6)
    fast = median_time(lambda: kernels.silhouette_fit(img.dirs, A, e, inv, y, o, None, True, H, g))
    d2, y2, o2 = strided(img.dirs), strided(y), strided(o)
    slow = median_time(lambda: kernels.silhouette_fit(d2, A, e, inv, y2, o2, None, True, H, g))
    show(f"M-step sums + Jacobian, {n} px, vectorized", fast)
    show(f"  the scalar loop: {slow[1] / fast[1]:.2f}x the vectorized CPU time", slow)
    b = img.box
    rows, cols = b.v1 - b.v0, b.u1 - b.u0
    log_free, sp = np.zeros(cam.shape), np.empty(n)
    fast = median_time(
        lambda: kernels.estep_body(img.dirs, A, e, inv, log_free, b.v0, b.u0, rows, cols, sp, None, 1.0)
    )
    slow = median_time(lambda: kernels.estep_body(d2, A, e, inv, log_free, b.v0, b.u0, rows, cols, sp, None, 1.0))
    show(f"E-step softplus on the body's box, {n} px, vectorized", fast)
    show(f"  the scalar loop: {slow[1] / fast[1]:.2f}x the vectorized CPU time", slow)


if __name__ == "__main__":
    main()
