"""sgreg make-bag: a readable rosbag2 (MCAP) of two agents' growing maps, with a ground truth
that really maps one agent's frame into the other's."""
import json
import subprocess
import sys

import numpy as np
from mcap_ros2.reader import read_ros2_messages
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from scipy.spatial import cKDTree

from sgreg_core.geometry import transform_points
from sgreg_msgs.msg import InstanceMap
from sgreg_ros.convert import instance_map_from_msg

from .test_bag_tools import chunk_crcs

SGREG = [sys.executable, "-m", "sgreg_cli.main"]


def test_make_bag_from_a_synthetic_scene(tmp_path):
    scene, bag = tmp_path / "scene", tmp_path / "bag"
    subprocess.run(SGREG + ["synth", str(scene), "--seed", "4"], check=True, capture_output=True, timeout=120)
    out = subprocess.run(SGREG + ["make-bag", str(scene), "--out", str(bag), "--seed", "2"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "writing" in out.stderr          # progress is shown
    gt = json.loads((bag / "ground_truth.json").read_text())
    T_ab = np.asarray(gt["T_a_b"])
    assert np.allclose(T_ab[:3, :3] @ T_ab[:3, :3].T, np.eye(3), atol=1e-9)
    assert all(chunk_crcs(bag)), "damaged chunks would decode into maps of NaN points"

    maps = {"a": [], "b": []}
    with Reader(bag) as r:
        topics = {c.topic for c in r.connections}
        assert topics == {"/a/mapping/instances", "/b/mapping/instances", "/sgreg/ground_truth"}
        for conn, _, raw in r.messages():
            if conn.topic.endswith("instances"):
                msg = deserialize_message(bytes(raw), InstanceMap)
                maps[msg.agent_id].append(msg)
    for name, msgs in maps.items():
        assert len(msgs) >= 5
        assert [m.sequence for m in msgs] == list(range(len(msgs)))
        sizes = [m.points.width for m in msgs]
        assert sizes == sorted(sizes) and sizes[-1] > sizes[0]    # maps grow
    # the final maps overlap once a's is moved by the ground truth
    pa = instance_map_from_msg(maps["a"][-1]).points
    pb = instance_map_from_msg(maps["b"][-1]).points
    d, _ = cKDTree(pb).query(transform_points(T_ab, pa))
    d_wrong, _ = cKDTree(pb).query(pa)
    assert np.median(d) < 0.1 < np.median(d_wrong)
    # mcap-ros2 reads the same file from its own stored schemas
    n = sum(1 for _ in read_ros2_messages(str(next(bag.glob("*.mcap")))))
    assert n == sum(len(v) for v in maps.values()) + len(maps["a"])
    # the same command makes the same bytes (rclpy's CDR padding was left uninitialised)
    again = tmp_path / "again" / "bag"      # the bag's name is in its MCAP
    out = subprocess.run(SGREG + ["make-bag", str(scene), "--out", str(again), "--seed", "2"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    [first], [second] = bag.glob("*.mcap"), again.glob("*.mcap")
    assert first.read_bytes() == second.read_bytes()


def test_make_bag_refuses_bad_input(tmp_path):
    out = subprocess.run(SGREG + ["make-bag", str(tmp_path / "nope"), "--out", str(tmp_path / "bag")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "Traceback" not in out.stderr


def test_make_bag_with_three_agents_and_its_view(tmp_path):
    scene, bag, png = tmp_path / "scene", tmp_path / "bag", tmp_path / "view.png"
    subprocess.run(SGREG + ["synth", str(scene), "--seed", "3", "--rooms", "2"], check=True,
                   capture_output=True, timeout=120)
    out = subprocess.run(SGREG + ["make-bag", str(scene), "--out", str(bag), "--seed", "1", "--agents", "3",
                                  "--voxel", "0.1", "--random-start"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    gt = json.loads((bag / "ground_truth.json").read_text())
    assert set(gt["T_scene_map"]) == set(gt["objects"]) == set(gt["agents"]) == {"a", "b", "c"}
    with Reader(bag) as r:
        assert {c.topic for c in r.connections} >= {f"/{x}/mapping/instances" for x in "abc"}
        last = {}
        for conn, _, raw in r.messages():
            if conn.topic.endswith("instances"):
                msg = deserialize_message(bytes(raw), InstanceMap)
                last[msg.agent_id] = instance_map_from_msg(msg).points
    # where the maps overlap, each agent's lies on the others' once placed by the ground truth
    world = {x: transform_points(np.asarray(gt["T_scene_map"][x]), last[x]) for x in "abc"}
    for x in "bc":
        others = cKDTree(np.concatenate([world[y] for y in "abc" if y != x]))
        near = (others.query(world[x])[0] < 0.1).mean()
        near_unplaced = (others.query(last[x])[0] < 0.1).mean()
        assert near > 0.3 and near > 3 * near_unplaced
    view = subprocess.run(SGREG + ["view", str(bag), "--png", str(png)], capture_output=True, text=True,
                          timeout=120)
    assert view.returncode == 0, view.stderr
    assert "3 agents" in view.stdout and "ground truth" in view.stdout and png.stat().st_size > 20_000
    refused = subprocess.run(SGREG + ["make-bag", str(scene), "--out", str(tmp_path / "x"), "--agents", "1"],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "agents" in refused.stderr and "Traceback" not in refused.stderr
