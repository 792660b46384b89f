"""Kept correspondences: the inlier point pairs of a link's last dense estimate, which merged
estimates reuse while only coarse graphs arrive (the paper's scheme), and the checks that tell
when either map has moved under them (runtime/peers.py drops them then).

Public API:
    Kept                                    the pairs, their nodes' centers and levelling then
    centers_of(ids, node_ids, centers)      {node id: center} of the ids found
    levelled_alike(a, b) -> bool            two levelling rotations are the same
    median_shift(then, node_ids, centers)   median movement of nodes since `then`
    dense_shift(graph, dense)               median movement of a dense answer's nodes in the graph
    moved_between(graph, dense, max_shift_m)  a dense answer's nodes no longer where the graph has them
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..pipeline import Correspondences
from .messages import GraphMessage


@dataclass
class Kept:
    """Inlier correspondences of a dense estimate (peer -> own), with the centers their nodes
    had in each map then and both maps' levelling then, to notice when either map moves
    under them, and the estimate's pose between the levelled graphs (peer -> own)."""

    corr: Correspondences
    peer_nodes: dict[int, np.ndarray]
    own_nodes: dict[int, np.ndarray]
    pose: np.ndarray
    own_level: np.ndarray = field(default_factory=lambda: np.eye(3))
    peer_level: np.ndarray = field(default_factory=lambda: np.eye(3))


def centers_of(ids: np.ndarray, node_ids: np.ndarray, centers: np.ndarray) -> dict[int, np.ndarray]:
    """{node id: center} for the ids among node_ids (the others are left out)."""
    index = {int(i): k for k, i in enumerate(node_ids)}
    return {int(i): np.asarray(centers[index[int(i)]], np.float64) for i in np.unique(ids) if int(i) in index}


def levelled_alike(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two levelling rotations are the same (data levelled by them share a frame)."""
    return np.allclose(a, b, atol=1e-9)


def median_shift(then: dict[int, np.ndarray], node_ids: np.ndarray, centers: np.ndarray) -> float:
    """Median movement of the nodes in `then` (inf when fewer than half of them are left)."""
    now = centers_of(np.fromiter(then, np.int64), node_ids, centers)
    if 2 * len(now) < len(then):
        return float("inf")
    return float(np.median([np.linalg.norm(now[i] - then[i]) for i in now])) if now else float("inf")


def dense_shift(graph: GraphMessage, dense: GraphMessage) -> float:
    """Median distance between where a dense answer has its nodes and where the peer's coarse
    graph has them (inf when the graph has fewer than half of them: counted against the
    answer's nodes, so that one node the two share cannot stand for all of them)."""
    ids = np.unique(dense.nodes.node_ids)
    in_graph = centers_of(ids, graph.nodes.node_ids, graph.nodes.centers)
    if 2 * len(in_graph) < len(ids):
        return float("inf")
    return median_shift(in_graph, dense.nodes.node_ids, dense.nodes.centers)


def moved_between(graph: GraphMessage, dense: GraphMessage, max_shift_m: float) -> bool:
    """Whether the nodes of a dense answer lie more than max_shift_m (median) from where the
    peer's coarse graph puts them, or the graph has too few of them: the two are not in one
    frame. A shift that cannot be measured (NaN) counts as moved."""
    return not dense_shift(graph, dense) <= max_shift_m
