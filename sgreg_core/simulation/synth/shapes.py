"""Surface primitives and their area-uniform sampling (vectorised over all primitives).

Public API:
    Shapes                         a growing list of primitives in one local frame:
        .rect(o, u, v)             parallelogram o + s u + t v, s, t in [0, 1]
        .box(c, size, bottom=False, top=True)  axis-aligned box surfaces; c = (x, y, z_bottom)
        .cyl(base, r, h, top=True)             vertical cylinder side (+ top disk)
        .ell(center, radii, zmin=-1.0)         ellipsoid surface above zmin (in unit radii)
        .extend(other, yaw=0.0, t=(0,0,0), tag=0)  add another Shapes moved by yaw then t
        .tags                      per-primitive integer tag (the instance index in a scene)
    sample_shapes(shapes, density, rng) -> (points (N, 3) float32, tags (N,) int64)

Primitives are kept in numpy-friendly lists; sampling draws a Poisson number of points per
primitive (density * area) and places them all in a few vectorised operations.
"""
from __future__ import annotations

import numpy as np

from ...geometry import yaw_rotation


class Shapes:
    def __init__(self) -> None:
        self.rects: list[np.ndarray] = []   # rows of 9: o, u, v
        self.cyls: list[np.ndarray] = []    # rows of 6: base xyz, r, h, top flag
        self.ells: list[np.ndarray] = []    # rows of 8: center xyz, radii xyz, yaw, zmin
        self.rect_tags: list[int] = []
        self.cyl_tags: list[int] = []
        self.ell_tags: list[int] = []

    def rect(self, o, u, v, tag: int = 0) -> "Shapes":
        self.rects.append(np.r_[o, u, v].astype(np.float64))
        self.rect_tags.append(tag)
        return self

    def box(self, c, size, bottom: bool = False, top: bool = True, tag: int = 0) -> "Shapes":
        x, y, z = c
        sx, sy, sz = size
        o = np.array([x - sx / 2, y - sy / 2, z])
        X, Y, Z = np.array([sx, 0, 0]), np.array([0, sy, 0]), np.array([0, 0, sz])
        self.rect(o, X, Z, tag).rect(o + Y, X, Z, tag).rect(o, Y, Z, tag).rect(o + X, Y, Z, tag)
        if top:
            self.rect(o + Z, X, Y, tag)
        if bottom:
            self.rect(o, X, Y, tag)
        return self

    def cyl(self, base, r: float, h: float, top: bool = True, tag: int = 0) -> "Shapes":
        self.cyls.append(np.r_[base, r, h, float(top)].astype(np.float64))
        self.cyl_tags.append(tag)
        return self

    def ell(self, center, radii, zmin: float = -1.0, tag: int = 0) -> "Shapes":
        self.ells.append(np.r_[center, radii, 0.0, zmin].astype(np.float64))
        self.ell_tags.append(tag)
        return self

    def extend(self, other: "Shapes", yaw: float = 0.0, t=(0.0, 0.0, 0.0), tag: int = 0) -> "Shapes":
        R, t = yaw_rotation(yaw), np.asarray(t, dtype=np.float64)
        if other.rects:
            r = np.array(other.rects)
            r = np.c_[r[:, :3] @ R.T + t, r[:, 3:6] @ R.T, r[:, 6:9] @ R.T]
            self.rects.extend(r)
            self.rect_tags.extend([tag] * len(r))
        if other.cyls:
            c = np.array(other.cyls)
            c[:, :3] = c[:, :3] @ R.T + t
            self.cyls.extend(c)
            self.cyl_tags.extend([tag] * len(c))
        if other.ells:
            e = np.array(other.ells)
            e[:, :3] = e[:, :3] @ R.T + t
            e[:, 6] += yaw
            self.ells.extend(e)
            self.ell_tags.extend([tag] * len(e))
        return self

    def area(self) -> float:
        r = np.array(self.rects).reshape(-1, 9)
        c = np.array(self.cyls).reshape(-1, 6)
        e = np.array(self.ells).reshape(-1, 8)
        return float(_rect_area(r).sum() + _cyl_areas(c).sum() + _ell_area(e).sum())


def _rect_area(r: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.cross(r[:, 3:6], r[:, 6:9]), axis=1)


def _cyl_areas(c: np.ndarray) -> np.ndarray:
    return 2 * np.pi * c[:, 3] * c[:, 4] + np.pi * c[:, 3] ** 2 * c[:, 5]


def _ell_area(e: np.ndarray) -> np.ndarray:
    # Knud Thomsen's approximation, scaled by the kept fraction of the height
    a, b, c = e[:, 3], e[:, 4], e[:, 5]
    p = 1.6075
    full = 4 * np.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3) ** (1 / p)
    return full * (1 - e[:, 7]) / 2


def sample_shapes(shapes: Shapes, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on every primitive, and each point's primitive tag."""
    out_p, out_t = [], []
    r = np.array(shapes.rects).reshape(-1, 9)
    if len(r):
        n = rng.poisson(density * _rect_area(r))
        i = np.repeat(np.arange(len(r)), n)
        s, t = rng.random((2, len(i), 1))
        out_p.append(r[i, :3] + s * r[i, 3:6] + t * r[i, 6:9])
        out_t.append(np.asarray(shapes.rect_tags)[i])
    c = np.array(shapes.cyls).reshape(-1, 6)
    if len(c):
        side = rng.poisson(density * 2 * np.pi * c[:, 3] * c[:, 4])
        i = np.repeat(np.arange(len(c)), side)
        th = rng.uniform(0, 2 * np.pi, len(i))
        out_p.append(c[i, :3] + np.c_[c[i, 3] * np.cos(th), c[i, 3] * np.sin(th), rng.random(len(i)) * c[i, 4]])
        out_t.append(np.asarray(shapes.cyl_tags)[i])
        cap = rng.poisson(density * np.pi * c[:, 3] ** 2 * c[:, 5])
        i = np.repeat(np.arange(len(c)), cap)
        th, rad = rng.uniform(0, 2 * np.pi, len(i)), c[i, 3] * np.sqrt(rng.random(len(i)))
        out_p.append(c[i, :3] + np.c_[rad * np.cos(th), rad * np.sin(th), c[i, 4]])
        out_t.append(np.asarray(shapes.cyl_tags)[i])
    e = np.array(shapes.ells).reshape(-1, 8)
    if len(e):
        n = rng.poisson(density * _ell_area(e))
        i = np.repeat(np.arange(len(e)), n)
        # uniform directions with z restricted to [zmin, 1] (z of a uniform sphere point is uniform)
        z = rng.uniform(e[i, 7], 1.0)
        th = rng.uniform(0, 2 * np.pi, len(i))
        ring = np.sqrt(1 - z**2)
        local = np.c_[ring * np.cos(th), ring * np.sin(th), z] * e[i, 3:6]
        cy, sy = np.cos(e[i, 6]), np.sin(e[i, 6])
        world = np.c_[cy * local[:, 0] - sy * local[:, 1], sy * local[:, 0] + cy * local[:, 1], local[:, 2]]
        out_p.append(e[i, :3] + world)
        out_t.append(np.asarray(shapes.ell_tags)[i])
    if not out_p:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    return np.concatenate(out_p).astype(np.float32), np.concatenate(out_t).astype(np.int64)
