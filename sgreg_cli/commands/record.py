"""sgreg record TOPICS --out DIR: record live topics into a rosbag2 directory (MCAP)."""
from __future__ import annotations

import sys

from ..topics import topic_name

NAME = "record"
HELP = "record live topics into a rosbag2 (MCAP)"


def add_arguments(p):
    p.add_argument("topics", nargs="+", type=topic_name, help="topics to record (their types are discovered)")
    p.add_argument("--out", required=True, help="new rosbag2 directory")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: Ctrl-C)")


def run(args) -> int:
    import rclpy

    from ..bags import BagError, BagRecorder, spin_for

    if not args.duration >= 0:   # NaN too: it would stop at once
        print(f"sgreg record: --duration must be >= 0 s (0: until Ctrl-C), got {args.duration}", file=sys.stderr)
        return 2
    rclpy.init()
    node = rclpy.create_node("sgreg_record")
    try:
        recorder = BagRecorder(node, args.out)
    except BagError as exc:
        print(f"sgreg record: {exc}", file=sys.stderr)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2

    refused: set = set()     # said once: discovery runs every half second

    def discover():
        for topic, types in node.get_topic_names_and_types():
            if topic in args.topics and topic not in recorder.connections and topic not in refused \
                    and node.get_publishers_info_by_topic(topic):    # its QoS is the publishers'
                try:
                    recorder.add_topic(topic, types[0])
                    print(f"recording {topic} ({types[0]})", flush=True)
                except BagError as exc:
                    refused.add(topic)
                    print(f"sgreg record: {topic} not recorded: {exc}", file=sys.stderr)

    node.create_timer(0.5, discover)
    print(f"recorder ready, waiting for {', '.join(args.topics)}", flush=True)
    try:
        spin_for(node, args.duration)
    finally:
        recorder.close()
        node.destroy_node()
        rclpy.try_shutdown()
    counts = ", ".join(f"{t}: {n}" for t, n in sorted(recorder.counts.items()) if n)
    print(f"recorded {sum(recorder.counts.values())} messages into {args.out}" + (f": {counts}" if counts else ""))
    return 0
