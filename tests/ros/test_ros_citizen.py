"""The nodes as a ROS 2 user meets them, over real DDS: names, run-time parameters, shutdown on
signals, /diagnostics levels, the topic prefix from agent_name, sim time from `sgreg play
--clock`, and a quiet link once the maps stop changing."""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sgreg_msgs.msg import CoarseGraph, DenseRequest, RegistrationResult

from sgreg_cli.bags import play_bag
from sgreg_core.types import InstanceMap
from sgreg_ros import qos
from sgreg_ros.convert import instance_map_to_msg, stamp_to_ns

from .harness import FAST, Watcher, agent_maps, alive, processes

BAGS = Path(__file__).resolve().parents[2] / "bags"
OK, WARN, ERROR = 0, 1, 2


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture
def agent_a(ros, tmp_path):
    """Both nodes of agent a (quick map timeout), a watcher, and a's map."""
    maps, _ = agent_maps(["a", "b"], seed=3)
    # quiet_after_s given as an integer, as "-p quiet_after_s:=3" gives it
    procs = processes.start_agents(["a"], overrides={**FAST, "map_timeout_s": 3.0, "quiet_after_s": 3}, log_dir=tmp_path)
    w = Watcher(["a"])
    yield procs, w, maps["a"]
    processes.stop(procs)
    w.close()


def _set(w, node, **values):
    client = AsyncParameterClient(w.node, node)
    assert client.wait_for_services(timeout_sec=30), f"no parameter services on {node}"
    future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    assert w.spin_until(future.done, 10)
    return future.result().results


def test_nodes_are_named_as_run_and_report_on_diagnostics(agent_a):
    procs, w, imap = agent_a
    assert w.wait_ready(["a"]), f"dead: {alive(procs)}"
    assert w.spin_until(lambda: {("agent", "/a"), ("registration", "/a")}
                        <= set(w.node.get_node_names_and_namespaces()), 20)
    # no map for map_timeout_s: ERROR, one status per node, hardware_id = the agent id
    assert w.spin_until(lambda: all(any(lv == ERROR for lv, _, _ in w.levels.get(n, []))
                                    for n in ("/a/agent", "/a/registration")), 30), w.levels
    assert {hw for n in ("/a/agent", "/a/registration") for _, hw, _ in w.levels[n]} == {"a"}
    assert "no instance map" in w.levels["/a/agent"][-1][2]
    # maps of one object, too small to register, once a second: the front end is heard from
    # and nothing was refused, so OK past map_timeout_s, and the agent says what it waits for
    nodes = ("/a/agent", "/a/registration")
    first = imap.instance == imap.instance[imap.instance > 0][0]
    small = InstanceMap(points=imap.points[first], instance=imap.instance[first], labels=imap.labels)
    w.map_pubs["a"].publish(instance_map_to_msg(small, "a", 1, 1))
    assert w.spin_until(lambda: all(w.levels.get(n, [(None,)])[-1][0] == OK for n in nodes), 15), w.levels
    w.levels.clear()
    for seq in range(2, 8):                          # 6 s, twice map_timeout_s
        w.map_pubs["a"].publish(instance_map_to_msg(small, "a", seq, seq))
        w.spin_until(lambda: False, 1.0)
    assert {lv for n in nodes for lv, _, _ in w.levels.get(n, [])} == {OK}, w.levels
    assert "too small so far" in w.levels["/a/agent"][-1][2]
    assert w.counter("/a/agent", "small_map") >= 6 and w.counter("/a/registration", "small_map") >= 6
    # a map: OK; then a map the nodes refuse: WARN for that period
    w.levels.clear()
    w.map_pubs["a"].publish(instance_map_to_msg(imap, "a", 10, 10))
    assert w.spin_until(lambda: w.levels.get("/a/agent", [(None,)])[-1][0] == OK, 15), w.levels
    broken = instance_map_to_msg(imap, "a", 11, 11)
    broken.labels = broken.labels[:1]            # labels no longer match the instance ids
    w.levels.clear()
    w.map_pubs["a"].publish(broken)
    assert w.spin_until(lambda: any(lv == WARN for lv, _, _ in w.levels.get("/a/agent", [])), 15), w.levels
    assert not alive(procs)


def _get(w, node, *names):
    client = AsyncParameterClient(w.node, node)
    assert client.wait_for_services(timeout_sec=30), f"no parameter services on {node}"
    future = client.get_parameters(list(names))
    assert w.spin_until(future.done, 10)
    return [(Parameter.Type(v.type), parameter_value_to_python(v)) for v in future.result().values]


def test_parameters_take_effect_or_are_refused(agent_a):
    procs, w, imap = agent_a
    assert w.wait_ready(["a"]), f"dead: {alive(procs)}"
    coarse = []
    w.node.create_subscription(CoarseGraph, "/a/sgreg/coarse", coarse.append, qos.COARSE_SUB)
    w.map_pubs["a"].publish(instance_map_to_msg(imap, "a", 1, 1))
    assert w.spin_until(lambda: coarse, 20)
    # a static map: at the rate for quiet_after_s (3 s here), then only as a heartbeat (10 s) ...
    w.spin_until(lambda: False, 4.0)
    coarse.clear()
    w.spin_until(lambda: False, 4.0)
    assert len(coarse) <= 1
    # ... until the heartbeat is set faster, at run time
    [ok] = _set(w, "/a/agent", heartbeat_period_s=1.0)
    assert ok.successful, ok.reason
    coarse.clear()
    w.spin_until(lambda: False, 5.0)
    assert len(coarse) >= 3
    [ok] = _set(w, "/a/agent", coarse_rate_hz=0.25)      # the timer itself slows down
    assert ok.successful
    [ok] = _set(w, "/a/agent", heartbeat_period_s=1)     # an integer for a float is taken
    assert ok.successful, ok.reason
    # ... and kept as the double it means, as one given at start (describe and dump say double)
    assert _get(w, "/a/agent", "heartbeat_period_s", "quiet_after_s") == [(Parameter.Type.DOUBLE, 1.0),
                                                                         (Parameter.Type.DOUBLE, 3.0)]
    # without a keystore the peer's word is off, and the parameter reads what is in effect
    assert _get(w, "/a/registration", "confirm_with_peer") == [(Parameter.Type.BOOL, False)]
    w.spin_until(lambda: False, 1.0)
    coarse.clear()
    w.spin_until(lambda: False, 8.0)
    assert 1 <= len(coarse) <= 3
    # invalid values and read-only parameters are refused with the reason
    [bad] = _set(w, "/a/agent", feature_encoding="bogus")
    assert not bad.successful and "feature_encoding" in bad.reason
    [ro] = _set(w, "/a/agent", voxel_size=0.1)
    assert not ro.successful and "read-only" in ro.reason.lower()
    [ok] = _set(w, "/a/registration", min_request_interval_s=3.0)
    assert ok.successful
    [ro] = _set(w, "/a/registration", confirm=False)
    assert not ro.successful
    [bad] = _set(w, "/a/agent", heartbeat_period_s="often")
    assert not bad.successful and "heartbeat_period_s" in bad.reason
    # a parameter of the agent node only: the registration node does not claim to take it
    [absent] = _set(w, "/a/registration", quiet_after_s=5.0)
    assert not absent.successful
    assert not alive(procs)


def test_a_refused_set_of_parameters_changes_nothing(ros, tmp_path):
    """A set given at once (set_parameters_atomically: a launch file, an rclpy client) with one
    value that does not fit the others is refused whole: the values that fit are not put in
    effect either, and `ros2 param get` says what is."""
    procs = processes.start_agents(["a"], executables=("agent",), overrides={"min_nodes": 12},
                                   log_dir=tmp_path)
    w = Watcher(["a"])
    try:
        client = AsyncParameterClient(w.node, "/a/agent")
        assert client.wait_for_services(timeout_sec=90), f"dead: {alive(procs)}"
        future = client.set_parameters_atomically([Parameter("map_timeout_s", value=1.0),
                                                   Parameter("max_nodes", value=11)])
        assert w.spin_until(future.done, 10)
        res = future.result().result
        assert not res.successful and "min_nodes (12) must not exceed max_nodes (11)" in res.reason
        assert _get(w, "/a/agent", "map_timeout_s", "max_nodes") == [(Parameter.Type.DOUBLE, 30.0),
                                                                     (Parameter.Type.INTEGER, 2000)]
        # no map yet: a 1 s map timeout in effect would say ERROR within a second or two
        w.levels.clear()
        w.spin_until(lambda: False, 4.0)
        assert w.levels.get("/a/agent") and all(lv != ERROR for lv, _, _ in w.levels["/a/agent"]), w.levels
        [ok] = _set(w, "/a/agent", map_timeout_s=1.0)          # alone it fits, and takes effect
        assert ok.successful, ok.reason
        assert w.spin_until(lambda: any(lv == ERROR for lv, _, _ in w.levels.get("/a/agent", [])), 10), w.levels
        assert not alive(procs)
    finally:
        processes.stop(procs)
        w.close()


def _node(args, **kw):
    return subprocess.Popen([sys.executable, "-m", "sgreg_ros", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True, **kw)


@pytest.mark.parametrize("exe", ["agent", "registration"])
def test_signals_end_a_node_cleanly_at_any_moment(ros, exe):
    """SIGINT during start-up, SIGTERM once up, and the double SIGINT a terminal plus
    ros2 launch deliver: exit code 0, no traceback, promptly."""
    w = Watcher([])
    try:
        for sig, when, twice in ((signal.SIGINT, 0.5, False), (signal.SIGTERM, None, False),
                                 (signal.SIGINT, None, True)):
            p = _node([exe, "--ros-args", "-r", "__ns:=/s"])
            if when is None:       # up: subscribed to its map
                assert w.spin_until(lambda: w.node.count_subscribers("/s/mapping/instances") >= 1, 90)
            else:
                time.sleep(when)
            t0 = time.monotonic()
            os.killpg(p.pid, sig)
            if twice:
                time.sleep(0.05)
                os.killpg(p.pid, sig)
            out, _ = p.communicate(timeout=30)
            took = time.monotonic() - t0
            assert p.returncode == 0, out[-2000:]
            assert "Traceback" not in out and "KeyboardInterrupt" not in out, out[-2000:]
            assert took < 3.0, f"{exe} took {took:.1f} s to exit after {sig.name}"
    finally:
        w.close()


def test_agent_name_without_namespace_prefixes_the_topics(ros, tmp_path):
    w = Watcher([])
    p = _node(["agent", "--ros-args", "-p", "agent_name:=x"])
    try:
        # discovery reports a node's entities one by one: wait until both have been seen
        assert w.spin_until(lambda: w.node.count_subscribers("/x/mapping/instances") >= 1
                            and w.node.count_publishers("/x/sgreg/coarse") >= 1, 90), p.poll()
        assert w.node.count_subscribers("/mapping/instances") == 0
    finally:
        os.killpg(p.pid, signal.SIGINT)
        p.communicate(timeout=30)
        w.close()
    clash = subprocess.run([sys.executable, "-m", "sgreg_ros", "agent", "--ros-args", "-r", "__ns:=/a",
                            "-p", "agent_name:=x"], capture_output=True, text=True, timeout=120)
    assert clash.returncode == 2 and "differs from the namespace" in clash.stderr


def test_sim_time_from_play_clock_stamps_outputs_in_bag_time(ros, tmp_path):
    """Nodes under use_sim_time, a bag played with /clock: coarse graphs and results carry the
    bag's time, and the nodes' timers run on it."""
    bag = BAGS / "apartment_opposite"
    procs = processes.start_agents(["a", "b"], overrides={"use_sim_time": True}, log_dir=tmp_path)
    w = Watcher([])
    coarse, results, diagnostics = [], [], []
    w.node.create_subscription(CoarseGraph, "/a/sgreg/coarse", coarse.append, qos.COARSE_SUB)
    w.node.create_subscription(RegistrationResult, "/b/sgreg/registration", results.append, qos.RESULTS)
    # stamped by each node's own clock (coarse graphs and results carry their maps' stamps, the
    # bag's whatever clock the node runs on)
    w.node.create_subscription(DiagnosticArray, "/diagnostics",
                               lambda m: diagnostics.append(stamp_to_ns(m.header.stamp) / 1e9), qos.DIAGNOSTICS)
    player = rclpy.create_node("test_player")
    try:
        assert w.spin_until(lambda: all(w.node.count_subscribers(f"/{n}/mapping/instances") >= 2
                                        for n in "ab"), 120), f"dead: {alive(procs)}"
        thread = threading.Thread(target=play_bag, args=(player, bag), daemon=True,
                                  kwargs={"rate": 2.0, "delay": 0.5, "clock_hz": 40.0, "log": lambda s: None})
        thread.start()
        w.spin_until(lambda: not thread.is_alive() and results, 120)
        w.spin_until(lambda: False, 2.0)
    finally:
        processes.stop(procs)
        player.destroy_node()
        w.close()
    start, end = 1_700_000_000.0, 1_700_000_030.0     # the shipped bags' time span
    assert coarse and results
    assert all(start <= m.header.stamp.sec <= end for m in coarse), [m.header.stamp.sec for m in coarse[:5]]
    assert all(start <= r.header.stamp.sec <= end for r in results)
    assert len(coarse) >= 5   # the coarse timer ran on the bag's clock
    in_bag_time = [t for t in diagnostics if start <= t <= end + 1.0]
    assert len(in_bag_time) >= 4, diagnostics[-8:]
    assert not [t for t in diagnostics if t > end + 1.0], diagnostics[-8:]    # not the wall clock


class _TestClock:
    """/clock from the test, from 1.7e9 s on: running with the wall clock, or paused."""

    def __init__(self, node):
        self.pub = node.create_publisher(Clock, "/clock", 10)
        self.t, self.last, self.running = 1_700_000_000.0, None, True

    def __call__(self):
        now = time.monotonic()
        if self.running and self.last is not None:
            self.t += now - self.last
        self.last = now
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(self.t * 1e9), 1_000_000_000)
        self.pub.publish(msg)


def test_a_paused_clock_pauses_the_link_timers(ros, tmp_path):
    """Nodes under use_sim_time, a bag paused longer than peer_timeout_s: the registration's
    intervals run on the bag's clock, so when it goes on no peer has been forgotten as silent."""
    maps, _ = agent_maps(["a", "b"], seed=5)
    procs = processes.start_agents(["a", "b"], overrides={**FAST, "use_sim_time": True, "peer_timeout_s": 10.0},
                                   log_dir=tmp_path)
    w = Watcher(["a", "b"])
    clock = _TestClock(w.node)
    try:
        assert w.wait_ready(["a", "b"]), f"dead: {alive(procs)}"
        assert w.spin_until(lambda: ("a", "b") in w.transforms and ("b", "a") in w.transforms, 120,
                            publish_maps=maps, each=clock), f"not registered; dead: {alive(procs)}"
        clock.running = False
        w.spin_until(lambda: False, 13.0, each=clock)       # paused, the maps too
        clock.running = True
        w.diagnostics.clear()
        assert w.spin_until(lambda: all(f"/{n}/registration" in w.diagnostics for n in "ab"), 20, each=clock)
        w.spin_until(lambda: False, 3.0, each=clock)
        assert [w.counter(f"/{n}/registration", "peer_expired") for n in "ab"] == [0, 0]
        assert not alive(procs)
    finally:
        processes.stop(procs)
        w.close()


def test_link_goes_quiet_when_maps_stop_changing(ros, tmp_path):
    """Two agents with static maps: once registered, no dense request goes out and coarse graphs
    only as heartbeats."""
    maps, _ = agent_maps(["a", "b"], seed=5)
    procs = processes.start_agents(["a", "b"], overrides={**FAST, "quiet_after_s": 3.0}, log_dir=tmp_path)
    w = Watcher(["a", "b"])
    seen: list = []
    for n in "ab":
        w.node.create_subscription(CoarseGraph, f"/{n}/sgreg/coarse", lambda m: seen.append(("coarse", m.agent_id)), qos.COARSE_SUB)
        w.node.create_subscription(DenseRequest, f"/{n}/sgreg/dense_request", lambda m: seen.append(("request", m.from_agent)), qos.DENSE_REQUEST)
    try:
        assert w.wait_ready(["a", "b"]), f"dead: {alive(procs)}"
        assert w.spin_until(lambda: ("a", "b") in w.transforms and ("b", "a") in w.transforms, 120,
                            publish_maps=maps), f"not registered; dead: {alive(procs)}"
        w.spin_until(lambda: False, 6.0, publish_maps=maps)   # the same maps, over and over
        seen.clear()
        w.spin_until(lambda: False, 8.0, publish_maps=maps)
        assert sum(k == "request" for k, _ in seen) == 0, seen
        assert sum(k == "coarse" for k, _ in seen) <= 2, seen    # heartbeat: every 10 s per agent
        assert not alive(procs)
    finally:
        processes.stop(procs)
        w.close()


def test_without_a_model_the_node_stays_up_and_reports_error(ros, tmp_path):
    w = Watcher([])
    p = _node(["registration", "--ros-args", "-r", "__ns:=/m", "-p", f"weights_path:={tmp_path / 'none.safetensors'}"])
    try:
        assert w.spin_until(lambda: w.levels.get("/m/registration"), 90), p.poll()
        level, hardware_id, message = w.levels["/m/registration"][-1]
        assert level == ERROR and hardware_id == "m" and message.startswith("no model")
        assert p.poll() is None
    finally:
        os.killpg(p.pid, signal.SIGINT)
        out, _ = p.communicate(timeout=30)
        w.close()
    assert p.returncode == 0 and "Traceback" not in out


def test_a_parameter_the_nodes_do_not_have_is_named_in_a_warning(ros, tmp_path):
    """ROS ignores an undeclared parameter without a word, so a typo in a params file would
    silently leave the default: the node names it (and the closest real one) and runs on."""
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    agree_mm: 0.4\n    coarse_rate_hz: 2.0\n"
                      "    use_sim_time: false\n")
    w = Watcher([])
    p = _node(["registration", "--ros-args", "-r", "__ns:=/u", "--params-file", str(params)])
    try:
        assert w.spin_until(lambda: w.node.count_subscribers("/u/mapping/instances") >= 1, 90), p.poll()
    finally:
        os.killpg(p.pid, signal.SIGINT)
        out, _ = p.communicate(timeout=30)
        w.close()
    assert p.returncode == 0, out[-2000:]
    warned = [line for line in out.splitlines() if "is not a parameter" in line]
    # coarse_rate_hz is the agent node's (one file serves both), use_sim_time rclpy's own
    assert len(warned) == 1 and "'agree_mm'" in warned[0] and "did you mean 'agree_m'" in warned[0], out[-2000:]


@pytest.mark.parametrize("exe", ["agent", "registration"])
def test_help_says_how_to_run_the_node_without_starting_it(exe):
    res = subprocess.run([sys.executable, "-m", "sgreg_ros", exe, "--help"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and not res.stderr, res.stderr
    assert res.stdout.startswith(f"usage: ros2 run sgreg_ros {exe} --ros-args -r __ns:=/<agent>")
    assert f"ros2 param describe /<agent>/{exe} NAME" in res.stdout
