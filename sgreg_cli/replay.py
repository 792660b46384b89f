"""`sgreg replay`: start every agent's nodes as separate processes, play a bag of two or more
agents into them, collect every published estimate, the merged frame the agents publish on
/tf, the traffic between agents, and the nodes' CPU and memory. Scoring is
sgreg_core.bench.replay_score and merge_score."""
from __future__ import annotations

import contextlib
import json
import signal
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import psutil
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from sgreg_msgs.msg import RegistrationResult
from tf2_msgs.msg import TFMessage

from sgreg_core.bench.bandwidth import BandwidthMeter
from sgreg_core.bench.replay_score import ResultRecord, check_ground_truth
from sgreg_core.runtime.auth import AuthConfig, init_keystore
from sgreg_ros.convert import transform_from_msg
from sgreg_ros.qos import DIAGNOSTICS, RESULTS, TF
from sgreg_ros.signing import MessageAuth

from . import processes
from .bags import BagError, message_class, open_bag, play_bag, qos_for

# what one agent sends the others (metered: kB per query frame); the results are heard by
# every peer's registration node (witnesses, merging)
CROSS_AGENT = {"/sgreg/coarse": "sgreg_msgs/msg/CoarseGraph", "/sgreg/dense": "sgreg_msgs/msg/DenseGraph",
               "/sgreg/dense_request": "sgreg_msgs/msg/DenseRequest",
               "/sgreg/registration": "sgreg_msgs/msg/RegistrationResult"}


@dataclass
class ReplayConfig:
    """rate: playback speed. tail_s: time to keep listening after the bag ends (a dense
    exchange may still be in flight; the agents' traffic in the last tail_s - settle_s of it is
    what a static map costs the link, unmeasured when tail_s <= settle_s). ready_timeout_s: how
    long nodes may take to start.
    overrides: ROS parameters given to every node (e.g. weights_path).
    restart: (agent, seconds): kill that agent's nodes (SIGKILL) that long after the bag starts
        and start them again at once: a robot whose software crashes mid-mission.
    The agents sign and check their messages with a fleet keystore made for the replay (unless
    overrides name a keystore), as a deployed fleet would."""

    rate: float = 1.0
    tail_s: float = 42.0    # a 20 s window after settle_s: two heartbeat periods
    settle_s: float = 22.0   # past AgentConfig.quiet_after_s: coarse graphs are heartbeats by then
    ready_timeout_s: float = 90.0
    params_file: str | None = None
    overrides: dict = field(default_factory=dict)
    log_dir: Path | None = None
    restart: tuple[str, float] | None = None


@dataclass
class ReplayRun:
    records: list
    bandwidth: list
    bytes_per_topic: dict
    processes: dict
    played: int
    corrupted: list
    duration_s: float
    timeline: list   # (t, topic, bytes) of cross-agent traffic
    events: list     # (t, what) e.g. a restart
    bag_end_s: float = 0.0   # when the last message was played (t of the timeline)
    tf: dict = field(default_factory=dict)   # child frame -> (parent frame, 4x4), last on /tf
    # agent -> its two nodes' last counter tables in one: the registration node's (on each
    # result) and the agent node's (on /diagnostics: the dense requests it refused to answer)
    counters: dict = field(default_factory=dict)
    # signs of another fleet on the same ROS_DOMAIN_ID (FleetCheck): results on the agents'
    # topics not from the replay's nodes, left out (unsigned, unknown_key, ...), and other
    # publishers of the agents' maps
    foreign: dict = field(default_factory=dict)

    def merged_poses(self, merged_frame: str) -> dict:
        """agent -> its map's last pose in the merged frame, as /tf carried it."""
        return {child.split("/")[0]: T for child, (parent, T) in self.tf.items() if parent == merged_frame}


class FleetCheck:
    """Whether another fleet shares the replay's ROS_DOMAIN_ID (a test run, a second replay:
    agents of the same names), counted in `foreign` by what gave it away.
    take(msg, agent): whether a result on /<agent>/sgreg/registration comes from the nodes the
        replay started: with a keystore, one signed by the agent's key; without, one that
        names the agent. Others are left out of the score.
    look(node, names): another publisher of an agent's mapping/instances than the replay's
        player: its maps reach the replay's nodes (unsigned: they are the robot's own input)."""

    def __init__(self, keystore: str):
        self.auth = MessageAuth(AuthConfig(keystore=keystore), None, None) if keystore else None
        self.foreign: Counter = Counter()

    def take(self, msg, agent: str) -> bool:
        why = "agent_mismatch" if msg.agent_id != agent else (
            self.auth.check(msg, f"/{agent}/sgreg/registration", agent) if self.auth else None)
        if why:
            self.foreign[why] += 1
        return why is None

    def look(self, node, names: list[str]) -> None:
        extra = max(node.count_publishers(f"/{n}/mapping/instances") - 1 for n in names)
        if extra > 0:
            self.foreign["other_map_publishers"] = max(self.foreign["other_map_publishers"], extra)


INSTANCE_MAP_TYPE = "sgreg_msgs/msg/InstanceMap"


def instance_map_counts(bag: str | Path) -> dict[str, int]:
    """{agent: instance maps the bag holds on /<agent>/mapping/instances}; BagError when fewer
    than two agents have some, or such a topic carries another message type (a bag of another
    tool would otherwise replay nothing and report an empty success)."""
    reader = open_bag(bag)
    try:
        conns = [c for c in reader.connections if c.topic.endswith("/mapping/instances")]
    finally:
        reader.close()
    wrong = sorted({f"{c.topic} ({c.msgtype})" for c in conns if c.msgtype != INSTANCE_MAP_TYPE})
    if wrong:
        raise BagError(f"{bag}: {', '.join(wrong)} must carry {INSTANCE_MAP_TYPE}")
    counts: dict[str, int] = {}
    for c in conns:
        agent = c.topic.split("/")[1]
        counts[agent] = counts.get(agent, 0) + c.msgcount
    if len(counts) < 2:
        raise BagError(f"{bag} holds instance maps of {len(counts)} agent(s); a replay needs two or more")
    return counts


def check_bag_against_ground_truth(bag: str | Path, gt: dict, counts: dict[str, int]) -> None:
    """BagError, before any node starts, when the ground truth cannot be this bag's (counts:
    instance_map_counts of the bag): it lacks an agent of the bag, or states another number of
    map snapshots for one (a ground_truth.json copied from another bag would score right
    estimates as wrong verified transforms)."""
    missing = sorted(set(counts) - set(gt["T_scene_map"]))
    if missing:
        raise BagError(f"{bag}/ground_truth.json has no pose of agent(s) {', '.join(missing)} of the bag "
                       f"(it names {', '.join(sorted(gt['T_scene_map']))}): is it another bag's?")
    for agent, snapshots in (gt.get("objects") or {}).items():
        if agent in counts and len(snapshots) != counts[agent]:
            raise BagError(f"{bag}/ground_truth.json describes {len(snapshots)} map snapshots of agent "
                           f"{agent}, the bag holds {counts[agent]}: is it another bag's?")


class _Sampler:
    """CPU time and peak memory of the node processes, sampled every 0.5 s."""

    def __init__(self, procs):
        self.procs, self.peak_rss, self.cpu, self.started = {}, {}, {}, {}
        self.track(procs)

    def track(self, procs, suffix: str = ""):
        for p in procs:
            name = f"{p.agent}/{p.executable}{suffix}"
            self.procs[name] = psutil.Process(p.proc.pid)
            self.peak_rss[name], self.cpu[name], self.started[name] = 0, 0.0, time.monotonic()

    def sample(self):
        for name, proc in self.procs.items():
            try:
                self.peak_rss[name] = max(self.peak_rss[name], proc.memory_info().rss)
                t = proc.cpu_times()
                self.cpu[name] = t.user + t.system
            except psutil.Error:
                pass

    def report(self) -> dict:
        """CPU share = CPU seconds over the process's wall time (1.0 = one core busy)."""
        now = time.monotonic()
        return {name: {"cpu_s": round(self.cpu[name], 2),
                       "cpu_share": round(self.cpu[name] / max(now - self.started[name], 1e-3), 3),
                       "peak_rss_mb": round(self.peak_rss[name] / 2**20, 1)} for name in self.procs}


def _check_before_start(cfg: ReplayConfig, names: list[str]) -> None:
    """ValueError, in one line, for what would otherwise fail only once every node is up."""
    if not 0 < cfg.rate < float("inf"):     # NaN too
        raise ValueError(f"--rate must be a positive number, got {cfg.rate}")
    if not 0 <= cfg.tail_s < float("inf"):
        raise ValueError(f"--tail must be >= 0 s, got {cfg.tail_s}")
    if cfg.restart is not None:
        agent, at = cfg.restart
        if agent not in names:
            raise ValueError(f"--restart: the bag has no agent {agent!r} (its agents: {', '.join(names)})")
        if not 0 <= at < float("inf"):
            raise ValueError(f"--restart: the time must be >= 0 s, got {at}")
    for line in processes.check_params_file(cfg.params_file):
        print(f"warning: --params-file {cfg.params_file}: {line}", file=sys.stderr)


def run_replay(bag: str | Path, cfg: ReplayConfig, log=print) -> ReplayRun:
    """ValueError before any node starts when cfg does not suit the bag (rate, restart,
    params file)."""
    counts = instance_map_counts(bag)
    names = sorted(counts)
    _check_before_start(cfg, names)
    # a bag's ground truth (none: a recorded bag) is checked before any node starts
    gt = ground_truth_of(bag, required=False)
    if gt is not None:
        check_bag_against_ground_truth(bag, gt, counts)
    origin = (gt or {}).get("t_origin", 0.0)
    overrides = dict(cfg.overrides)
    keys = None
    if "keystore" not in overrides:
        keys = tempfile.TemporaryDirectory(prefix="sgreg-keys-")
        init_keystore(keys.name, names)
        overrides["keystore"] = keys.name
    try:
        return _run_replay(bag, cfg, names, overrides, origin, log)
    finally:
        if keys is not None:
            keys.cleanup()


def _run_replay(bag, cfg: ReplayConfig, names: list[str], overrides: dict, origin: float,
                log) -> ReplayRun:
    fleet = FleetCheck(overrides.get("keystore", ""))    # a bad keystore fails before any node starts
    procs = processes.start_agents(names, cfg.params_file or processes.DEFAULT_PARAMS, overrides, cfg.log_dir)
    sampler = _Sampler(procs)
    rclpy.init()
    node = rclpy.create_node("sgreg_replay")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    records: list[ResultRecord] = []
    meter = BandwidthMeter()
    timeline = []
    t0 = time.monotonic()

    counters: dict = {}          # agent -> the registration node's last table
    agent_counters: dict = {}    # agent -> the agent node's last table

    def on_result(msg: RegistrationResult, agent: str):
        if not fleet.take(msg, agent):
            return
        timing = dict(zip(msg.timing_names, msg.timing_ms))
        counters[msg.agent_id] = dict(zip(msg.counter_names, (int(v) for v in msg.counter_values)))
        records.append(ResultRecord(t=time.monotonic() - t0, agent=msg.agent_id, peer=msg.peer_id,
                                    T=transform_from_msg(msg.transform), verified=msg.verified,
                                    mode=msg.mode, reason=msg.reason, node_matches=msg.node_matches,
                                    inliers=msg.inliers, total_ms=float(timing.get("total", 0.0)),
                                    confidence=float(msg.confidence),
                                    evidence={"objects": int(msg.inlier_objects),
                                              "fitness": float(msg.fitness),
                                              "ambiguity": float(msg.ambiguity)},
                                    link=msg.link,
                                    stamp_ns=msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec))

    def on_diagnostics(msg: DiagnosticArray):
        for status in msg.status:
            if status.name == f"/{status.hardware_id}/agent":
                agent_counters[status.hardware_id] = {kv.key: int(kv.value) for kv in status.values
                                                      if kv.value.lstrip("-").isdigit()}

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, DIAGNOSTICS)
    tf: dict = {}

    def on_tf(msg: TFMessage):
        for t in msg.transforms:
            tf[t.child_frame_id] = (t.header.frame_id, transform_from_msg(t))

    node.create_subscription(TFMessage, "/tf", on_tf, TF)

    def on_bytes(topic, raw):
        t = time.monotonic() - t0
        meter.add(topic, t, len(raw))
        timeline.append((t, topic, len(raw)))

    for name in names:
        node.create_subscription(RegistrationResult, f"/{name}/sgreg/registration",
                                 lambda msg, agent=name: on_result(msg, agent), RESULTS)
        for suffix, kind in CROSS_AGENT.items():
            topic = f"/{name}{suffix}"
            node.create_subscription(message_class(kind), topic, lambda raw, t=topic: on_bytes(t, raw),
                                     qos_for(topic), raw=True)

    player = rclpy.create_node("sgreg_replay_player")
    play_result = {}
    events: list = []
    died = None
    try:
        # ready: both nodes of every agent subscribe to its mapping/instances
        deadline = time.monotonic() + cfg.ready_timeout_s
        while time.monotonic() < deadline:
            dead = [p for p in procs if p.proc.poll() is not None]
            if dead:
                raise RuntimeError(f"node {dead[0].agent}/{dead[0].executable} exited with "
                                   f"{dead[0].proc.returncode} during start-up{_last_words(dead[0])}"
                                   + (f" (log: {dead[0].log_path})" if dead[0].log_path else ""))
            if all(node.count_subscribers(f"/{n}/mapping/instances") >= 2 for n in names):
                break
            executor.spin_once(timeout_sec=0.1)
        else:
            raise RuntimeError(f"nodes not ready after {cfg.ready_timeout_s} s")
        log(f"nodes of agents {', '.join(names)} are up; playing {bag}")
        t0 = time.monotonic()

        def play():
            # only the nodes' inputs: the ground-truth topic has no subscriber to wait for
            try:
                play_result["report"] = play_bag(player, bag, rate=cfg.rate, delay=0.5, wait_subscribers=10.0,
                                                 topics=[f"/{n}/mapping/instances" for n in names], log=log)
            except BagError as exc:   # a damaged chunk: the run stops short and is not scored
                play_result["error"] = exc

        thread = threading.Thread(target=play, daemon=True)
        thread.start()
        last_sample = 0.0
        end_at = None
        bag_end = 0.0
        restart = cfg.restart
        while end_at is None or time.monotonic() < end_at:
            executor.spin_once(timeout_sec=0.05)
            if restart and time.monotonic() - t0 >= restart[1]:
                victims = [p for p in procs if p.agent == restart[0]]
                processes.kill(victims)
                for p in victims:
                    procs.remove(p)
                fresh = processes.start_agents([restart[0]], cfg.params_file or processes.DEFAULT_PARAMS, overrides, cfg.log_dir,
                                            log_suffix="_restarted")
                procs += fresh
                sampler.track(fresh, " (restarted)")
                events.append((time.monotonic() - t0, f"killed and restarted the nodes of {restart[0]}"))
                log(events[-1][1])
                restart = None
            if time.monotonic() - last_sample > 0.5:
                sampler.sample()
                fleet.look(node, names)
                last_sample = time.monotonic()
                dead = [p for p in procs if p.proc.poll() is not None]
                if dead:      # its agent stopped answering: what follows would score a crash
                    died = (f"node {dead[0].agent}/{dead[0].executable} exited with {dead[0].proc.returncode} "
                            f"{time.monotonic() - t0:.1f} s into the replay"
                            + (f" (log: {dead[0].log_path})" if dead[0].log_path else ""))
                    break
            if end_at is None and not thread.is_alive():
                if "error" in play_result:   # nothing past the damage will come: stop now
                    break
                end_at = time.monotonic() + cfg.tail_s
                bag_end = end_at - cfg.tail_s - t0
                log(f"bag played ({bag_end:.0f} s); listening {cfg.tail_s:g} s more: the last "
                    "dense exchanges, then the link once the maps stop changing (--tail)")
        duration = time.monotonic() - t0
        if restart is not None and died is None:
            # asked for but never done: say so, rather than a report that reads as a restart survived
            events.append((duration, f"restart of {restart[0]} at {restart[1]:g} s not done: the "
                                     f"replay ended at {duration:.0f} s"))
            log(f"warning: {events[-1][1]}")
    finally:
        # a second Ctrl-C waits for the cleanup: an interrupted one left the nodes running
        # (they have sessions of their own)
        with _sigint_ignored():
            sampler.sample()
            processes.stop(procs)
            player.destroy_node()
            node.destroy_node()
            rclpy.try_shutdown()
    if died is not None:
        raise RuntimeError(died)
    if "error" in play_result:
        raise play_result["error"]
    report = play_result.get("report")
    if report is not None and report.clock is not None:
        # bag seconds (after the bag's t_origin, as its ground truth counts them) of each frame
        wall0, bag0 = report.clock
        for r in records:
            r.bag_t = bag0 - origin + (t0 + r.t - wall0) * cfg.rate
    return ReplayRun(records=records, bandwidth=meter.report(span=duration),
                     bytes_per_topic=dict(meter.totals), processes=sampler.report(),
                     played=report.published if report else 0,
                     corrupted=report.corrupted if report else [], duration_s=duration,
                     timeline=timeline, events=events, bag_end_s=bag_end, tf=tf,
                     # both nodes count a refused map: the registration node's count stands
                     counters={a: {**agent_counters.get(a, {}), **counters.get(a, {})} for a in names},
                     foreign=dict(fleet.foreign))


def _last_words(p) -> str:
    """': ' and the last line a node wrote to its log (a refusal says why there), or ''."""
    try:
        lines = [line.strip() for line in p.log_path.read_text(errors="replace").splitlines() if line.strip()]
    except (AttributeError, OSError):
        return ""
    return f": {lines[-1][:300]}" if lines else ""


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored for the block (from the main thread; elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        # None: a handler installed outside Python (rclpy's, gone with its shutdown)
        signal.signal(signal.SIGINT, signal.default_int_handler if before is None else before)


def ground_truth_of(bag: str | Path, required: bool = True) -> dict | None:
    """The bag's ground_truth.json, checked (replay_score.check_ground_truth) before anything
    is replayed or scored against it; BagError with a one-line reason. None when the bag has
    none and it is not `required` (a recorded bag)."""
    path = Path(bag) / "ground_truth.json"
    if not path.exists():
        if not required:
            return None
        raise BagError(f"{bag} has no ground_truth.json (made by sgreg make-bag)")
    try:
        return check_ground_truth(json.loads(path.read_text()))
    except RecursionError:
        raise BagError(f"{path}: malformed JSON (nested too deep)") from None
    except (OSError, ValueError) as exc:     # JSON and text decoding errors are ValueErrors
        raise BagError(f"{path}: {' '.join(str(exc).split())}") from None
