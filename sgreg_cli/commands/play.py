"""sgreg play BAG [--rate R] [--clock [HZ]]: publish a recorded bag with its original timing
(and its time on /clock, for nodes run with use_sim_time)."""
from __future__ import annotations

import signal
import sys

from ..topics import topic_name

NAME = "play"
HELP = "publish a recorded bag with its original timing"


def add_arguments(p):
    p.add_argument("bag", help="rosbag2 directory (metadata.yaml + .mcap)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--topics", nargs="*", type=topic_name, help="play only these topics (default: all)")
    p.add_argument("--delay", type=float, default=1.0,
                   help="seconds between advertising the topics and the first message")
    p.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                   help="first wait up to S seconds until every topic has a subscriber")
    p.add_argument("--clock", type=float, nargs="?", const=40.0, default=0.0, metavar="HZ",
                   help="publish the bag's time on /clock, at HZ (40 when no HZ is given, as ros2 bag "
                        "play); default: no /clock")


def run(args) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    from ..bags import BagError, open_bag, play_bag

    inf = float("inf")
    bad = [f"--{name} must be {rule}, got {value}" for name, value, ok, rule in (
        ("rate", args.rate, 0 < args.rate < inf, "a positive number"),
        ("delay", args.delay, 0 <= args.delay < inf, ">= 0 s"),
        ("wait-subscribers", args.wait_subscribers, 0 <= args.wait_subscribers < inf, ">= 0 s"),
        ("clock", args.clock, 0 <= args.clock < inf, ">= 0 Hz (0: no /clock)")) if not ok]
    if bad:    # NaN compares False: refused too
        print(f"sgreg play: {bad[0]}", file=sys.stderr)
        return 2
    try:
        open_bag(args.bag).close()      # a bad bag is said before anything is announced
    except BagError as exc:
        print(f"sgreg play: {exc}", file=sys.stderr)
        return 2
    # Ctrl-C is Python's KeyboardInterrupt (even where the shell started play with SIGINT
    # ignored, as rclpy's handler took it before) and rclpy takes SIGTERM only: with both to
    # rclpy, its thread shut the context down and play could see that before the interrupt,
    # reporting a shutdown for a Ctrl-C
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rclpy.init(signal_handler_options=SignalHandlerOptions.SIGTERM)
    node = rclpy.create_node("sgreg_play")
    print(f"sgreg play: playing {args.bag}", file=sys.stderr, flush=True)
    try:
        report = play_bag(node, args.bag, rate=args.rate, topics=args.topics, delay=args.delay,
                          wait_subscribers=args.wait_subscribers, clock_hz=args.clock,
                          log=lambda s: print(f"sgreg play: {s}", file=sys.stderr, flush=True))
    except BagError as exc:
        print(f"sgreg play: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except Exception:
        if rclpy.ok():
            raise
        return 0     # SIGTERM shut the context down between a check and a publish
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print((f"stopped by {report.interrupted}: " if report.interrupted else "") + f"played {report.published} messages "
          + ", ".join(f"{t}: {n}" for t, n in sorted(report.per_topic.items())))
    if report.corrupted:
        print(f"{len(report.corrupted)} corrupted messages skipped: "
              + "; ".join(f"#{i} on {t}" for t, i, _ in report.corrupted))
    # 128 + SIGINT, as a shell reports Ctrl-C; a shutdown (SIGTERM, as launch stops nodes) is clean
    return 130 if report.interrupted == "Ctrl-C" else 0
