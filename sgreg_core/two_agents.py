"""Two agents walking through one scene: the instance maps each holds over time, each in its own
map frame, and the ground truth between the frames. What `sgreg make-bag` records.

Agent a walks a path across the scene; agent b walks the same path in the opposite direction
(the paper's hardest sequences: they see the same places at different times, from opposite
sides) or another path. Each agent's map frame is its start pose, with a random yaw and offset
on top, so no two frames agree and nothing can be learnt from where maps happen to start.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import invert_transform, pack_keys, transform_points, voxel_coords, yaw_transform
from .instance_map import select_points
from .observe import SensorConfig, TrajectoryConfig, make_trajectory, observe_sequence, reverse_trajectory
from .types import InstanceMap


@dataclass
class TwoAgentConfig:
    """opposite: b walks a's path backwards (else a second, independent path).
    mapping_period: seconds between two instance-map snapshots of one agent.
    voxel: snapshots are voxel-downsampled to this size (m) to keep messages and bags small.
    max_offset: the map frames' random offsets are up to this far (m) from the start poses."""

    opposite: bool = True
    mapping_period: float = 1.0
    voxel: float = 0.05
    max_offset: float = 10.0
    sensor: SensorConfig = field(default_factory=SensorConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)


@dataclass
class AgentRun:
    name: str
    times: np.ndarray                       # (T,) s, trajectory samples
    poses: np.ndarray                       # (T, 3) x, y, yaw in the scene frame
    T_scene_map: np.ndarray                 # 4x4: the agent's map frame in the scene frame
    snapshots: list[tuple[float, InstanceMap]]   # (t, map in the agent's map frame)


@dataclass
class TwoAgentRun:
    a: AgentRun
    b: AgentRun

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


def simulate(scene: InstanceMap, rng: np.random.Generator, cfg: TwoAgentConfig | None = None,
             progress=None) -> TwoAgentRun:
    """Both agents' snapshot sequences. progress(fraction) is called as work proceeds."""
    cfg = cfg or TwoAgentConfig()
    if cfg.voxel > 0:
        scene = downsample_per_instance(scene, cfg.voxel)
    sensor = SensorConfig(**{**cfg.sensor.__dict__, "period": cfg.mapping_period})
    times_a, poses_a = make_trajectory(scene, rng, cfg.trajectory)
    if cfg.opposite:
        times_b, poses_b = reverse_trajectory(times_a, poses_a)
    else:
        times_b, poses_b = make_trajectory(scene, rng, cfg.trajectory)
    runs = []
    for i, (name, times, poses) in enumerate((("a", times_a, poses_a), ("b", times_b, poses_b))):
        T = _map_frame(poses[0], rng, cfg.max_offset)
        snaps = [(t, _in_frame(m, T)) for t, m in observe_sequence(scene, times, poses, sensor)]
        runs.append(AgentRun(name, times, poses, T, snaps))
        if progress:
            progress((i + 1) / 2)
    return TwoAgentRun(*runs)
