"""Core data types shared by every part of sgreg_core.

They are plain containers with numpy arrays so that the ROS layer, the CLI and the tests can
build and inspect them without knowing anything about how they are computed.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from .geometry import transform_points

if TYPE_CHECKING:    # maps/level.py imports this module
    from .maps.level import Levelling


@dataclass
class InstanceMap:
    """What a semantic-mapping front-end hands us (docs/ARCHITECTURE.md ("Contracts")).

    points:   (N, 3) float32, metres, z up.
    instance: (N,) int32 instance id per point; ids <= 0 or absent from `labels` are unlabelled.
    labels:   instance id -> open-set label text.
    scores:   instance id -> detection score in [0, 1] (1.0 when the front-end gives none).
    colors:   (N, 3) uint8 or None.
    """

    points: np.ndarray
    instance: np.ndarray
    labels: dict[int, str]
    scores: dict[int, float] = field(default_factory=dict)
    colors: np.ndarray | None = None

    def transformed(self, T: np.ndarray) -> "InstanceMap":
        """The same map with its points moved by the 4x4 transform T."""
        return InstanceMap(transform_points(T, self.points).astype(np.float32), self.instance,
                           self.labels, self.scores, self.colors)


@dataclass
class SceneGraph:
    """A semantic scene graph G = {V, E} (paper section IV-A), one node per kept instance.

    node_ids:   (n,) int64 instance id of each node in the source instance map.
    labels:     n label strings.
    scores:     (n,) float32 label scores.
    centers:    (n, 3) float32 node centers o_i.
    extents:    (n, 3) float32 box extents b_i (length >= width, height), orientation dropped.
    points:     n arrays (k_i, 3) float32, the voxel-downsampled node point clouds P_i.
    edges:      (m, 2) int64 undirected edges (i < j), indices into the node arrays.
    structural: (n,) bool, True for floor / wall / ceiling-like nodes.
    level:      how the map was levelled before the graph was built (maps/level.Levelling:
                centers and points are in the levelled frame, p = level.R p_map); None: the
                map's own frame.
    map_points: (N, 3) float32 every point of the map the graph was built from, labelled or
                not, in the graph's frame (what a pose is verified against); None: only the
                node points are known.
    """

    node_ids: np.ndarray
    labels: list[str]
    scores: np.ndarray
    centers: np.ndarray
    extents: np.ndarray
    points: list[np.ndarray]
    edges: np.ndarray
    structural: np.ndarray
    level: Levelling | None = None
    map_points: np.ndarray | None = None

    @property
    def num_nodes(self) -> int:
        return int(self.node_ids.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edges.shape[0])

    def reordered(self, perm: np.ndarray) -> "SceneGraph":
        """The same graph with its nodes listed in another order: new row r is old node perm[r]
        (edges renumbered, still i < j and sorted)."""
        perm = np.asarray(perm, np.int64)
        edges = np.sort(np.argsort(perm)[self.edges], axis=1) if len(self.edges) else self.edges
        if len(edges):
            edges = edges[np.lexsort((edges[:, 1], edges[:, 0]))]
        return replace(self, node_ids=self.node_ids[perm], labels=[self.labels[i] for i in perm],
                       scores=self.scores[perm], centers=self.centers[perm],
                       extents=self.extents[perm], points=[self.points[i] for i in perm],
                       edges=edges, structural=self.structural[perm])
