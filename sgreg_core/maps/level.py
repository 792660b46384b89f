"""Levelling: each map's gravity from its own geometry, so the graph is built on an upright map.

A robot's map is gravity-aligned by its visual-inertial odometry, but only to 0.5-2 degrees,
and differently for each robot (real scans lean by up to 15). Everything yaw-invariant in
SG-Reg (box extents about z, the triplets' anticlockwise order, the shape network's local
frame, the footprint of the verdict) assumes z is up, so each map is levelled first.

Gravity is the direction that horizontal surfaces (floor, table tops, seats) are normal to and
vertical ones (walls, cabinet fronts) are perpendicular to. From surface normals of the
voxelised map (local PCA, planar neighbourhoods only), iteratively with a narrowing cone about
the current estimate: up = the top eigenvector of mean(n n^T | horizontal) - mean(n n^T |
vertical). Labels are not needed (and may be wrong).

Public API:
    LevelConfig
    MAX_TILT_DEG                the most any map is levelled by (a peer's levelling beyond it is refused)
    tilt_deg(R) -> float        how far a levelling rotation tilts a map
    Levelling                   R (3x3, map -> levelled), up (gravity's opposite in the map
                                frame), tilt_deg, ok, reason; .T (4x4); .apply(points)
    estimate_level(points, cfg) -> Levelling
    level_map(imap, cfg) -> (levelled InstanceMap, Levelling)
    rotation_between(a, b) -> (3, 3) the smallest rotation taking unit vector a onto b
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry import local_planes, voxel_downsample
from ..types import InstanceMap


MAX_TILT_DEG = 30.0   # no map is levelled further: it would be on its side (LevelConfig.max_tilt_deg)


@dataclass
class LevelConfig:
    """enabled:         level maps before the graph is built.
    voxel:              m, the map is voxelised to this grid before normals are estimated.
    neighbours:         points per local plane fit.
    max_planarity:      a point's neighbourhood is planar when its smallest eigenvalue is at
                        most this share of the eigenvalue sum.
    cones_deg:          the narrowing cones: a normal within cone of `up` is horizontal
                        surface, within cone of the horizontal plane vertical surface.
    max_tilt_deg:       a larger estimated tilt is not trusted (the map is left as it is); at
                        most MAX_TILT_DEG (30), past which a peer's levelling is refused.
    min_tilt_deg:       a smaller one is left alone (levelling cannot do better than this).
    min_points:         voxels needed to estimate anything.
    max_points:         at most this many voxels (seeded subsample) keep the cost flat.
    A 10 cm grid and 8000 voxels: ~20 ms a map; on tilted partial views of the real scans the
    error to the whole scan's estimate is 0.4 deg median (0.5 deg at 5 cm and 20000, 50 ms):
    the scans themselves are warped by about that much."""

    enabled: bool = True
    voxel: float = 0.1
    neighbours: int = 12
    max_planarity: float = 0.02
    cones_deg: tuple[float, ...] = (35.0, 15.0, 6.0, 4.0, 4.0)
    max_tilt_deg: float = 20.0
    min_tilt_deg: float = 0.05
    min_points: int = 200
    max_points: int = 8000

    def __post_init__(self):
        # no cone at all would leave up at z and report the map level, whatever its tilt
        if not (self.cones_deg and all(0.0 < c < 90.0 for c in self.cones_deg)):
            raise ValueError(f"level: cones_deg must be one or more angles in (0, 90) deg, "
                             f"got {self.cones_deg!r}")
        if not (0.0 < self.voxel < np.inf and self.neighbours >= 3
                and 0.0 < self.max_planarity <= 1.0 / 3.0
                and 0.0 <= self.min_tilt_deg <= self.max_tilt_deg <= MAX_TILT_DEG
                and 10 <= self.min_points <= self.max_points):
            raise ValueError(f"level: voxel must be a finite distance > 0 (m), neighbours >= 3, "
                             f"max_planarity in (0, 1/3], 0 <= min_tilt_deg <= max_tilt_deg <= "
                             f"{MAX_TILT_DEG:g}, 10 <= min_points <= max_points")


@dataclass
class Levelling:
    """R maps map coordinates into the levelled frame (p_level = R p_map, about the origin);
    up: the estimated up direction in the map frame; tilt_deg: its angle to the map's z;
    ok: False when nothing could be estimated (R is then the identity) and reason says why."""

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    tilt_deg: float = 0.0
    ok: bool = True
    reason: str = "ok"

    @classmethod
    def from_rotation(cls, R: np.ndarray) -> "Levelling":
        """The levelling a rotation stands for (e.g. a peer's, from its message)."""
        R = np.asarray(R, np.float64)
        return cls(R=R, up=R.T @ np.array([0.0, 0.0, 1.0]), tilt_deg=tilt_deg(R))

    @property
    def T(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        return T

    def apply(self, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points)
        return (pts.astype(np.float64) @ self.R.T).astype(pts.dtype if pts.dtype.kind == "f" else np.float64)

    def to_json(self) -> dict:
        return {"tilt_deg": round(float(self.tilt_deg), 4), "up": [round(float(v), 6) for v in self.up],
                "ok": bool(self.ok), "reason": self.reason}


def tilt_deg(R: np.ndarray) -> float:
    """How far the levelling rotation R tilts a map (deg): the angle between the map's up,
    R^T z, and z."""
    return float(np.degrees(np.arccos(np.clip(np.asarray(R, np.float64)[2, 2], -1.0, 1.0))))


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b (Rodrigues)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite: half a turn about any axis perpendicular to a
        p = np.eye(3)[np.argmin(np.abs(a))]
        k = np.cross(a, p) / np.linalg.norm(np.cross(a, p))
        return 2.0 * np.outer(k, k) - np.eye(3)
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def _planar_normals(pts: np.ndarray, k: int, max_planarity: float) -> np.ndarray:
    """Unit normals of the points whose k-neighbourhood is a plane."""
    normals, vals = local_planes(pts, k)
    planar = vals[:, 0] <= max_planarity * np.maximum(vals.sum(1), 1e-12)
    return normals[planar]


def estimate_level(points: np.ndarray, cfg: LevelConfig | None = None) -> Levelling:
    """Gravity of a map from its surfaces (see the module docstring); identity when disabled."""
    cfg = cfg or LevelConfig()
    if not cfg.enabled:
        return Levelling(reason="disabled")
    pts = np.asarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        return Levelling(ok=False, reason=f"points must have shape (N, 3), got {pts.shape}")
    pts = pts[np.isfinite(pts).all(1)]
    vox = voxel_downsample(pts, cfg.voxel).astype(np.float64) if len(pts) else pts
    if len(vox) > cfg.max_points:
        vox = vox[np.random.default_rng(0).choice(len(vox), cfg.max_points, replace=False)]
    if len(vox) < cfg.min_points:
        return Levelling(ok=False, reason=f"too few points ({len(vox)} voxels) to find gravity")
    normals = _planar_normals(vox, cfg.neighbours, cfg.max_planarity)
    up = np.array([0.0, 0.0, 1.0])
    for cone in cfg.cones_deg:
        cos_up = np.abs(normals @ up)
        horizontal = normals[cos_up >= np.cos(np.radians(cone))]
        vertical = normals[cos_up <= np.sin(np.radians(cone))]
        if len(horizontal) < cfg.min_points // 10 or len(horizontal) + len(vertical) < cfg.min_points // 4:
            # walls alone leave gravity free to turn about their common direction
            return Levelling(ok=False, reason="too few horizontal surfaces (floor, tables) to find gravity")
        M = np.zeros((3, 3))
        if len(horizontal):
            M += horizontal.T @ horizontal / len(horizontal)
        if len(vertical):
            M -= vertical.T @ vertical / len(vertical)
        new = np.linalg.eigh(M)[1][:, -1]
        up = new if new @ up >= 0 else -new
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    if tilt > cfg.max_tilt_deg:     # left as it is: up stays z, as R says
        return Levelling(tilt_deg=tilt, ok=False,
                         reason=f"estimated tilt {tilt:.1f} deg over max_tilt_deg; left as it is")
    if tilt < cfg.min_tilt_deg:
        return Levelling(up=up, tilt_deg=tilt)
    return Levelling(R=rotation_between(up, np.array([0.0, 0.0, 1.0])), up=up, tilt_deg=tilt)


def level_map(imap: InstanceMap, cfg: LevelConfig | None = None) -> tuple[InstanceMap, Levelling]:
    """The map in its levelled frame, and the levelling (identity when disabled or not found)."""
    lev = estimate_level(imap.points, cfg)
    if np.allclose(lev.R, np.eye(3)):
        return imap, lev
    return replace(imap, points=lev.apply(imap.points).astype(np.float32)), lev
