"""One message of every sgreg_msgs type, filled with seeded random content in every field."""
from __future__ import annotations

import numpy as np
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult

from sgreg_ros.pointcloud import pack_xyz_id


def _stamp(msg, rng):
    msg.header.stamp.sec = int(rng.integers(0, 2**31 - 1))
    msg.header.stamp.nanosec = int(rng.integers(0, 10**9))


def instance_map(rng, n_points=1000, n_inst=12):
    m = InstanceMap()
    _stamp(m, rng)
    m.header.frame_id = "a/map"
    m.agent_id = "a"
    m.sequence = int(rng.integers(0, 2**32))
    m.instance_ids = [int(i) for i in rng.choice(np.arange(1, 1000), n_inst, replace=False)]
    m.labels = [f"label {i} é" for i in range(n_inst)]
    m.label_scores = rng.random(n_inst).astype(np.float32).tolist()
    m.points = pack_xyz_id(rng.normal(size=(n_points, 3)), rng.choice(m.instance_ids, n_points),
                           "instance", frame_id="a/map")
    return m


def coarse_graph(rng, n_nodes=40, dim=96):
    g = CoarseGraph()
    _stamp(g, rng)
    g.header.frame_id = "b/map"
    g.agent_id = "b"
    g.sequence = int(rng.integers(0, 2**32))
    g.map_sequence = int(rng.integers(0, 2**32))
    g.weights_id = "0123456789ab"
    q = rng.normal(size=4)
    g.level.x, g.level.y, g.level.z, g.level.w = (q / np.linalg.norm(q)).tolist()
    g.node_ids = rng.integers(0, 2**32, n_nodes, dtype=np.uint64).tolist()
    g.centers = rng.normal(size=3 * n_nodes).astype(np.float32).tolist()
    g.extents = rng.random(3 * n_nodes).astype(np.float32).tolist()
    g.feature_dim = dim
    g.feature_encoding = CoarseGraph.FEATURE_INT8
    g.feature_scales = rng.random(n_nodes).astype(np.float32).tolist()
    g.features = rng.integers(0, 256, n_nodes * dim, dtype=np.uint8).tobytes()
    return g


def dense_request(rng):
    r = DenseRequest()
    _stamp(r, rng)
    r.from_agent, r.to_agent = "a", "b"
    r.sequence = int(rng.integers(0, 2**32))
    r.coarse_sequence = int(rng.integers(0, 2**32))
    r.weights_id = "0123456789ab"
    r.node_ids = rng.integers(0, 2**32, 17, dtype=np.uint64).tolist()
    return r


def dense_graph(rng, n_points=350_000):
    """About 5.6 MB: 350k points x 16 bytes."""
    d = DenseGraph()
    _stamp(d, rng)
    d.header.frame_id = "b/map"
    d.agent_id = "b"
    d.sequence = int(rng.integers(0, 2**32))
    d.requester = "a"
    d.request_sequence = int(rng.integers(0, 2**32))
    d.graph = coarse_graph(rng)
    d.points = pack_xyz_id(rng.normal(size=(n_points, 3)) * 5.0,
                           rng.integers(0, 2**32, n_points, dtype=np.uint64), "node_id",
                           frame_id="b/map")
    return d


def registration_result(rng):
    r = RegistrationResult()
    _stamp(r, rng)
    r.header.frame_id = "b/map"
    r.agent_id, r.peer_id = "a", "b"
    r.sequence = int(rng.integers(0, 2**32))
    t = r.transform
    t.header = r.header
    t.child_frame_id = "a/map"
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = rng.normal(size=3).tolist()
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q.tolist()
    r.verified = True
    r.mode = "dense"
    r.reason = "ok"
    r.link = "confirmed"
    r.node_matches, r.correspondences, r.inliers, r.inlier_objects = (int(v) for v in rng.integers(0, 1000, 4))
    r.inlier_ratio, r.confidence, r.fitness, r.ambiguity = (float(np.float32(v)) for v in rng.random(4))
    r.peer_coarse_sequence, r.peer_dense_sequence = (int(v) for v in rng.integers(0, 2**32, 2))
    r.timing_names = ["match", "pose", "total"]
    r.timing_ms = rng.random(3).astype(np.float32).tolist()
    r.counter_names = ["duplicate_sequence", "rejected_weights"]
    r.counter_values = [3, 1]
    r.inlier_node_pairs = rng.integers(0, 2**32, 24, dtype=np.uint64).tolist()
    r.key_id, r.signed_ns = "0123456789abcdef", int(rng.integers(0, 2**62))
    r.signature = rng.integers(0, 256, 64, dtype=np.uint8).tobytes()
    return r


def all_samples(seed=0):
    """{type name: message} for every sgreg_msgs type."""
    rng = np.random.default_rng(seed)
    return {
        "InstanceMap": instance_map(rng),
        "CoarseGraph": coarse_graph(rng),
        "DenseRequest": dense_request(rng),
        "DenseGraph": dense_graph(rng),
        "RegistrationResult": registration_result(rng),
    }
