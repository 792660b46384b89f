"""Decoding that cannot throw: thousands of mutated messages of every sgreg type go through the
decoders and the cores (no exception but a counted ConversionError), then a few hundred through
real nodes over DDS, which must stay up and count what they refused."""
import numpy as np
import pytest
import rclpy
from rclpy.serialization import deserialize_message, serialize_message
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult

from sgreg_core.net.model import load_model
from sgreg_core.net.testing import moved_graph, toy_graph
from sgreg_core.geometry import yaw_transform
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.merge import Merger, MergeConfig
from sgreg_core.runtime.messages import DenseRequestMessage
from sgreg_core.runtime.peers import Peers, PeersConfig
from sgreg_ros import convert, qos
from sgreg_ros.pointcloud import PointField

from .harness import Watcher, agent_maps, alive, processes

MUTANTS = 1500


@pytest.fixture(scope="module")
def cores():
    model = load_model()
    rng = np.random.default_rng(0)
    ga = toy_graph(rng, n=16)
    a, b = AgentCore(AgentConfig(name="a"), model), AgentCore(AgentConfig(name="b"), model)
    a.set_graph(ga, 1, 0)
    b.set_graph(moved_graph(ga, yaw_transform(1.0, (1.0, 2.0, 0.0)), rng), 1, 0)
    return model, a, b


def valid_messages(a, b):
    """One valid serialized message of each type, as the nodes send them."""
    maps, _ = agent_maps(["a"], seed=1)
    dense = convert.dense_to_msg(b.dense_message(1, None, "a", 1), 1)
    peers = Peers(PeersConfig(), b, b.model, log=lambda s: None)
    _, req = peers.on_coarse(a.coarse_message(1), now=0.0)
    estimate = peers.on_dense(a.dense_message(1, req.node_ids, "b", req.sequence), now=0.5)
    request = convert.request_to_msg(DenseRequestMessage("a", "b", 1, 1, a.weights_id, np.arange(4)), 0.0)
    return {InstanceMap: serialize_message(convert.instance_map_to_msg(maps["a"], "a", 1, 0.0)),
            CoarseGraph: serialize_message(convert.coarse_to_msg(b.coarse_message(1), 1)),
            DenseGraph: serialize_message(dense),
            DenseRequest: serialize_message(request),
            RegistrationResult: serialize_message(convert.result_to_msg(estimate, "b", 1, 0.0, {"x": 1}))}


def mutate(raw: bytes, rng) -> bytes:
    data = bytearray(raw)
    kind = rng.integers(4)
    if kind == 0:                        # flip a few bytes
        for i in rng.integers(4, len(data), rng.integers(1, 9)):
            data[i] = rng.integers(256)
    elif kind == 1:                      # cut
        data = data[: rng.integers(0, len(data))]
    elif kind == 2:                      # grow
        data += bytes(rng.integers(0, 256, rng.integers(1, 64), dtype=np.uint8))
    else:                                # overwrite a 4-byte word (lengths, counts, offsets)
        i = 4 * rng.integers(1, len(data) // 4)
        data[i:i + 4] = int(rng.choice([0, 1, 2**31 - 1, 2**32 - 1, rng.integers(2**32)])).to_bytes(4, "little")
    return bytes(data)


FROM_MSG = {InstanceMap: convert.instance_map_from_msg, CoarseGraph: convert.coarse_from_msg,
            DenseGraph: convert.dense_from_msg, DenseRequest: convert.request_from_msg,
            RegistrationResult: convert.result_from_msg}


def test_decoders_and_cores_never_throw_on_mutated_messages(cores):
    model, a, b = cores
    rng = np.random.default_rng(7)
    peers = Peers(PeersConfig(), a, model, log=lambda s: None)
    peers.on_coarse(b.coarse_message(1), now=0.0)
    peers.links["b"].asked = [1]         # so that mutated answers reach the checks behind it
    merger = Merger(MergeConfig(), "a")
    reached = dict.fromkeys(FROM_MSG, 0)
    refused = 0
    for cls, raw in valid_messages(a, b).items():
        core_runs = 0
        for _ in range(MUTANTS):
            try:
                value = FROM_MSG[cls](convert.decode(mutate(raw, rng), cls))
            except convert.ConversionError:
                refused += 1
                continue
            reached[cls] += 1
            if core_runs >= 60:          # the cores cost a registration each: a sample is enough
                continue
            core_runs += 1
            if cls is CoarseGraph:
                peers.on_coarse(value, now=float(core_runs))
            elif cls is DenseGraph:
                peers.on_dense(value, now=float(core_runs))
            elif cls is DenseRequest:
                b.answer_request(value, now=float(core_runs))
            elif cls is RegistrationResult:
                merger.take(value.agent, value.peer, value.T, value.verified, value.reason, value.link,
                            value.confidence, value.stamp_ns)
                merger.update()
            else:
                a.take_map(value, 100 + core_runs, 0)
    assert refused > MUTANTS // 4            # the mutations do break messages ...
    assert all(n > 0 for n in reached.values()), reached   # ... and some still decode
    assert sum(a.counters.values()) > 0


def test_point_field_offsets_past_the_point_are_refused(cores):
    _, a, b = cores
    msg = convert.dense_to_msg(b.dense_message(1, None, "a", 1), 1)
    msg.points.fields = [PointField(name=f.name, offset=f.offset + (40 if f.name == "y" else 0),
                                    datatype=f.datatype, count=1) for f in msg.points.fields]
    with pytest.raises(convert.ConversionError, match="offsets"):
        convert.dense_from_msg(msg)


def test_nodes_survive_a_stream_of_mutated_messages(cores, tmp_path):
    model, a, b = cores
    rclpy.init()
    procs = processes.start_agents(["a"], log_dir=tmp_path)
    w = Watcher(["a"])
    rng = np.random.default_rng(11)
    try:
        assert w.wait_ready(["a"]), f"dead: {alive(procs)}"
        pubs = {CoarseGraph: w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE),
                DenseGraph: w.publisher(DenseGraph, "/b/sgreg/dense", qos.DENSE),
                DenseRequest: w.publisher(DenseRequest, "/a/sgreg/dense_request", qos.DENSE_REQUEST),
                RegistrationResult: w.publisher(RegistrationResult, "/b/sgreg/registration", qos.RESULTS),
                InstanceMap: w.map_pubs["a"]}
        assert w.spin_until(lambda: w.node.count_subscribers("/b/sgreg/coarse") >= 1, 30)
        for cls, raw in valid_messages(a, b).items():
            for _ in range(150):
                pubs[cls].publish(mutate(raw, rng))
                rclpy.spin_once(w.node, timeout_sec=0.002)
        assert w.spin_until(lambda: w.counter("/a/registration", "malformed_message") > 0
                            and w.counter("/a/agent", "malformed_message") > 0, 30), w.diagnostics
        w.spin_until(lambda: False, 2.0)
        assert not alive(procs)
    finally:
        processes.stop(procs)
        w.close()
        rclpy.try_shutdown()


@pytest.mark.parametrize("ns", [0, 1_700_000_000_123_456_789, 1_700_000_000_999_999_999])
def test_stamps_pass_through_the_wire_to_the_nanosecond(ns):
    """A map's stamp, through a serialised message and back (float seconds of today's epoch
    resolve 240 ns, and rounding up to a whole second lost a second); the nodes end to end:
    test_nodes.py."""
    msg = convert.instance_map_to_msg(agent_maps(["a", "b"], seed=1)[0]["a"], "a", 1, ns)
    back = deserialize_message(serialize_message(msg), InstanceMap)
    assert convert.stamp_to_ns(back.header.stamp) == ns and back.header.stamp.nanosec < 1_000_000_000
