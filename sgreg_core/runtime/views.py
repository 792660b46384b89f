"""What a viewer draws of an agent's registration (RViz, Foxglove: sgreg_ros/markers.py turns
these into messages): its scene graph in its map frame, the node matches of its verified links
and every map it knows of, in the merged frame. Plain arrays, no ROS.

Public API:
    label_rgb(label) -> (3,) float in [0, 1]    one stable colour per label text
    agent_rgb(index) -> (3,) uint8              one colour per agent (tab10)
    GraphView                                   nodes (map frame), labels, colours, edges
    graph_view(graph) -> GraphView              of a SceneGraph built on a levelled map
    centers_in_map(node_ids, centers, level) / points_in_map(points, level)   levelled -> map frame
    match_lines(own, peer, pairs, T_own, T_peer) -> (m, 2, 3)   matched node centers, merged frame
    merged_cloud(clouds, poses, voxel) -> (points (N, 3), rgb (N,) uint32 0x00RRGGBB)
"""
from __future__ import annotations

import colorsys
import hashlib
from dataclasses import dataclass

import numpy as np

from ..geometry import transform_points, voxel_downsample
from ..types import SceneGraph

_TAB10 = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                   [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]],
                  np.uint8)


def label_rgb(label: str) -> np.ndarray:
    """A colour per label text, the same in every agent and run."""
    h = int(hashlib.sha1(label.strip().lower().encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    return np.array(colorsys.hsv_to_rgb(h, 0.65, 0.9))


def agent_rgb(index: int) -> np.ndarray:
    return _TAB10[index % len(_TAB10)]


@dataclass
class GraphView:
    node_ids: np.ndarray     # (n,)
    centers: np.ndarray      # (n, 3) map frame
    extents: np.ndarray      # (n, 3) box sizes (about z, orientation dropped as in the graph)
    labels: list[str]
    colors: np.ndarray       # (n, 3) float in [0, 1]
    edges: np.ndarray        # (e, 2) node indices


def _to_map(level, points: np.ndarray) -> np.ndarray:
    """Levelled-frame points back into the map frame (p_map = R^T p_levelled)."""
    R = np.eye(3) if level is None else np.asarray(level.R if hasattr(level, "R") else level, np.float64)
    return np.asarray(points, np.float64) @ R


def graph_view(graph: SceneGraph) -> GraphView:
    return GraphView(node_ids=np.asarray(graph.node_ids), centers=_to_map(graph.level, graph.centers),
                     extents=np.asarray(graph.extents, np.float64), labels=list(graph.labels),
                     colors=np.array([label_rgb(l) for l in graph.labels]).reshape(-1, 3),
                     edges=np.asarray(graph.edges, np.int64).reshape(-1, 2))


def centers_in_map(node_ids: np.ndarray, centers: np.ndarray, level) -> dict[int, np.ndarray]:
    """node id -> its center in the map frame, from centers given in the levelled frame."""
    return dict(zip(np.asarray(node_ids).tolist(), _to_map(level, centers)))


def points_in_map(points: np.ndarray, level) -> np.ndarray:
    """Points of a levelled frame back in the map frame (level: a Levelling or a 3x3 R)."""
    return _to_map(level, points)


def match_lines(own: dict[int, np.ndarray], peer: dict[int, np.ndarray], pairs: np.ndarray,
                T_own: np.ndarray, T_peer: np.ndarray) -> np.ndarray:
    """(m, 2, 3) segments from each own node to its matched peer node, in the merged frame.
    pairs: (m, 2) (own id, peer id); own / peer: node id -> center in that agent's map frame."""
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    keep = [(a, b) for a, b in pairs.tolist() if a in own and b in peer]
    if not keep:
        return np.zeros((0, 2, 3))
    a = transform_points(T_own, np.array([own[i] for i, _ in keep]))
    b = transform_points(T_peer, np.array([peer[j] for _, j in keep]))
    return np.stack([a, b], axis=1)


def merged_cloud(clouds: dict, poses: dict, voxel: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Every agent's cloud (agent -> (N, 3) in its map frame) that has a merged pose, voxelised
    and moved into the merged frame, coloured by agent (agents in sorted order)."""
    pts, rgb = [], []
    for k, agent in enumerate(sorted(clouds)):
        if agent not in poses or len(clouds[agent]) == 0:
            continue
        p = transform_points(poses[agent], voxel_downsample(np.asarray(clouds[agent], np.float32), voxel))
        c = agent_rgb(k).astype(np.uint32)
        pts.append(p.astype(np.float32))
        rgb.append(np.full(len(p), (c[0] << 16) | (c[1] << 8) | c[2], np.uint32))
    if not pts:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.uint32)
    return np.concatenate(pts), np.concatenate(rgb)
