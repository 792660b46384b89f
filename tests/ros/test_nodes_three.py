"""Three agents' nodes register pairwise, and bad parameters are refused at start. A module of
its own: the two-agent nodes of test_nodes.py (same names, same domain) are gone by then."""
import subprocess

import pytest
import rclpy

from sgreg_core.metrics import two_agent_success
from sgreg_core.bench.replay_score import ground_truth

from .harness import FAST, Watcher, agent_maps, alive, processes, verified_pairs_ok


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_three_agents_register_pairwise(ros, tmp_path):
    names = ["a", "b", "c"]
    maps, frames = agent_maps(names, seed=12)
    procs = processes.start_agents(names, overrides=FAST, log_dir=tmp_path)
    w = Watcher(names)
    try:
        assert w.wait_ready(names), f"dead: {alive(procs)}"
        # each pair of agents registered (one direction gives the other by inversion)
        pairs = [("a", "b"), ("a", "c"), ("b", "c")]

        def registered(x, y):
            return verified_pairs_ok(w, frames, [(x, y)]) or verified_pairs_ok(w, frames, [(y, x)])

        assert w.spin_until(lambda: all(registered(x, y) for x, y in pairs), 200, publish_maps=maps), (
            {p: len(w.transforms.get(p, [])) for p in w.transforms})
        for (agent, peer), Ts in w.transforms.items():
            assert all(two_agent_success(T, ground_truth(frames, agent, peer)) for T in Ts), (agent, peer)
    finally:
        processes.stop(procs)
        w.close()


@pytest.mark.parametrize("exe,params,words", [
    ("agent", {"coarse_rate_hz": -1.0}, "coarse_rate_hz"),
    ("agent", {"feature_encoding": "bits"}, "feature_encoding"),
    ("registration", {"max_retries": "three"}, "max_retries"),
    ("agent", {"agent_name": "1a"}, "cannot start a topic name"),   # was rclpy's traceback
    ("registration", {"peers": ["b-c"]}, "are not agent ids"),
    ("registration", {"peers": ["a"]}, "own name"),                 # would hear nobody
    ("registration", {"merged_frame": "a/map"}, "merged_frame"),    # a frame its own parent on /tf
    # each in range, together no map could be registered
    ("agent", {"min_nodes": 500, "max_nodes": 100}, "min_nodes (500) must not exceed max_nodes (100)"),
    ("registration", {"min_nodes": 500, "max_nodes": 100}, "min_nodes (500) must not exceed max_nodes (100)"),
    # no dense request could go out: it names fewer nodes than an answer needs
    ("registration", {"min_nodes": 60}, "max_request_nodes (48) must not be below min_nodes (60)"),
])
def test_invalid_parameters_are_refused_at_start(exe, params, words):
    out = subprocess.run(processes.node_command(exe, "a", params_file=None, overrides=params), capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "refusing to start" in out.stderr and words in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("text,words", [
    (None, "cannot be read"),
    ("/**:\n  ros__parameters:\n    merged_frame: ''\n", "merged_frame"),   # tf2 refuses '' frames
    ("/**:\n  ros__parameters: [unclosed\n", "ROS could not start"),
])
def test_bad_parameter_files_are_refused_at_start(tmp_path, text, words):
    path = tmp_path / "params.yaml"
    if text is not None:
        path.write_text(text)
    out = subprocess.run(processes.node_command("registration", "a", params_file=path),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "refusing to start" in out.stderr and words in out.stderr
    assert "Traceback" not in out.stderr

