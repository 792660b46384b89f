"""Agents walking through one scene: the instance maps each holds over time, each in its own map
frame, and the ground truth between the frames. What `sgreg make-bag` records.

Agent a walks a path across the scene; agent b walks the same path in the opposite direction
(the paper's hardest sequences: they see the same places at different times, from opposite
sides) or another path; agents c, d, ... (N agents) walk paths of their own from seeded
starts. Each agent's map frame is its start pose, with a random yaw and offset
on top, so no two frames agree and nothing can be learnt from where maps happen to start.

Agent b may walk a second capture of the same room (furniture moved, other coverage), given
already in a's scene frame: what two robots mapping one room on different days hold. Which
objects both maps hold at any time (the "registrable" frames of a replay) comes with the run:
per snapshot, the objects of each map named by a's instance ids (`object_correspondence`
pairs the captures' instances by their overlap in the common frame).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import invert_transform, pack_keys, transform_points, voxel_coords, yaw_transform
from ..maps.instance_map import labelled_mask, select_points
from ..maps.level import rotation_between
from .observe import SensorConfig, TrajectoryConfig, make_trajectory, observe_sequence, reverse_trajectory
from .pairs import node_iou
from ..maps.scene_graph import is_structural
from ..types import InstanceMap


AGENT_NAMES = "abcdefghijklmnopqrstuvwxyz"


@dataclass
class WalkConfig:
    """agents: how many agents walk (named a, b, c, ...).
    opposite: b walks a's path backwards (else a second, independent path).
    mapping_period: seconds between two instance-map snapshots of one agent.
    voxel: snapshots are voxel-downsampled to this size (m) to keep messages and bags small.
    max_offset: the map frames' random offsets are up to this far (m) from the start poses.
    start_b: scene x, y where b starts when it walks its own path (a's start is
        trajectory.start); None: seeded.
    sensor_b: b's sensor when it differs from a's (a lidar robot and a camera robot).
    object_min_points: an object counts as held by a map once it has this many points (the
        scene graph's GraphConfig.min_points)."""

    agents: int = 2
    opposite: bool = True
    mapping_period: float = 1.0
    voxel: float = 0.05
    max_offset: float = 10.0
    start_b: tuple[float, float] | None = None
    sensor_b: SensorConfig | None = None
    object_min_points: int = 30
    sensor: SensorConfig = field(default_factory=SensorConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)


@dataclass
class AgentRun:
    name: str
    times: np.ndarray                       # (T,) s, trajectory samples
    poses: np.ndarray                       # (T, 3) x, y, yaw in the scene frame
    T_scene_map: np.ndarray                 # 4x4: the agent's map frame in the scene frame
    snapshots: list[tuple[float, InstanceMap]]   # (t, map in the agent's map frame)
    objects: list[list[int]] = field(default_factory=list)   # per snapshot: objects held, a's ids


@dataclass
class WalkRun:
    agents: list[AgentRun]

    @property
    def a(self) -> AgentRun:
        return self.agents[0]

    @property
    def b(self) -> AgentRun:
        return self.agents[1]

    @property
    def T_a_b(self) -> np.ndarray:
        """Ground truth: maps points of a's map frame into b's (p_b = T_a_b p_a)."""
        return invert_transform(self.b.T_scene_map) @ self.a.T_scene_map


def _map_frame(start_pose: np.ndarray, rng: np.random.Generator, max_offset: float) -> np.ndarray:
    """The start pose (x, y, yaw) moved by a random yaw and offset."""
    start = yaw_transform(float(start_pose[2]), (float(start_pose[0]), float(start_pose[1]), 0.0))
    r = rng.uniform(0, max_offset)
    phi = rng.uniform(-np.pi, np.pi)
    jitter = yaw_transform(rng.uniform(-np.pi, np.pi), (r * np.cos(phi), r * np.sin(phi), rng.uniform(-0.5, 0.5)))
    return start @ jitter


def _in_frame(imap: InstanceMap, T_scene_map: np.ndarray) -> InstanceMap:
    """The snapshot expressed in the agent's map frame."""
    pts = transform_points(invert_transform(T_scene_map), imap.points).astype(np.float32)
    return InstanceMap(points=pts, instance=imap.instance, labels=dict(imap.labels),
                       scores=dict(imap.scores), colors=imap.colors)


def downsample_per_instance(imap: InstanceMap, voxel: float) -> InstanceMap:
    """One point per occupied (voxel, instance) cell, so instances keep their own points."""
    vc = voxel_coords(imap.points, voxel)
    keys = pack_keys([vc[:, 0], vc[:, 1], vc[:, 2], imap.instance.astype(np.int64)])
    _, first = np.unique(keys, return_index=True)
    return select_points(imap, np.isin(np.arange(len(keys)), first))


FLOOR_LABELS = ("floor", "floors", "flooring", "ground", "ground floor")


def level_transform(scene: InstanceMap, min_tilt_deg: float = 1.0) -> np.ndarray:
    """Rotation (4x4) that makes the scene's labelled floor horizontal: some real scans lean by
    up to 15 degrees, while a robot's map is gravity-aligned by its IMU to about a degree.
    Identity when the scene labels no floor or leans by less than min_tilt_deg."""
    floor = np.isin(scene.instance, [i for i, l in scene.labels.items()
                                     if l.strip().lower() in FLOOR_LABELS])
    T = np.eye(4)
    if floor.sum() < 100:
        return T
    pts = scene.points[floor].astype(np.float64)
    n = np.linalg.svd(pts - pts.mean(0), full_matrices=False)[2][2]
    n = n if n[2] > 0 else -n
    if np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0))) < min_tilt_deg:
        return T
    T[:3, :3] = rotation_between(n, np.array([0.0, 0.0, 1.0]))
    return T


def object_correspondence(scene_a: InstanceMap, scene_b: InstanceMap, voxel: float = 0.1,
                          min_iou: float = 0.2) -> dict[int, int]:
    """b instance id -> a instance id for the labelled instances of two captures of one room,
    both in one frame: mutual best voxel IoU of at least min_iou (moved furniture has none)."""
    ma, mb = labelled_mask(scene_a), labelled_mask(scene_b)
    pairs, iou = node_iou(scene_b.points[mb], scene_b.instance[mb],
                          scene_a.points[ma], scene_a.instance[ma], voxel)
    keep = iou >= min_iou
    pairs, iou = pairs[keep], iou[keep]
    order = np.argsort(-iou, kind="stable")
    out, used = {}, set()
    for b_id, a_id in pairs[order].tolist():   # greedy by IoU: one partner each
        if b_id not in out and a_id not in used:
            out[b_id] = a_id
            used.add(a_id)
    return out


def held_objects(imap: InstanceMap, min_points: int, rename: dict[int, int] | None = None) -> list[int]:
    """Non-structural labelled instances with at least min_points points, renamed by `rename`
    (instances it does not name have no counterpart and are left out)."""
    ids, counts = np.unique(imap.instance[labelled_mask(imap)], return_counts=True)
    out = [int(i) for i, c in zip(ids, counts)
           if c >= min_points and not is_structural(imap.labels.get(int(i), ""))]
    if rename is not None:
        out = [rename[i] for i in out if i in rename]
    return sorted(out)


def simulate(scene: InstanceMap, rng: np.random.Generator, cfg: WalkConfig | None = None,
             progress=None, scene_b: InstanceMap | None = None) -> WalkRun:
    """Every agent's snapshot sequence. scene_b: a second capture of the room, in scene's
    frame, that b walks (default: b walks `scene` too). progress(fraction) is called as work
    proceeds."""
    cfg = cfg or WalkConfig()
    if not 2 <= cfg.agents <= len(AGENT_NAMES):
        raise ValueError(f"agents must be in [2, {len(AGENT_NAMES)}], got {cfg.agents}")
    rename = None if scene_b is None else object_correspondence(scene, scene_b)
    if cfg.voxel > 0:
        scene = downsample_per_instance(scene, cfg.voxel)
        scene_b = None if scene_b is None else downsample_per_instance(scene_b, cfg.voxel)
    scene_b = scene if scene_b is None else scene_b
    sensors = [SensorConfig(**{**sensor.__dict__, "period": cfg.mapping_period})
               for sensor in (cfg.sensor, cfg.sensor_b or cfg.sensor)]
    times_a, poses_a = make_trajectory(scene, rng, cfg.trajectory)
    if cfg.opposite:
        times_b, poses_b = reverse_trajectory(times_a, poses_a)
    else:
        traj_b = TrajectoryConfig(**{**cfg.trajectory.__dict__, "start": cfg.start_b})
        times_b, poses_b = make_trajectory(scene_b, rng, traj_b)
    walks = [("a", scene, times_a, poses_a, None, sensors[0]),
             ("b", scene_b, times_b, poses_b, rename, sensors[1])]
    for name in AGENT_NAMES[2:cfg.agents]:        # the others walk paths of their own
        traj = TrajectoryConfig(**{**cfg.trajectory.__dict__, "start": None, "random_start": True})
        walks.append((name, scene, *make_trajectory(scene, rng, traj), None, sensors[0]))
    runs = []
    for i, (name, walked, times, poses, names, sensor) in enumerate(walks):
        T = _map_frame(poses[0], rng, cfg.max_offset)
        seen = observe_sequence(walked, times, poses, sensor)
        snaps = [(t, _in_frame(m, T)) for t, m in seen]
        objects = [held_objects(m, cfg.object_min_points, names) for _, m in seen]
        runs.append(AgentRun(name, times, poses, T, snaps, objects))
        if progress:
            progress((i + 1) / len(walks))
    return WalkRun(runs)


def overlapping_views(names: list[str], seed: int = 0, rooms: int = 1) -> tuple[dict, dict]:
    """One synthetic scene seen whole by each agent (no walk): overlapping crops along x, disjoint
    point samples, each in its own random frame. ({name: InstanceMap}, {name: T_scene_map}):
    quick, static maps for node tests and probes."""
    from .synth.scene import SynthConfig, generate_scene

    rng = np.random.default_rng(seed)
    scene = generate_scene(seed, SynthConfig(rooms=rooms))
    x = scene.points[:, 0]
    lo, hi = x.min(), x.max()
    owner = rng.integers(0, len(names), x.size)            # each point sampled by one agent only
    maps, frames = {}, {}
    k = len(names)
    for i, name in enumerate(names):
        start = lo + (hi - lo) * 0.25 * i / max(k - 1, 1)
        keep = (x >= start) & (x <= start + 0.75 * (hi - lo)) & (owner == i)
        part = select_points(scene, keep)
        T = yaw_transform(rng.uniform(-np.pi, np.pi), (*rng.uniform(-8, 8, 2), 0.0))
        frames[name] = T
        maps[name] = InstanceMap(points=transform_points(np.linalg.inv(T), part.points).astype(np.float32),
                                 instance=part.instance, labels=part.labels, scores=part.scores)
    return maps, frames
