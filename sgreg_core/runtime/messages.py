"""What one agent tells another, and what it publishes, as plain numpy types.

The ROS layer converts sgreg_msgs to and from these; everything else works on them. A graph
message wraps the node features the network made (net.model.NodeFeatures: ids, centers,
descriptors), and an estimate wraps the registration the pipeline made (pipeline.Registration)
with what the link decided about it.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from ..net.model import NodeFeatures
from ..pipeline import Registration


def graph_digest(node_ids: np.ndarray, centers: np.ndarray) -> str:
    """12 hex chars naming a graph's content (node ids and centers to the millimetre): two maps
    with one digest hold the same evidence, whatever their sequence numbers say."""
    h = hashlib.sha256(np.ascontiguousarray(node_ids, np.int64).tobytes())
    h.update(np.round(np.asarray(centers, np.float64) * 1000).astype(np.int64).tobytes())
    return h.hexdigest()[:12]


@dataclass
class GraphMessage:
    """A CoarseGraph, or the content of a DenseGraph when `points` is set.

    nodes:           node ids, centers (n, 3) and descriptors (n, d) float32 (decoded from the
                     wire encoding), sender's levelled map frame; no points, valid or z (a
                     receiver computes those from `points`).
    extents:         (n, 3) float32 box extents.
    points:          (P, 3) float32 node points (dense only), sender's levelled map frame.
    level:           (3, 3) rotation the sender levelled its map with (p_levelled = level
                     p_map; maps/level.py), the identity when it did not.
    point_node:      (P,) index into the node arrays of each point (dense only).
    requester, request_sequence: the request a dense message answers.
    """

    agent_id: str
    sequence: int
    map_sequence: int
    weights_id: str
    stamp_ns: int
    nodes: NodeFeatures
    extents: np.ndarray
    points: np.ndarray | None = None
    point_node: np.ndarray | None = None
    requester: str = ""
    request_sequence: int = 0
    level: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def num_nodes(self) -> int:
        return int(self.nodes.node_ids.shape[0])

    @property
    def is_dense(self) -> bool:
        return self.points is not None

    @property
    def digest(self) -> str:
        return graph_digest(self.nodes.node_ids, self.nodes.centers)


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
    """One estimate T_agent^peer (maps the agent's map into the peer's) as the registration node
    publishes it: the pipeline's registration (peer graph as source, own graph as reference)
    and what the link made of it.

    T:               T_agent^peer, the inverse of registration.T.
    verified:        the transform may be acted on (the verdict passed and the link is
                     confirmed); reason: "ok" or why not (the verdict's reason or the link's).
    link:            the peer link's state after this estimate ("none", "candidate", "confirmed").
    peer_coarse_sequence / peer_dense_sequence: the peer's messages it was made from.
    timing_ms:       milliseconds per stage, "total" from message in to estimate out.
    stamp_ns:        the time of the newer of the two maps it was made from (their stamps, ns)."""

    peer_id: str
    T: np.ndarray
    verified: bool
    reason: str
    link: str
    registration: Registration
    peer_coarse_sequence: int
    peer_dense_sequence: int
    timing_ms: dict
    stamp_ns: int = 0

    @property
    def mode(self) -> str:
        return self.registration.mode

    @property
    def node_matches(self) -> int:
        return self.registration.node_matches

    @property
    def correspondences(self) -> int:
        return self.registration.correspondences

    @property
    def inliers(self) -> int:
        return self.registration.inliers

    @property
    def inlier_ratio(self) -> float:
        return self.registration.inlier_ratio

    @property
    def confidence(self) -> float:
        return self.registration.confidence

    @property
    def evidence(self) -> dict:
        """The verdict's evidence (pose.verdict.Evidence) as a dict, with the repeat check
        (pose/repeats.py: repeat, unrepeated) and whether the pose is the clouds' geometric
        one (pose/geometric.py) of the registration."""
        reg = self.registration
        return {**vars(reg.evidence), "repeat": reg.repeat, "unrepeated": reg.unrepeated,
                "geometric": reg.geometric}
