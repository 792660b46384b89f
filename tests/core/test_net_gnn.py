"""Triplet GNN: sampling, anticlockwise ordering, 4-DoF invariance, determinism."""
import numpy as np
import pytest
import torch

from sgreg_core.geometry import yaw_transform
from sgreg_core.net.node_encoder import NodeEncoder, NodeEncoderConfig
from sgreg_core.net.testing import toy_graph
from sgreg_core.net.triplet_gnn import (GNNConfig, TripletGNN, neighbor_table,
                                        order_anticlockwise, sample_triplets)


def _tensors(graph):
    return (torch.from_numpy(graph.centers), torch.from_numpy(graph.edges))


def test_neighbor_table_nearest_first_and_capped():
    centers = torch.tensor([[0, 0, 0], [3, 0, 0], [1, 0, 0], [0, 2, 0]], dtype=torch.float32)
    edges = torch.tensor([[0, 1], [0, 2], [0, 3], [1, 2]])
    nbr, valid = neighbor_table(centers, edges, max_neighbors=2)
    assert nbr.shape == (4, 2)
    assert nbr[0].tolist() == [2, 3]  # 1 m, 2 m kept; 3 m dropped by the cap
    assert valid[3].tolist() == [True, False] and nbr[3, 0] == 0
    assert set(nbr[1].tolist()) == {0, 2}


def test_triplets_are_neighbour_pairs_ordered_anticlockwise():
    graph = toy_graph(np.random.default_rng(1), n=30)
    centers, edges = _tensors(graph)
    nbr, valid = neighbor_table(centers, edges, 12)
    j, k, mask = sample_triplets(nbr, valid, 10, torch.Generator().manual_seed(0))
    j, k = order_anticlockwise(centers, j, k)
    assert mask.any()
    adj = np.zeros((30, 30), bool)
    adj[graph.edges[:, 0], graph.edges[:, 1]] = adj[graph.edges[:, 1], graph.edges[:, 0]] = True
    rows = torch.arange(30).unsqueeze(1).expand_as(j)
    i_, j_, k_ = rows[mask].numpy(), j[mask].numpy(), k[mask].numpy()
    assert adj[i_, j_].all() and adj[i_, k_].all() and (j_ != k_).all()
    e_ij, e_ik = graph.centers[j_] - graph.centers[i_], graph.centers[k_] - graph.centers[i_]
    assert (e_ij[:, 0] * e_ik[:, 1] - e_ij[:, 1] * e_ik[:, 0] >= 0).all()
    # no duplicate triplet per anchor
    keys = i_ * 10000 + np.minimum(j_, k_) * 100 + np.maximum(j_, k_)
    assert len(np.unique(keys)) == len(keys)
    # an anchor with d neighbours has min(C(d, 2), 10) triplets
    deg = valid.sum(1).numpy()
    assert (mask.sum(1).numpy() == np.minimum(deg * (deg - 1) // 2, 10)).all()


@pytest.mark.parametrize("use_triplets", [True, False])
def test_gnn_invariant_to_yaw_and_translation(use_triplets):
    torch.manual_seed(0)
    rng = np.random.default_rng(2)
    graph = toy_graph(rng, n=25)
    enc = NodeEncoder(NodeEncoderConfig())
    gnn = TripletGNN(GNNConfig(use_triplets=use_triplets), enc.cfg.d_out).eval()
    x0 = enc(torch.randn(25, 384), torch.from_numpy(graph.extents))
    T = yaw_transform(rng.uniform(-np.pi, np.pi), rng.uniform(-20, 20, 3))
    moved = (graph.centers @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    edges = torch.from_numpy(graph.edges)
    with torch.no_grad():
        a = gnn(x0, torch.from_numpy(graph.centers), edges)
        b = gnn(x0, torch.from_numpy(moved), edges)
    assert not torch.allclose(a, x0)  # the message passing did something
    torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


def test_gnn_sees_mirror_images_apart():
    """Anticlockwise ordering makes the triplets chiral: a mirrored layout is another scene."""
    torch.manual_seed(0)
    graph = toy_graph(np.random.default_rng(3), n=25)
    gnn = TripletGNN(GNNConfig(), 32).eval()
    x0 = torch.randn(25, 32)
    mirrored = graph.centers * np.array([1, -1, 1], np.float32)
    edges = torch.from_numpy(graph.edges)
    with torch.no_grad():
        a = gnn(x0, torch.from_numpy(graph.centers), edges)
        b = gnn(x0, torch.from_numpy(mirrored), edges)
    assert (a - b).abs().max() > 1e-3


def test_gnn_deterministic_in_eval_random_in_train():
    torch.manual_seed(0)
    graph = toy_graph(np.random.default_rng(4), n=30)
    gnn = TripletGNN(GNNConfig(max_triplets=3), 32)
    x0 = torch.randn(30, 32)
    centers, edges = _tensors(graph)
    with torch.no_grad():
        gnn.eval()
        assert torch.equal(gnn(x0, centers, edges), gnn(x0, centers, edges))
        gnn.train()
        assert not torch.equal(gnn(x0, centers, edges), gnn(x0, centers, edges))


def test_gnn_without_edges_or_nodes():
    gnn = TripletGNN(GNNConfig(), 32).eval()
    x0 = torch.randn(3, 32)
    with torch.no_grad():
        out = gnn(x0, torch.randn(3, 3), torch.zeros(0, 2, dtype=torch.long))
        assert out.shape == (3, 32) and torch.isfinite(out).all()
        empty = gnn(torch.zeros(0, 32), torch.zeros(0, 3), torch.zeros(0, 2, dtype=torch.long))
        assert empty.shape == (0, 32)
