"""sgreg make-bag SCAN_DIR --out bags/NAME: two agents walk through a scan; their growing instance
maps and the ground truth go into a rosbag2 directory (MCAP) plus ground_truth.json."""
from __future__ import annotations

import json
import sys
from pathlib import Path

NAME = "make-bag"
HELP = "simulate two agents in a scan and write a rosbag2 (MCAP)"
GT_TOPIC = "/sgreg/ground_truth"


def add_arguments(p):
    p.add_argument("scan", help="instance map directory (points.npy, instance.npy, instances.json)")
    p.add_argument("--out", required=True, help="new rosbag2 directory, e.g. bags/apartment")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--same-direction", action="store_true",
                   help="b walks its own path (default: a's path in the opposite direction)")
    p.add_argument("--mapping-period", type=float, default=1.0, help="seconds between map snapshots")
    p.add_argument("--voxel", type=float, default=0.08, help="map points are downsampled to this (m)")
    p.add_argument("--speed", type=float, default=0.5, help="walking speed (m/s)")
    p.add_argument("--range", type=float, default=4.0, help="sensor range (m)")


def run(args) -> int:
    import numpy as np
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from sgreg_ros.bag_types import typestore
    from sgreg_ros.convert import instance_map_to_msg, transform_msg

    from ..instance_map import InstanceMapError, read_instance_map
    from ..observe import SensorConfig, TrajectoryConfig
    from ..two_agents import TwoAgentConfig, simulate

    out = Path(args.out)
    if out.exists():
        print(f"sgreg make-bag: {out} exists; choose a new directory", file=sys.stderr)
        return 2
    try:
        scene = read_instance_map(args.scan)
    except InstanceMapError as exc:
        print(f"sgreg make-bag: {exc}", file=sys.stderr)
        return 2
    cfg = TwoAgentConfig(opposite=not args.same_direction, mapping_period=args.mapping_period,
                         voxel=args.voxel, sensor=SensorConfig(max_range=args.range),
                         trajectory=TrajectoryConfig(speed=args.speed))
    rng = np.random.default_rng(args.seed)
    print(f"simulating two agents in {args.scan} ...", file=sys.stderr, flush=True)
    sim = simulate(scene, rng, cfg, progress=lambda f: print(f"  agents simulated: {f:.0%}", file=sys.stderr, flush=True))
    T = sim.T_a_b
    store = typestore()
    t0 = 1_700_000_000.0  # bag time origin (s); the replay only uses differences
    events = [(t, agent.name, m) for agent in (sim.a, sim.b) for t, m in agent.snapshots]
    events.sort(key=lambda e: (e[0], e[1]))
    seq = {"a": 0, "b": 0}
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    # zstd chunks inside the MCAP (rosbag2's "storage" compression): point clouds shrink ~2x
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer as w:
        conns = {name: w.add_connection(f"/{name}/mapping/instances", "sgreg_msgs/msg/InstanceMap", typestore=store)
                 for name in ("a", "b")}
        gt = w.add_connection(GT_TOPIC, "geometry_msgs/msg/TransformStamped", typestore=store)
        for i, (t, name, imap) in enumerate(events):
            stamp = t0 + t
            msg = instance_map_to_msg(imap, name, seq[name], stamp)
            seq[name] += 1
            w.write(conns[name], int(stamp * 1e9), serialize_message(msg))
            if name == "a":
                w.write(gt, int(stamp * 1e9) + 1, serialize_message(transform_msg(T, "a", "b", stamp)))
            if i % 10 == 0 or i == len(events) - 1:
                print(f"  writing: {i + 1}/{len(events)} messages", file=sys.stderr, flush=True)
    info = {
        "T_a_b": T.tolist(),
        "description": "T_a_b maps points of a's map frame (a/map) into b's (b/map); also on "
                       f"{GT_TOPIC} (header.frame_id b/map, child_frame_id a/map)",
        "T_scene_map": {r.name: r.T_scene_map.tolist() for r in (sim.a, sim.b)},
        "scan": str(args.scan), "seed": args.seed,
        "agents": {r.name: {"snapshots": len(r.snapshots), "duration_s": float(r.times[-1]),
                            "path_length_m": float(np.linalg.norm(np.diff(r.poses[:, :2], axis=0), axis=1).sum()),
                            "final_points": int(r.snapshots[-1][1].points.shape[0]) if r.snapshots else 0,
                            "final_instances": len(r.snapshots[-1][1].labels) if r.snapshots else 0}
                   for r in (sim.a, sim.b)},
        "config": {"opposite": cfg.opposite, "mapping_period": cfg.mapping_period, "voxel": cfg.voxel,
                   "speed": args.speed, "sensor_range": args.range},
    }
    (out / "ground_truth.json").write_text(json.dumps(info, indent=1) + "\n")
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out}: {len(events)} instance maps, {size / 1e6:.1f} MB; ground truth in {out / 'ground_truth.json'}")
    return 0
