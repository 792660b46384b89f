"""sgreg bw [TOPICS] | sgreg bw --bag BAG: per-topic bandwidth, like `ros2 topic bw`."""
from __future__ import annotations

import sys
import time

from ..topics import topic_name

NAME = "bw"
HELP = "per-topic bandwidth of live topics or of a bag"


def add_arguments(p):
    p.add_argument("topics", nargs="*", type=topic_name, help="topics to watch (default: every topic with /sgreg/ in its name: the "
                   "agents' and a replay's /sgreg/ground_truth)")
    p.add_argument("--bag", help="report a rosbag2 directory instead of live topics")
    p.add_argument("--window", type=float, default=10.0, help="live: averaging window in seconds (msgs "
                   "and mean over the window; total since the start; default 10)")
    p.add_argument("--duration", type=float, default=0.0, help="live: stop after this many seconds (0: Ctrl-C)")


def _bag_report(bag: str, topics: list[str] | None) -> str:
    """The bandwidth table of a bag's `topics` (None: all); raises BagError."""
    from sgreg_core.bench.bandwidth import HEADER, BandwidthMeter, format_table

    from ..bags import open_bag, read_messages, select_connections

    reader = open_bag(bag)
    meter = BandwidthMeter()
    try:
        for conn, t_ns, raw in read_messages(reader, select_connections(reader, topics, bag), bag):
            meter.add(conn.topic, t_ns * 1e-9, len(raw))
        # first to last message of the whole recording (rosbags' end_time is the last + 1 ns);
        # a bag with no message has no time span (rosbags gives placeholders)
        span = (reader.end_time - 1 - reader.start_time) * 1e-9 if reader.message_count else 0.0
    finally:
        reader.close()
    # a recording shorter than a millisecond (one message) has no rate worth printing
    rows = meter.report(span=span if span >= 1e-3 else 0.0)
    if not rows:
        return f"bag {bag}: {span:.1f} s\n(no messages)"
    return (f"bag {bag}: {span:.1f} s (rates over the whole recording; '-': no time to divide by)\n"
            + format_table(HEADER, [r.as_row() for r in rows]))


def run(args) -> int:
    from sgreg_core.bench.bandwidth import HEADER, BandwidthMeter, format_table

    # NaN compares False: refused too
    if not args.bag and not (0 < args.window < float("inf") and 0 <= args.duration < float("inf")):
        print(f"sgreg bw: --window must be > 0 s and --duration >= 0 s (0: until Ctrl-C), got "
              f"{args.window} and {args.duration}", file=sys.stderr)
        return 2
    if args.bag:
        from ..bags import BagError

        try:
            print(_bag_report(args.bag, args.topics or None))
        except BagError as exc:
            print(f"sgreg bw: {exc}", file=sys.stderr)
            return 2
        return 0

    import rclpy
    from rclpy.qos import qos_profile_sensor_data

    from ..bags import message_class, spin_for

    rclpy.init()
    node = rclpy.create_node("sgreg_bw")
    meter = BandwidthMeter(window_s=args.window)
    watched: set[str] = set()

    def watch():
        for topic, types in node.get_topic_names_and_types():
            wanted = topic in args.topics if args.topics else "/sgreg/" in topic
            if wanted and topic not in watched:
                watched.add(topic)
                # best effort and volatile, as `ros2 topic bw`: matches every publisher (a
                # reliable reader hears nothing of a best-effort one) and counts no message
                # a transient-local publisher stored before bw joined
                node.create_subscription(message_class(types[0]), topic,
                                         lambda raw, t=topic: meter.add(t, time.monotonic(), len(raw)),
                                         qos_profile_sensor_data, raw=True)
                meter.watch(topic, time.monotonic())

    def show():
        rows = meter.report(now=time.monotonic())
        print(format_table(HEADER, [r.as_row() for r in rows]) if rows else "(no messages yet)", flush=True)

    node.create_timer(1.0, watch)
    node.create_timer(max(1.0, args.window / 5), show)
    try:
        spin_for(node, args.duration)
    finally:
        show()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
