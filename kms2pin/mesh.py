"""The unit-sphere mesh that URDF visuals scale into ellipsoids (URDF has no ellipsoid)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

MESH_NAME = "unit_sphere.obj"


@lru_cache(maxsize=4)
def icosphere(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) on the unit sphere and outward-wound triangles (F, 3)."""
    t = (1.0 + 5.0**0.5) / 2.0
    verts = [
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
        (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
        (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1),
    ]  # fmt: skip
    faces = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    v = [np.asarray(p, float) / np.linalg.norm(p) for p in verts]
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[key] = len(v) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(v), np.array(faces, dtype=np.int64)


def sphere_obj(subdivisions: int = 3) -> str:
    """Wavefront OBJ text of the unit icosphere (deterministic)."""
    v, f = icosphere(subdivisions)
    lines = ["# unit sphere (icosphere), written by kms2pin; scaled per body by <mesh scale>"]
    lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    return "\n".join(lines) + "\n"
