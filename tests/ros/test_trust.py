"""A verified transform is something to act on: the traps that made sgreg publish wrong ones.

- A point-symmetric room (every object has a twin half a turn away about the room's middle):
  agent a maps all of it at once, agent b has seen only a few objects. b's objects fit both
  twins equally well, so nothing may be verified. The same bag with the verdict switched off
  does verify wrong transforms: the trap is real.
- A confirmed link that new, well-supported evidence contradicts is withdrawn over real DDS, and
  only the new pose is published after it.
"""
import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import rclpy

from sgreg_cli.commands.make_bag import BagSpec, make_bag
from sgreg_core.geometry import transform_points, yaw_transform
from sgreg_core.maps.instance_map import select_points, write_instance_map
from sgreg_core.metrics import two_agent_success
from sgreg_core.net.model import load_model
from sgreg_core.bench.offline_replay import OfflineReplayConfig, offline_replay
from sgreg_core.bench.replay_score import ground_truth, score_replay
from sgreg_core.runtime.merge import MergeConfig
from sgreg_core.runtime.peers import PeersConfig
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.types import InstanceMap
from sgreg_cli.bags import instance_maps_in_bag
from sgreg_ros.convert import transform_from_msg

from .harness import FAST, Watcher, agent_maps, alive, processes

SGREG = [sys.executable, "-m", "sgreg_cli.main"]


def symmetric_room(seed: int) -> InstanceMap:
    """One synthetic room cut in half at its middle, plus that half turned half a turn about
    the middle: a point-symmetric room in which every object has an identical twin."""
    scene = generate_scene(seed, SynthConfig(rooms=1))
    mid = 0.5 * (scene.points.min(0) + scene.points.max(0))
    half = select_points(scene, scene.points[:, 0] < mid[0])
    turn = yaw_transform(np.pi, mid - yaw_transform(np.pi)[:3, :3] @ mid)
    shift = max(half.labels) + 1
    twin = np.where(half.instance > 0, half.instance + shift, 0).astype(np.int32)
    return InstanceMap(points=np.concatenate([half.points, transform_points(turn, half.points)]).astype(np.float32),
                       instance=np.concatenate([half.instance, twin]),
                       labels={**half.labels, **{k + shift: v for k, v in half.labels.items()}},
                       scores={**half.scores, **{k + shift: v for k, v in half.scores.items()}})


@pytest.fixture(scope="module")
def symmetric_bag(tmp_path_factory):
    root = tmp_path_factory.mktemp("symmetric")
    write_instance_map(symmetric_room(2), root / "room")
    # a: a sensor that sees the whole room at once; b: a narrow, short one on its own walk
    spec = BagSpec(scan=str(root / "room"), seed=1, speed=0.3, opposite=False, voxel=0.05,
                   range=20.0, fov=360.0, range_b=2.5, fov_b=60.0, random_start=True)
    make_bag(spec, root / "bag")
    return root / "bag"


def offline(bag, cfg: OfflineReplayConfig):
    gt = json.loads((bag / "ground_truth.json").read_text())
    records = offline_replay(instance_maps_in_bag(bag, gt["t_origin"]), load_model(), cfg)
    return score_replay(records, gt["T_scene_map"], gt["objects"])


def without_verdict() -> OfflineReplayConfig:
    """Every estimate that fits a few correspondences published at once: the old behaviour (no
    evidence, ambiguity or confidence threshold, no confirmation, and no merger that would
    catch a and b disagreeing)."""
    loose = dict(min_inliers=3, min_objects=1, min_spread=0.0, min_fitness=0.0,
                 min_footprint_share=0.0, max_ambiguity=1e9, min_confidence=0.0)
    peers = PeersConfig(confirm=False)
    return OfflineReplayConfig(peers=replace(peers, pipeline=peers.pipeline.with_verdict(**loose)),
                               merge=MergeConfig(cycle_m=1e9, cycle_deg=1e9))


def test_few_objects_of_a_symmetric_room_verify_nothing_wrong(symmetric_bag):
    gt = json.loads((symmetric_bag / "ground_truth.json").read_text())
    assert len(gt["objects"]["b"][0][1]) <= 6            # b starts with a few objects
    trusting = offline(symmetric_bag, without_verdict())
    assert trusting.wrong_verified > 0, "the trap did not catch the old behaviour"
    score = offline(symmetric_bag, OfflineReplayConfig())
    assert score.query_frames > 10
    assert score.wrong_verified == 0
    assert any(f.reason == "ambiguous" for f in score.frames)


def test_real_nodes_verify_nothing_wrong_in_the_symmetric_room(symmetric_bag, tmp_path):
    out = tmp_path / "r.json"
    res = subprocess.run(SGREG + ["replay", str(symmetric_bag), "--json", str(out)],
                         capture_output=True, text=True, timeout=400)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["query_frames"] > 5 and report["wrong_verified"] == 0


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_a_contradicted_link_is_withdrawn_over_dds(ros, tmp_path):
    names = ["a", "b"]
    maps, frames = agent_maps(names, seed=11)
    procs = processes.start_agents(names, overrides=FAST, log_dir=tmp_path)
    w = Watcher(names)
    try:
        assert w.wait_ready(names), f"nodes did not start; dead: {alive(procs)}"

        def verified(agent, peer, frame):
            Ts = w.transforms.get((agent, peer), [])
            return bool(Ts) and two_agent_success(Ts[-1], ground_truth(frame, agent, peer))

        assert w.spin_until(lambda: verified("a", "b", frames), 90, publish_maps=maps), \
            [(r.agent_id, r.mode, r.reason) for r in w.results[-6:]]
        # b's front end re-anchors its map: b's frame jumps by W
        W = yaw_transform(np.radians(75.0), (3.0, -2.0, 0.0))
        moved = {"a": maps["a"], "b": maps["b"].transformed(W)}
        new_frames = {"a": frames["a"], "b": frames["b"] @ np.linalg.inv(W)}
        n_results = len(w.results)

        def withdrawn_and_back():
            mine = [r.reason if not r.verified else "verified" for r in w.results[n_results:]
                    if r.agent_id == "a" and r.peer_id == "b"]
            return "contradicted" in mine and "verified" in mine[mine.index("contradicted"):]

        assert w.spin_until(withdrawn_and_back, 90, publish_maps=moved), \
            [(r.agent_id, r.mode, r.reason) for r in w.results[n_results:][-10:]]
        mine = [r for r in w.results[n_results:] if r.agent_id == "a" and r.peer_id == "b"]
        cut = next(i for i, r in enumerate(mine) if r.reason == "contradicted")
        # withdrawn: by the moved nodes of its kept pairs (link none) or a new estimate (candidate)
        assert not mine[cut].verified and mine[cut].link in ("none", "candidate")
        # after the withdrawal, every transform a publishes for b is the new, right one
        after = [r for r in mine[cut:] if r.verified]
        gt = ground_truth(new_frames, "a", "b")
        assert after and all(two_agent_success(transform_from_msg(r.transform), gt) for r in after)
        assert not alive(procs)
    finally:
        processes.stop(procs)
        w.close()
