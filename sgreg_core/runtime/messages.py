"""Decoded coarse/dense graph messages: what one agent tells another, as numpy arrays.

The ROS layer converts sgreg_msgs to and from these; everything else works on them."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np


def graph_digest(node_ids: np.ndarray, centers: np.ndarray) -> str:
    """12 hex chars naming a graph's content (node ids and centers to the millimetre): two maps
    with one digest hold the same evidence, whatever their sequence numbers say."""
    h = hashlib.sha256(np.ascontiguousarray(node_ids, np.int64).tobytes())
    h.update(np.round(np.asarray(centers, np.float64) * 1000).astype(np.int64).tobytes())
    return h.hexdigest()[:12]


@dataclass
class GraphMessage:
    """A CoarseGraph, or the content of a DenseGraph when `points` is set.

    x:               (n, d) float32 node descriptors (decoded from the wire encoding).
    centers/extents: (n, 3) float32, sender's map frame.
    points:          (P, 3) float32 node points (dense only), sender's map frame.
    point_node:      (P,) index into the node arrays of each point (dense only).
    """

    agent_id: str
    sequence: int
    map_sequence: int
    weights_id: str
    stamp: float
    node_ids: np.ndarray
    centers: np.ndarray
    extents: np.ndarray
    x: np.ndarray
    points: np.ndarray | None = None
    point_node: np.ndarray | None = None
    requester: str = ""
    request_sequence: int = 0

    @property
    def num_nodes(self) -> int:
        return int(self.node_ids.shape[0])

    @property
    def is_dense(self) -> bool:
        return self.points is not None

    @property
    def digest(self) -> str:
        return graph_digest(self.node_ids, self.centers)


@dataclass
class DenseRequestMessage:
    from_agent: str
    to_agent: str
    sequence: int
    coarse_sequence: int
    weights_id: str
    node_ids: np.ndarray  # empty: all nodes


@dataclass
class Estimate:
    """One registration estimate T_agent^peer (maps the agent's map into the peer's), as the
    registration node publishes it. verified: the transform may be acted on (the verdict
    passed and the link is confirmed); reason: "ok" or why not; confidence: P(T right |
    evidence); inlier_objects / fitness / ambiguity: the verdict's evidence (all of it in
    `evidence`, pose.verdict.Evidence as a dict); link: the peer link's state after this
    estimate ("none", "candidate", "confirmed")."""

    peer_id: str
    T: np.ndarray
    verified: bool
    mode: str                 # "coarse" | "dense" | "merged"
    reason: str
    node_matches: int
    correspondences: int
    inliers: int
    inlier_ratio: float
    confidence: float
    peer_coarse_sequence: int
    peer_dense_sequence: int
    timing_ms: dict
    inlier_objects: int = 0
    fitness: float = float("nan")
    ambiguity: float = 0.0
    link: str = "none"
    evidence: dict = field(default_factory=dict)
