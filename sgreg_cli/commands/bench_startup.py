"""sgreg bench-startup [--scan DIR] [--runs N] [--out DIR]: how fast sgreg starts and stops, as
whole processes: `sgreg register` on a noisy pair beside a KISS-Matcher process on the same
pair, a node from launch to its first coarse graph out (its map published as soon as it
listens), and a node from SIGINT to exit (during start-up and once up). Prints a table, writes
results.json with the resolved config."""
from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

NAME = "bench-startup"
HELP = "time whole processes: sgreg register vs KISS-Matcher, node ready, node shutdown"

# KISS-Matcher alone in a fresh process, as a user would run it on the pair's points
_KISS = """
import sys, numpy as np, kiss_matcher as km
src, ref = (np.load(f"{d}/points.npy").astype(np.float32) for d in sys.argv[1:3])
sol = km.KISSMatcher(km.KISSMatcherConfig(0.05)).estimate(src, ref)
print("valid", sol.valid)
"""


@dataclass
class StartupConfig:
    """runs: repetitions of each measurement (medians are reported); scan: instance map to cut
    the noisy pair from (default: a synthetic apartment); seed: the pair's cut and noise."""

    runs: int = 5
    scan: str = ""
    seed: int = 0
    noise: str = "jitter,overseg,drop,paraphrase,partial"


def add_arguments(p):
    p.add_argument("--scan", default="",
                   help="instance map directory to cut the pair from (default: a synthetic apartment)")
    p.add_argument("--runs", type=int, default=5, help="repetitions of each measurement (medians are reported)")
    p.add_argument("--seed", type=int, default=0, help="seed of the cut pair")
    p.add_argument("--out", default="results/bench_startup", help="output folder")


def _pair(cfg: StartupConfig, root: Path) -> Path:
    import numpy as np

    from sgreg_core.maps.instance_map import read_instance_map
    from sgreg_core.simulation.noise import NoiseConfig
    from sgreg_core.simulation.pairs import PairConfig, make_pair, write_pair
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    scene = read_instance_map(cfg.scan) if cfg.scan else generate_scene(cfg.seed, SynthConfig())
    pair = make_pair(scene, PairConfig(noise=NoiseConfig.preset(cfg.noise)), np.random.default_rng(cfg.seed))
    write_pair(pair, root / "pair")
    return root / "pair"


class ProcessFailed(RuntimeError):
    """A timed process that failed: its time is not the time of the work it was to do."""


def _timed(cmd: list[str], what: str) -> float:
    """Seconds `cmd` ran; ProcessFailed (with the end of its stderr) when it exits non-zero."""
    t0 = time.perf_counter()
    res = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["no output"])[-1]
        raise ProcessFailed(f"{what} exited with {res.returncode} ({last}): not timed")
    return time.perf_counter() - t0


def _stopped(proc, what: str) -> None:
    """After SIGINT: ProcessFailed unless the node exited cleanly (a crash is no shutdown)."""
    proc.wait(timeout=30)
    if proc.returncode != 0:
        raise ProcessFailed(f"{what} exited with {proc.returncode} on SIGINT: not timed")


def _node_ready(node, exe: str, agent: str, imap) -> tuple[float, float]:
    """(s to first coarse graph out, s from SIGINT to exit) of one agent node."""
    import rclpy
    from sgreg_msgs.msg import CoarseGraph, InstanceMap

    from sgreg_ros import qos
    from sgreg_ros.convert import instance_map_to_msg

    got = []
    sub = node.create_subscription(CoarseGraph, f"/{agent}/sgreg/coarse", got.append, qos.COARSE_SUB)
    pub = node.create_publisher(InstanceMap, f"/{agent}/mapping/instances", qos.INSTANCES)
    try:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "sgreg_ros", exe, "--ros-args", "-r", f"__ns:=/{agent}"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        sent = False
        while not got and time.perf_counter() - t0 < 60:
            if proc.poll() is not None:     # crashed while starting: no shutdown to time either
                raise ProcessFailed(f"the {exe} node exited with {proc.returncode} during start-up: not timed")
            if not sent and pub.get_subscription_count() > 0:
                pub.publish(instance_map_to_msg(imap, agent, 1, time.time_ns()))
                sent = True
            rclpy.spin_once(node, timeout_sec=0.01)
        ready = time.perf_counter() - t0
        t1 = time.perf_counter()
        os.killpg(proc.pid, signal.SIGINT)
        _stopped(proc, f"the {exe} node")
        if not got:
            raise ProcessFailed(f"the {exe} node sent no coarse graph within 60 s: not timed")
        return ready, time.perf_counter() - t1
    finally:
        node.destroy_subscription(sub)
        node.destroy_publisher(pub)


def _stop_during_startup(exe: str, after_s: float) -> float:
    proc = subprocess.Popen([sys.executable, "-m", "sgreg_ros", exe, "--ros-args", "-r", "__ns:=/s"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    time.sleep(after_s)
    t0 = time.perf_counter()
    os.killpg(proc.pid, signal.SIGINT)
    _stopped(proc, f"the {exe} node")
    return time.perf_counter() - t0


def run(args) -> int:
    import rclpy

    from sgreg_core.maps.instance_map import read_instance_map

    from sgreg_core.bench.bandwidth import format_table

    cfg = StartupConfig(runs=args.runs, scan=args.scan, seed=args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        pair = _pair(cfg, Path(tmp))
        sgreg = [sys.executable, "-m", "sgreg_cli.main", "register", str(pair / "src"), str(pair / "ref")]
        kiss = [sys.executable, "-c", _KISS, str(pair / "src"), str(pair / "ref")]
        rows: dict[str, list[float]] = {}
        for k in range(cfg.runs):
            print(f"[bench-startup] run {k + 1}/{cfg.runs}: register processes", flush=True)
            try:
                rows.setdefault("sgreg register (whole process)", []).append(_timed(sgreg, "sgreg register"))
                rows.setdefault("KISS-Matcher (whole process)", []).append(_timed(kiss, "KISS-Matcher"))
            except ProcessFailed as exc:
                print(f"sgreg bench-startup: {exc}", file=sys.stderr)
                return 2
        imap = read_instance_map(pair / "ref")
        rclpy.init()
        node = rclpy.create_node("sgreg_bench_startup")
        try:
            for k in range(cfg.runs):
                print(f"[bench-startup] run {k + 1}/{cfg.runs}: nodes", flush=True)
                for exe in ("agent",):
                    ready, stop = _node_ready(node, exe, f"s{k}", imap)
                    rows.setdefault(f"{exe} node: start -> first coarse out", []).append(ready)
                    rows.setdefault(f"{exe} node: SIGINT -> exit (up)", []).append(stop)
                for exe in ("agent", "registration"):
                    rows.setdefault(f"{exe} node: SIGINT -> exit (1 s into start-up)", []).append(
                        _stop_during_startup(exe, 1.0))
        except ProcessFailed as exc:
            print(f"sgreg bench-startup: {exc}", file=sys.stderr)
            return 2
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    table = {name: {"median_s": statistics.median(v), "max_s": max(v), "runs": v} for name, v in rows.items()}
    print(format_table(["whole process", "median s", "max s"],
                            [[n, f"{t['median_s']:.2f}", f"{t['max_s']:.2f}"] for n, t in table.items()]))
    (out / "results.json").write_text(json.dumps({"config": asdict(cfg), "results": table}, indent=1) + "\n")
    print(f"results: {out / 'results.json'}")
    return 0
