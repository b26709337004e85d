"""Micro-benchmark of the ECM image geometry at 320x240.

Prints the median wall and CPU time of ``projected_density`` for one body (whole image
and its outer bounding box) and of one ``e_step`` on a 17-body scene.

    .venv/bin/python benchmarks/ecm_geometry.py
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from kms2pin.ecm import Camera, body_bbox, e_step, projected_density, render_mask


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


if __name__ == "__main__":
    main()
