"""Dual softmax, mutual top-k and Sinkhorn with a dustbin."""
import math

import pytest
import torch

from sgreg_core.net.matching import (MatchConfig, NodeMatcher, PointMatcher, log_dual_softmax,
                                     log_optimal_transport, mutual_topk)


def test_mutual_topk_on_hand_made_scores():
    s = torch.tensor([[0.9, 0.1, 0.0],
                      [0.8, 0.2, 0.1],
                      [0.0, 0.3, 0.7]])
    m1 = mutual_topk(s, 1)
    # row 1 prefers column 0, but column 0 prefers row 0: not mutual
    assert m1.nonzero().tolist() == [[0, 0], [2, 2]]
    m2 = mutual_topk(s, 2)
    assert m2.nonzero().tolist() == [[0, 0], [1, 0], [1, 1], [2, 1], [2, 2]]
    assert mutual_topk(s, 10).all()
    assert mutual_topk(torch.zeros(0, 3), 2).shape == (0, 3)


def test_dual_softmax_is_product_of_row_and_column_softmax():
    a, b = torch.randn(4, 8), torch.randn(5, 8)
    s = a @ b.T / math.sqrt(8)
    expected = torch.softmax(s, 1) * torch.softmax(s, 0)
    torch.testing.assert_close(log_dual_softmax(a, b).exp(), expected)


def test_node_matcher_threshold_and_mutuality():
    matcher = NodeMatcher(8, MatchConfig(d_match=8, node_topk=1, node_threshold=0.5))
    strong = torch.eye(3) * 20.0
    ia, ib, conf = matcher.match(strong, strong[[2, 0, 1]])
    assert list(zip(ia.tolist(), ib.tolist())) == [(0, 1), (1, 2), (2, 0)]
    assert (conf > 0.99).all()
    # all-equal similarities: A = 1/9 everywhere, below the threshold
    flat = torch.ones(3, 8)
    assert matcher.match(flat, flat)[0].numel() == 0
    assert matcher.match(torch.zeros(0, 8), strong)[0].numel() == 0


def _marginal_checks(log_p, valid_a, valid_b):
    p = log_p.exp()
    na, nb = valid_a.sum(1).float(), valid_b.sum(1).float()
    rows, cols = p.sum(2), p.sum(1)
    for k in range(p.shape[0]):
        # every valid point has mass 1 (matched or in the dustbin); padding has none
        torch.testing.assert_close(rows[k, :-1][valid_a[k]], torch.ones(int(na[k])), atol=1e-3, rtol=0)
        torch.testing.assert_close(cols[k, :-1][valid_b[k]], torch.ones(int(nb[k])), atol=1e-3, rtol=0)
        assert rows[k, :-1][~valid_a[k]].sum() < 1e-6
        assert cols[k, :-1][~valid_b[k]].sum() < 1e-6
        # the dustbins absorb what the other side does not match
        torch.testing.assert_close(rows[k, -1], nb[k], atol=1e-2, rtol=1e-3)
        torch.testing.assert_close(cols[k, -1], na[k], atol=1e-2, rtol=1e-3)


def test_sinkhorn_marginals_with_padding():
    torch.manual_seed(0)
    scores = torch.randn(3, 6, 5) * 3
    valid_a = torch.tensor([[1, 1, 1, 1, 1, 1], [1, 1, 1, 0, 0, 0], [1, 0, 0, 0, 0, 0]], dtype=torch.bool)
    valid_b = torch.tensor([[1, 1, 1, 1, 1], [1, 1, 0, 0, 0], [1, 1, 1, 1, 0]], dtype=torch.bool)
    log_p = log_optimal_transport(scores, valid_a, valid_b, torch.tensor(0.5), iters=100)
    assert log_p.shape == (3, 7, 6) and torch.isfinite(log_p).all()
    _marginal_checks(log_p, valid_a, valid_b)


def test_sinkhorn_batched_equals_one_by_one_and_padding_is_inert():
    torch.manual_seed(1)
    scores = torch.randn(2, 4, 4)
    valid = torch.ones(2, 4, dtype=torch.bool)
    valid[1, 3] = False
    batched = log_optimal_transport(scores, valid, valid, torch.tensor(1.0), 20)
    alone = log_optimal_transport(scores[1:, :3, :3], valid[1:, :3], valid[1:, :3], torch.tensor(1.0), 20)
    keep = [0, 1, 2, 4]
    torch.testing.assert_close(batched[1][keep][:, keep], alone[0], atol=1e-5, rtol=1e-5)


def test_point_matcher_finds_a_permutation():
    matcher = PointMatcher(MatchConfig(sinkhorn_iters=50, point_threshold=0.5))
    z_a = torch.eye(6).unsqueeze(0) * 8.0
    perm = torch.tensor([3, 0, 5, 1, 4, 2])
    z_b = z_a[:, perm]
    valid = torch.ones(1, 6, dtype=torch.bool)
    valid_b = valid.clone()
    valid_b[0, 5] = False  # b's point 5 (a's 2) is padding: a's 2 must stay unmatched
    pair, ia, ib, mass = matcher.match(z_a, valid, z_b, valid_b)
    assert pair.tolist() == [0] * 5
    assert sorted(zip(ia.tolist(), ib.tolist())) == sorted(
        (int(perm[j]), j) for j in range(5))
    assert (mass > 0.5).all()


@pytest.mark.parametrize("iters", [1, 5])
def test_sinkhorn_gradients_are_finite(iters):
    scores = torch.randn(2, 5, 5, requires_grad=True)
    valid = torch.ones(2, 5, dtype=torch.bool)
    valid[0, 2:] = False
    dustbin = torch.tensor(1.0, requires_grad=True)
    log_p = log_optimal_transport(scores, valid, valid, dustbin, iters)
    (log_p[0, :2, :2].sum() + log_p[1, :-1, -1].sum()).backward()
    assert torch.isfinite(scores.grad).all() and torch.isfinite(dustbin.grad)


def test_inference_sinkhorn_equals_the_log_domain_one():
    """Without gradients the transport runs on scaling vectors (faster): same plan."""
    import torch

    from sgreg_core.net.matching import log_optimal_transport

    torch.manual_seed(0)
    scores = torch.randn(30, 16, 12) * 5
    valid_src, valid_ref = torch.rand(30, 16) > 0.2, torch.rand(30, 12) > 0.3
    dustbin = torch.tensor(1.0)
    with torch.enable_grad():
        log_p = log_optimal_transport(scores, valid_src, valid_ref, dustbin, 20)
    with torch.no_grad():
        fast = log_optimal_transport(scores, valid_src, valid_ref, dustbin, 20)
    rows = torch.cat([valid_src, torch.ones(30, 1, dtype=torch.bool)], 1)
    cols = torch.cat([valid_ref, torch.ones(30, 1, dtype=torch.bool)], 1)
    both = rows.unsqueeze(2) & cols.unsqueeze(1)
    assert torch.allclose(log_p.exp()[both], fast.exp()[both], atol=1e-5)
    assert torch.isfinite(fast[both]).all() and not torch.isnan(fast).any()
