"""sgreg make-bag SCAN_DIR --out bags/NAME: agents walk through a scan (two by default, --agents N);
their growing instance maps and the ground truth go into a rosbag2 directory (MCAP) plus
ground_truth.json.

With --scan-b and --gt, agent b walks another capture of the same room (moved into a's frame by
the pseudo ground truth of rescan_gt.json): furniture moved, coverage different. The knobs
that make early, small maps: --speed, --range, --fov, --waypoints, --start-a / --start-b."""
from __future__ import annotations

import json
import numbers
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from sgreg_core.config import finite_number

NAME = "make-bag"
HELP = "simulate agents walking in a scan and write a rosbag2 (MCAP)"
GT_TOPIC = "/sgreg/ground_truth"
T_ORIGIN = 1_700_000_000.0  # bag time origin (s): bag stamp = T_ORIGIN + simulation time


@dataclass
class BagSpec:
    """Everything that decides a bag (the simulation is seeded: one spec, one bag).

    scan / scan_b: instance-map directories; scan_b (optional) is the capture b walks, and then
        gt names the pseudo ground truth (rescan_gt.json) that relates it to scan.
    agents: how many agents walk (a, b, c, ...; the third on walk paths of their own).
    opposite: b walks a's path backwards (else its own path).
    speed (m/s), range (m), fov (deg): walk and sensor; range_b / fov_b: b's sensor when it
    differs (None: as a's); mapping_period: s between snapshots;
    voxel: m, snapshot downsampling; clearance: m kept from obstacles by the walks;
    waypoints: far-apart free cells each walk visits; start_a / start_b: scene x, y of the
    first waypoint of a's and (own path only) b's walk, None: seeded; random_start: a seeded
    walk starts anywhere (else at a far end of the free space, where most seeds agree).
    level: rotate the scans so that their labelled floor is horizontal (robot maps are
        gravity-aligned; some scans lean)."""

    scan: str
    scan_b: str | None = None
    gt: str | None = None
    seed: int = 0
    agents: int = 2
    opposite: bool = True
    speed: float = 0.5
    range: float = 4.0
    fov: float = 90.0
    range_b: float | None = None
    fov_b: float | None = None
    mapping_period: float = 1.0
    voxel: float = 0.08
    clearance: float = 0.3
    waypoints: int = 2
    start_a: tuple[float, float] | None = None
    start_b: tuple[float, float] | None = None
    random_start: bool = False
    level: bool = True

    def __post_init__(self):
        """Refuse settings out of _LIMITS here, so that CLI flags and suite files alike get a
        clear BagSpecError before any simulation."""
        for name, (lo, hi, unit) in _LIMITS.items():
            value = getattr(self, name)
            if value is None and name in ("range_b", "fov_b"):
                continue
            integral = name in ("seed", "waypoints", "agents")
            if isinstance(value, bool) or not isinstance(value, numbers.Integral if integral else numbers.Real) \
                    or not lo <= value <= hi:     # NaN fails the comparison
                raise BagSpecError(f"{name} (--{name.replace('_', '-')}) must be "
                                   f"{'an integer' if integral else 'a number'} in [{lo:g}, {hi:g}]{unit}, "
                                   f"got {value!r}")
        for name in ("start_a", "start_b"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (tuple, list)) and len(value) == 2
                                          and all(finite_number(v) for v in value)):
                raise BagSpecError(f"{name} (--{name.replace('_', '-')}) must be two finite numbers "
                                   f"(scene x, y in m), got {value!r}")
        # settings that would be ignored, and yet recorded in the bag's ground truth
        if self.scan_b and not self.gt:
            raise BagSpecError("a second capture (scan_b) needs its pseudo ground truth (gt)")
        if self.gt and not self.scan_b:
            raise BagSpecError("gt (--gt) moves a second capture: give it with scan_b (--scan-b)")
        if self.start_b is not None and self.opposite:
            raise BagSpecError("start_b (--start-b) is where b starts its own path: it needs "
                               "same-direction walks (--same-direction); opposite walks retrace a's")


class BagSpecError(ValueError):
    """A spec that cannot become a bag (missing scan, pair without accepted ground truth, a
    setting out of range)."""


# BagSpec field -> (lowest, highest, unit). Outside these a walk fails (negative speed), eats
# the memory (a clearance dilates the obstacle grid by its square; tiny periods or speeds make
# millions of snapshots or poses) or maps nothing (the sensor sees nothing nearer than 0.3 m,
# SensorConfig.min_range, or with no field of view).
_LIMITS = {
    "seed": (0, 2**63 - 1, ""),
    "speed": (0.05, 10.0, " m/s"),
    "range": (0.5, 100.0, " m"),
    "range_b": (0.5, 100.0, " m"),
    "fov": (1.0, 360.0, " deg"),
    "fov_b": (1.0, 360.0, " deg"),
    "mapping_period": (0.2, 3600.0, " s"),    # 0.2: the walk's 5 poses a second
    "voxel": (0.0, 1.0, " m"),                # 0: no downsampling
    "clearance": (0.0, 2.0, " m"),
    "waypoints": (2, 100, ""),
    "agents": (2, 26, ""),                    # a to z
}


def add_arguments(p):
    p.add_argument("scan", help="instance map directory (points.npy, instance.npy, instances.json)")
    p.add_argument("--out", required=True, help="new rosbag2 directory, e.g. bags/apartment")
    p.add_argument("--scan-b", help="another capture of the same room for agent b (needs --gt)")
    p.add_argument("--gt", help="pseudo ground truth between captures (rescan_gt.json)")
    p.add_argument("--seed", type=int, default=0, help="seed of the walks")
    p.add_argument("--agents", type=int, default=2,
                   help="how many agents walk (a, b, c, ...; from the third on, each on a path of its own)")
    p.add_argument("--same-direction", action="store_true",
                   help="b walks its own path (default: a's path in the opposite direction)")
    p.add_argument("--mapping-period", type=float, default=1.0, help="seconds between map snapshots")
    p.add_argument("--voxel", type=float, default=0.08, help="map points are downsampled to this (m)")
    p.add_argument("--speed", type=float, default=0.5, help="walking speed (m/s)")
    p.add_argument("--range", type=float, default=4.0, help="sensor range (m)")
    p.add_argument("--fov", type=float, default=90.0, help="horizontal field of view (deg)")
    p.add_argument("--range-b", type=float, help="b's sensor range (m), if not a's")
    p.add_argument("--fov-b", type=float, help="b's field of view (deg), if not a's")
    p.add_argument("--clearance", type=float, default=0.3, help="distance walks keep from obstacles (m)")
    p.add_argument("--waypoints", type=int, default=2, help="far-apart places each walk visits (2: one crossing)")
    p.add_argument("--start-a", type=_xy, help="X,Y: where a starts (scene frame, m)")
    p.add_argument("--start-b", type=_xy, help="X,Y: where b starts (own path only)")
    p.add_argument("--random-start", action="store_true",
                   help="seeded walks start anywhere (default: at a far end of the free space)")
    p.add_argument("--no-level", action="store_true", help="keep the scans' own vertical")


def _xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"expected X,Y, got {text!r}") from None
    return x, y


def rescan_transform(scan: str, scan_b: str, gt_path: str):
    """T (4x4) mapping scan_b's points into scan's frame, from an accepted rescan_gt.json entry."""
    from sgreg_core.rescan_gt import RescanGTError, load_rescan_gt, transform_between

    try:
        return transform_between(load_rescan_gt(gt_path), Path(scan).name, Path(scan_b).name, gt_path)
    except RescanGTError as exc:
        raise BagSpecError(str(exc)) from None


def make_bag(spec: BagSpec, out: str | Path, log=lambda s: None) -> dict:
    """Simulate the walks of `spec` and write the bag directory `out` (MCAP, zstd) with its
    ground_truth.json; returns that ground truth. Raises BagSpecError on bad input."""
    import shutil

    import numpy as np

    from sgreg_core.maps.instance_map import InstanceMapError, read_instance_map
    from sgreg_core.paths import make_folder
    from sgreg_core.simulation.observe import SensorConfig, TrajectoryConfig, walkable_share
    from sgreg_core.simulation.walks import WalkConfig, level_transform, simulate

    out = Path(out)
    if out.exists():
        raise BagSpecError(f"{out} exists; choose a new directory")
    try:    # before simulating: a folder the bag cannot go into is said at once
        make_folder(out.parent)
    except OSError as exc:
        raise BagSpecError(str(exc)) from None
    try:
        scene = read_instance_map(spec.scan)
        scene_b = read_instance_map(spec.scan_b) if spec.scan_b else None
    except InstanceMapError as exc:
        raise BagSpecError(str(exc)) from None

    T_level = level_transform(scene) if spec.level else np.eye(4)
    T_b_capture = np.eye(4)   # b's capture frame -> a's scan frame
    if scene_b is not None:
        T_b_capture = rescan_transform(spec.scan, spec.scan_b, spec.gt)
        scene_b = scene_b.transformed(T_level @ T_b_capture)
    scene = scene.transformed(T_level)
    walks = (("start_a", spec.start_a, scene), ("start_b", spec.start_b, scene if scene_b is None else scene_b))
    for name, start, walked in walks:
        # the walk would start at the free cell nearest to it: far from where it was asked
        lo, hi = walked.points[:, :2].min(axis=0), walked.points[:, :2].max(axis=0)
        if start is not None and not np.all((lo - 1.0 <= np.asarray(start)) & (np.asarray(start) <= hi + 1.0)):
            raise BagSpecError(f"{name} ({start[0]:g}, {start[1]:g}) lies outside the scene (x in "
                               f"[{lo[0]:.1f}, {hi[0]:.1f}], y in [{lo[1]:.1f}, {hi[1]:.1f}] m)")
    cfg = WalkConfig(agents=spec.agents, opposite=spec.opposite, mapping_period=spec.mapping_period,
                     voxel=spec.voxel, start_b=spec.start_b,
                     sensor=SensorConfig(max_range=spec.range, hfov_deg=spec.fov),
                     sensor_b=SensorConfig(max_range=spec.range if spec.range_b is None else spec.range_b,
                                           hfov_deg=spec.fov if spec.fov_b is None else spec.fov_b),
                     trajectory=TrajectoryConfig(speed=spec.speed, clearance=spec.clearance,
                                                 waypoints=spec.waypoints, start=spec.start_a,
                                                 random_start=spec.random_start))
    try:
        # walks keep to the largest connected free area: said, since a room behind a closed
        # door is then seen (occlusion is not modelled) but never walked
        share = walkable_share(scene, cfg.trajectory)
        log(f"simulating {spec.agents} agents in {spec.scan} (walks reach {share:.0%} of its free floor"
            + ("; closed doors or furniture cut off the rest)" if share < 0.95 else ")") + " ...")
        sim = simulate(scene, np.random.default_rng(spec.seed), cfg, scene_b=scene_b,
                       progress=lambda f: log(f"  agents simulated: {f:.0%}"))
    except ValueError as exc:   # e.g. no free space to walk in
        raise BagSpecError(f"{spec.scan}: {exc}") from None
    try:
        info = _write_bag(out, spec, sim, T_level, T_b_capture, log)
    except BaseException:
        # Ctrl-C or a full disk half-way: no partial bag that a rerun would refuse as existing
        shutil.rmtree(out, ignore_errors=True)
        raise
    return info


def _write_bag(out: Path, spec: BagSpec, sim, T_level, T_b_capture, log) -> dict:
    import numpy as np
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from ..bag_types import typestore
    from ..bags import offered_qos, qos_for, seal_chunks
    from sgreg_ros.convert import instance_map_to_msg, transform_msg

    from sgreg_core.runtime.clock import seconds_to_ns

    T = sim.T_a_b
    store = typestore()

    def cdr(msg, msgtype: str) -> bytes:
        # through rosbags, which zero-fills CDR padding (rclpy leaves it uninitialised): the
        # same command makes the same bytes
        return bytes(store.serialize_cdr(store.deserialize_cdr(serialize_message(msg), msgtype), msgtype))

    events = [(t, agent.name, m) for agent in sim.agents for t, m in agent.snapshots]
    events.sort(key=lambda e: (e[0], e[1]))
    seq = {agent.name: 0 for agent in sim.agents}
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    # zstd chunks inside the MCAP (rosbag2's "storage" compression): point clouds shrink ~2x
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer as w:
        conns = {name: w.add_connection(f"/{name}/mapping/instances", "sgreg_msgs/msg/InstanceMap", typestore=store,
                                        offered_qos_profiles=[offered_qos(qos_for(f"/{name}/mapping/instances"))])
                 for name in seq}
        gt = w.add_connection(GT_TOPIC, "geometry_msgs/msg/TransformStamped", typestore=store,
                              offered_qos_profiles=[offered_qos(qos_for(GT_TOPIC))])
        for i, (t, name, imap) in enumerate(events):
            stamp_ns = int(T_ORIGIN) * 1_000_000_000 + seconds_to_ns(t)   # exact: no epoch in a float
            msg = instance_map_to_msg(imap, name, seq[name], stamp_ns)
            seq[name] += 1
            w.write(conns[name], stamp_ns, cdr(msg, "sgreg_msgs/msg/InstanceMap"))
            if name == "a":
                w.write(gt, stamp_ns + 1, cdr(transform_msg(T, "a", "b", stamp_ns), "geometry_msgs/msg/TransformStamped"))
            if i % 10 == 0 or i == len(events) - 1:
                log(f"  writing: {i + 1}/{len(events)} messages")
    seal_chunks(out)
    info = {
        "T_a_b": T.tolist(),
        "description": "T_scene_map: each agent's map frame (<id>/map) in the scene's frame, for "
                       "every agent; T_a_b maps points of a's map frame into b's (b/map); also on "
                       f"{GT_TOPIC} (header.frame_id b/map, child_frame_id a/map). objects: per "
                       "agent, [t, ids] per snapshot (bag stamp = t_origin + t): the objects "
                       "its map holds, named by a's instance ids (b's from another capture "
                       "renamed by overlap under the pseudo ground truth)",
        "T_scene_map": {r.name: r.T_scene_map.tolist() for r in sim.agents},
        "T_level": T_level.tolist(),
        "T_b_capture": T_b_capture.tolist(),
        "t_origin": T_ORIGIN,
        "objects": {r.name: [[t, ids] for (t, _), ids in zip(r.snapshots, r.objects)]
                    for r in sim.agents},
        "scan": str(spec.scan), "scan_b": spec.scan_b, "seed": spec.seed,
        "agents": {r.name: {"snapshots": len(r.snapshots), "duration_s": float(r.times[-1]),
                            "path_length_m": float(np.linalg.norm(np.diff(r.poses[:, :2], axis=0), axis=1).sum()),
                            "final_points": int(r.snapshots[-1][1].points.shape[0]) if r.snapshots else 0,
                            "final_instances": len(r.snapshots[-1][1].labels) if r.snapshots else 0}
                   for r in sim.agents},
        "config": asdict(spec),
    }
    (out / "ground_truth.json").write_text(json.dumps(info, indent=1) + "\n")
    return info


def run(args) -> int:
    try:
        spec = BagSpec(scan=args.scan, scan_b=args.scan_b, gt=args.gt, seed=args.seed,
                       agents=args.agents, opposite=not args.same_direction, speed=args.speed, range=args.range,
                       fov=args.fov, range_b=args.range_b, fov_b=args.fov_b,
                       mapping_period=args.mapping_period, voxel=args.voxel,
                       clearance=args.clearance, waypoints=args.waypoints,
                       start_a=args.start_a, start_b=args.start_b,
                       random_start=args.random_start, level=not args.no_level)
        info = make_bag(spec, args.out, log=lambda s: print(s, file=sys.stderr, flush=True))
    except BagSpecError as exc:
        print(f"sgreg make-bag: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    size = sum(f.stat().st_size for f in out.iterdir())
    n = sum(a["snapshots"] for a in info["agents"].values())
    print(f"wrote {out}: {n} instance maps, {size / 1e6:.1f} MB; ground truth in {out / 'ground_truth.json'}")
    return 0
