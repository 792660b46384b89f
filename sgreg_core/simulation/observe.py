"""Incremental observation: the instance maps an agent holds while it moves through a scene.

Public API:
    SensorConfig                 range, horizontal field of view, snapshot period
    first_seen(imap, times, poses, cfg) -> (N,) float64
        time each point is first inside the sensor's range and field of view (inf: never)
    observe_sequence(imap, times, poses, cfg) -> list[(t, InstanceMap)]
        the accumulated map after each period (instances appear partially and grow)
    TrajectoryConfig, make_trajectory(imap, rng, cfg) -> (times (T,), poses (T, 3) x, y, yaw)
        a walk across the free space of the scene: shortest paths through far-apart free cells
    walkable_share(imap, cfg) -> float
        the share of the scene's free floor that a walk can reach (closed doors and furniture
        cut the rest off: walks keep to the largest connected free area)
    reverse_trajectory(times, poses) -> (times, poses)     the same path walked the other way

Poses are (T, 3) arrays (x, y, yaw) or (T, 4, 4) camera-to-world transforms whose +x axis
(the yaw direction) is the viewing direction. Occlusion is not modelled: every surface point
within range and field of view counts as seen.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ..maps.instance_map import select_points
from ..types import InstanceMap


@dataclass
class SensorConfig:
    max_range: float = 4.0     # m, horizontal distance
    min_range: float = 0.3     # m
    hfov_deg: float = 90.0     # horizontal field of view
    period: float = 1.0        # s between snapshots
    chunk: int = 16            # poses per vectorised block (bounds memory at chunk x N)


@dataclass
class TrajectoryConfig:
    cell: float = 0.1          # m, free-space grid
    clearance: float = 0.3     # m, distance kept from obstacles (real rooms are cluttered: 0.15)
    waypoints: int = 2         # far-apart free cells visited in turn (2, the least: one crossing)
    start: tuple[float, float] | None = None   # scene x, y of the first waypoint (at most
                                               # max_start_offset from the walkable floor); None: seeded
    max_start_offset: float = 1.0   # m; a start farther from the walkable floor is refused
    random_start: bool = False  # seeded first waypoint: any free cell (walks differ from seed
                                # to seed) instead of the far end of the free space
    speed: float = 0.5         # m/s
    rate: float = 5.0          # poses per second
    look_around_deg: float = 25.0   # amplitude of a slow yaw sweep about the heading
    sweep_period: float = 6.0  # s


def _xy_yaw(poses: np.ndarray) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim == 3 and poses.shape[1:] == (4, 4):
        return np.c_[poses[:, 0, 3], poses[:, 1, 3], np.arctan2(poses[:, 1, 0], poses[:, 0, 0])]
    if poses.ndim == 2 and poses.shape[1] == 3:
        return poses
    raise ValueError(f"poses must be (T, 3) x, y, yaw or (T, 4, 4), got {poses.shape}")


def first_seen(imap: InstanceMap, times: np.ndarray, poses: np.ndarray, cfg: SensorConfig | None = None) -> np.ndarray:
    cfg = cfg or SensorConfig()
    pose = _xy_yaw(poses)
    times = np.asarray(times, dtype=np.float64)
    xy = imap.points[:, :2].astype(np.float32)
    seen = np.full(len(xy), np.inf)
    cos_half = np.float32(np.cos(np.radians(cfg.hfov_deg) / 2))
    for a in range(0, len(pose), cfg.chunk):
        p, t = pose[a:a + cfg.chunk].astype(np.float32), times[a:a + cfg.chunk]
        dx = xy[None, :, 0] - p[:, None, 0]                       # (c, N)
        dy = xy[None, :, 1] - p[:, None, 1]
        dist = np.sqrt(dx * dx + dy * dy)
        # inside the field of view <=> cos(bearing) >= cos(hfov / 2), without any arctan
        ahead = dx * np.cos(p[:, 2:3]) + dy * np.sin(p[:, 2:3])
        vis = (dist <= cfg.max_range) & (dist >= cfg.min_range) & (ahead >= cos_half * dist)
        seen = np.minimum(seen, np.where(vis, t[:, None], np.inf).min(axis=0))
    return seen


def observe_sequence(imap: InstanceMap, times, poses, cfg: SensorConfig | None = None) -> list[tuple[float, InstanceMap]]:
    cfg = cfg or SensorConfig()
    times = np.asarray(times, dtype=np.float64)
    seen = first_seen(imap, times, poses, cfg)
    out = []
    for t in np.arange(times[0] + cfg.period, times[-1] + cfg.period, cfg.period):
        out.append((float(t), select_points(imap, seen <= t)))
    return out


def _free_grid(imap: InstanceMap, cfg: TrajectoryConfig):
    """(the largest connected free area, as a grid mask; the grid's origin; its share of all
    free cells). Closed doors and furniture are obstacles, as to a robot."""
    pts = imap.points
    lo = pts[:, :2].min(0)
    ij = np.floor((pts[:, :2] - lo) / cfg.cell).astype(np.int64)
    shape = tuple(ij.max(0) + 1)
    z0 = np.percentile(pts[:, 2], 2)          # floor level
    inside = np.zeros(shape, dtype=bool)
    low = pts[:, 2] < z0 + 0.1
    inside[ij[low, 0], ij[low, 1]] = True
    inside = ndimage.binary_fill_holes(ndimage.binary_closing(inside, iterations=2))
    obst = np.zeros(shape, dtype=bool)
    body = (pts[:, 2] > z0 + 0.1) & (pts[:, 2] < z0 + 1.8)
    obst[ij[body, 0], ij[body, 1]] = True
    r = max(1, int(np.ceil(cfg.clearance / cfg.cell)))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    obst = ndimage.binary_dilation(obst, structure=(xx**2 + yy**2) <= r * r)
    free = inside & ~obst
    labels, n = ndimage.label(free)
    if n == 0:
        raise ValueError("no free space found to walk in this scene")
    sizes = np.bincount(labels.ravel())[1:]
    largest = np.argmax(sizes) + 1
    return labels == largest, lo, float(sizes.max() / sizes.sum())


def walkable_share(imap: InstanceMap, cfg: TrajectoryConfig | None = None) -> float:
    return _free_grid(imap, cfg or TrajectoryConfig())[2]


def make_trajectory(imap: InstanceMap, rng: np.random.Generator, cfg: TrajectoryConfig | None = None):
    """Walk through far-apart free cells along shortest grid paths. The first waypoint is the
    free cell nearest cfg.start, a random free cell (cfg.random_start), or the one farthest
    from a random free cell; each next one is
    the free cell farthest from all waypoints so far (farthest-point order), so two waypoints
    cross the scene and more of them tour it."""
    cfg = cfg or TrajectoryConfig()
    if cfg.waypoints < 2:
        raise ValueError(f"waypoints must be at least 2 (a walk from one to another), got {cfg.waypoints}")
    free, lo, _ = _free_grid(imap, cfg)
    cells = np.argwhere(free)
    index = -np.ones(free.shape, dtype=np.int64)
    index[tuple(cells.T)] = np.arange(len(cells))
    rows, cols, w = [], [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):   # 8-connected grid graph
        nb = cells + (dx, dy)
        ok = (nb[:, 0] < free.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < free.shape[1])
        j = np.full(len(cells), -1)
        j[ok] = index[nb[ok, 0], nb[ok, 1]]
        k = j >= 0
        rows.append(np.flatnonzero(k))
        cols.append(j[k])
        w.append(np.full(k.sum(), np.hypot(dx, dy)))
    g = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(len(cells),) * 2).tocsr()

    def farthest(d):
        return int(np.argmax(np.where(np.isfinite(d), d, -1)))

    if cfg.start is not None:
        centers = (cells + 0.5) * cfg.cell + lo
        off = np.linalg.norm(centers - np.asarray(cfg.start, np.float64), axis=1)
        first = int(np.argmin(off))
        if off[first] > cfg.max_start_offset:     # not quietly moved somewhere else
            x, y = centers[first]
            raise ValueError(f"start ({cfg.start[0]:g}, {cfg.start[1]:g}) lies {off[first]:.1f} m from the "
                             f"walkable floor (the largest connected free area: a closed door, a wall or "
                             f"furniture cuts it off); the nearest walkable point is ({x:.2f}, {y:.2f})")
    elif cfg.random_start:
        first = int(rng.integers(len(cells)))
    else:
        first = farthest(dijkstra(g, directed=False, indices=int(rng.integers(len(cells)))))
    stops = [first]
    d, pred = dijkstra(g, directed=False, indices=first, return_predecessors=True)
    nearest = d.copy()   # distance to the nearest waypoint so far
    legs = []
    for _ in range(cfg.waypoints - 1):
        nxt = farthest(nearest)
        leg = [nxt]
        while leg[-1] != stops[-1]:
            leg.append(int(pred[leg[-1]]))
        legs.append(leg[::-1][1:] if legs else leg[::-1])
        stops.append(nxt)
        d, pred = dijkstra(g, directed=False, indices=nxt, return_predecessors=True)
        nearest = np.minimum(nearest, d)
    path = np.concatenate(legs)
    xy = (cells[path] + 0.5) * cfg.cell + lo
    # resample at constant speed after smoothing the staircase of grid steps
    xy = ndimage.uniform_filter1d(xy, size=5, axis=0, mode="nearest")
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    times = np.arange(0.0, seg[-1] / cfg.speed + 1e-9, 1.0 / cfg.rate)
    s = times * cfg.speed
    x, y = np.interp(s, seg, xy[:, 0]), np.interp(s, seg, xy[:, 1])
    heading = np.arctan2(np.gradient(y), np.gradient(x)) if len(s) > 1 else np.zeros(1)
    sweep = np.radians(cfg.look_around_deg) * np.sin(2 * np.pi * times / cfg.sweep_period + rng.uniform(0, 2 * np.pi))
    return times, np.c_[x, y, heading + sweep]


def reverse_trajectory(times: np.ndarray, poses: np.ndarray):
    p = _xy_yaw(poses)[::-1].copy()
    p[:, 2] += np.pi
    return np.asarray(times, dtype=np.float64).copy(), p
