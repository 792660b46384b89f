"""The checks that tell when a map moved under a link's kept pairs or the peer's points
(runtime/kept.py): a dense answer and the peer's coarse graph are compared node by node."""
from dataclasses import replace

import numpy as np

from sgreg_core.runtime.kept import dense_shift, moved_between
from sgreg_core.runtime.messages import GraphMessage, NodeFeatures


def _graph(ids, centers) -> GraphMessage:
    ids = np.asarray(ids, np.int64)
    nodes = NodeFeatures(node_ids=ids, centers=np.asarray(centers, np.float64),
                         descriptor=np.zeros((len(ids), 4), np.float32))
    return GraphMessage(agent_id="b", sequence=1, map_sequence=1, weights_id="w", stamp_ns=0, nodes=nodes,
                        extents=np.ones((len(ids), 3), np.float32))


def test_a_shift_is_measured_on_the_nodes_the_two_share():
    centers = np.arange(30, dtype=float).reshape(10, 3)
    dense = _graph(range(10), centers)
    assert dense_shift(dense, dense) == 0.0 and not moved_between(dense, dense, 0.5)
    moved = _graph(range(10), centers + [1.0, 0.0, 0.0])
    assert dense_shift(moved, dense) == 1.0 and moved_between(moved, dense, 0.5)


def test_a_graph_that_keeps_few_of_the_answers_nodes_counts_as_moved():
    """One unmoved node the two still share must not stand for the nine that are gone."""
    centers = np.arange(30, dtype=float).reshape(10, 3)
    dense = _graph(range(10), centers)
    one_left = _graph([0, 100, 101], [centers[0], [50, 0, 0], [60, 0, 0]])
    assert dense_shift(one_left, dense) == float("inf") and moved_between(one_left, dense, 0.5)
    half_left = _graph(range(5), centers[:5])
    assert dense_shift(half_left, dense) == 0.0


def test_a_shift_that_cannot_be_measured_counts_as_moved():
    dense = _graph(range(4), np.zeros((4, 3)))
    nan = replace(dense, nodes=replace(dense.nodes, centers=np.full((4, 3), np.nan)))
    assert moved_between(nan, dense, 0.5)
