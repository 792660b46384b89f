"""sgreg attack [--peers 50] [--rate 10] [--seconds 60] [--unauthenticated] [--out DIR]: a flood of
fake peers against real nodes, measured: two agents (a, b) register over DDS on loopback, then
N fake agents publish coarse graphs (copies of b's) on their own topics at R Hz for S seconds.
Reports the CPU share of a's registration node before, during and after the flood, whether a
still holds a verified transform of b, and the peers it keeps. The other probes of a hostile
process (forged and moved graphs, malformed clouds, sequence numbers, forged requests) are
replayed against real nodes by tests/ros/test_attack.py."""
from __future__ import annotations

import copy
import json
import tempfile
import time
from pathlib import Path

NAME = "attack"
HELP = "flood real nodes with fake peers and measure their CPU and state"


def add_arguments(p):
    p.add_argument("--peers", type=int, default=50, help="fake peers flooding the nodes")
    p.add_argument("--rate", type=float, default=10.0, help="messages per second per fake peer")
    p.add_argument("--seconds", type=float, default=60.0, help="how long the flood lasts")
    p.add_argument("--unauthenticated", action="store_true", help="run the nodes without a keystore")
    p.add_argument("--out", default="results/attack", help="output folder (results.json, node logs)")


def run(args) -> int:
    import psutil
    import rclpy
    from sgreg_msgs.msg import CoarseGraph, InstanceMap

    from sgreg_core.runtime.auth import init_keystore
    from sgreg_core.simulation.walks import overlapping_views
    from sgreg_ros import qos
    from sgreg_ros.convert import instance_map_to_msg

    from ..processes import start_agents, stop

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = tempfile.TemporaryDirectory(prefix="sgreg-keys-")
    overrides = {} if args.unauthenticated else {"keystore": keys.name}
    if not args.unauthenticated:
        init_keystore(keys.name, ["a", "b"])
    maps, _ = overlapping_views(["a", "b"], seed=21)
    procs = start_agents(["a", "b"], overrides=overrides, log_dir=out / "logs")
    reg_a = next(psutil.Process(p.proc.pid) for p in procs if (p.agent, p.executable) == ("a", "registration"))
    rclpy.init()
    node = rclpy.create_node("sgreg_attack")
    coarse_b, verified = [], []
    node.create_subscription(CoarseGraph, "/b/sgreg/coarse", coarse_b.append, qos.COARSE_SUB)
    from geometry_msgs.msg import TransformStamped
    node.create_subscription(TransformStamped, "/a/sgreg/transform", verified.append, qos.RESULTS)
    map_pubs = {n: node.create_publisher(InstanceMap, f"/{n}/mapping/instances", qos.INSTANCES) for n in maps}
    seq = [0]

    def spin(seconds, flood=None):
        end, next_map = time.monotonic() + seconds, 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_map:
                seq[0] += 1
                for n, m in maps.items():
                    map_pubs[n].publish(instance_map_to_msg(m, n, seq[0], time.time_ns()))
                next_map = time.monotonic() + 1.0
            if flood:
                flood()
            rclpy.spin_once(node, timeout_sec=0.005)

    def cpu_share(seconds, flood=None):
        t0, c0 = time.monotonic(), sum(reg_a.cpu_times()[:2])
        spin(seconds, flood)
        return (sum(reg_a.cpu_times()[:2]) - c0) / (time.monotonic() - t0)

    report = {"config": vars(args)}
    try:
        print("[attack] waiting for a and b to register", flush=True)
        deadline = time.monotonic() + 180
        while not (verified and coarse_b) and time.monotonic() < deadline:
            spin(1.0)
        report["registered_before"] = bool(verified)
        spin(25.0)     # past quiet_after_s: the quiet baseline
        report["cpu_before"] = cpu_share(20.0)
        fakes = [node.create_publisher(CoarseGraph, f"/fake{k}/sgreg/coarse", qos.COARSE) for k in range(args.peers)]
        period, next_at = 1.0 / args.rate, [time.monotonic()]
        count = [0]

        def flood():
            if time.monotonic() < next_at[0]:
                return
            next_at[0] += period
            for k, pub in enumerate(fakes):
                m = copy.deepcopy(coarse_b[-1])
                m.agent_id, m.sequence = f"fake{k}", count[0] + 1
                pub.publish(m)
            count[0] += 1

        print(f"[attack] {args.peers} fake peers at {args.rate:g} Hz for {args.seconds:g} s", flush=True)
        verified.clear()
        report["cpu_during"] = cpu_share(args.seconds, flood)
        report["fake_messages"] = count[0] * args.peers
        report["registered_during"] = bool(verified)
        for pub in fakes:
            node.destroy_publisher(pub)
        spin(5.0)
        report["cpu_after"] = cpu_share(20.0)
        report["listening_to_fakes"] = sum(node.count_subscribers(f"/fake{k}/sgreg/coarse") > 0
                                           for k in range(args.peers))
    finally:
        stop(procs)
        node.destroy_node()
        rclpy.try_shutdown()
        keys.cleanup()
    ratio = report["cpu_during"] / max(report["cpu_before"], 1e-3)
    report["cpu_ratio"] = ratio
    print(f"a's registration node: CPU {report['cpu_before']:.1%} before, {report['cpu_during']:.1%} "
          f"during ({ratio:.2f}x), {report['cpu_after']:.1%} after; registered during the flood: "
          f"{report['registered_during']}; subscribed to {report['listening_to_fakes']} fake peers after it")
    (out / "results.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"results: {out / 'results.json'}")
    return 0
