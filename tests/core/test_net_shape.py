"""Shape network: point sampling, yaw/translation invariance of F, H and Z, padding."""
import numpy as np
import torch

from sgreg_core.geometry import transform_points, yaw_transform
from sgreg_core.net.shape import PointEncoder, ShapeConfig, ShapeEncoder, sample_node_points


def _clouds(rng, counts):
    return [(rng.normal(size=(c, 3)) * [1.0, 0.5, 0.3]).astype(np.float32) for c in counts]


def test_sampling_takes_distinct_points_of_each_node_and_pads():
    rng = np.random.default_rng(0)
    clouds = _clouds(rng, [5, 100, 0, 64])
    pts, valid = sample_node_points(clouds, 64, np.random.default_rng(1))
    assert pts.shape == (4, 64, 3) and pts.dtype == np.float32
    assert valid.sum(1).tolist() == [5, 64, 0, 64]
    for cloud, p, v in zip(clouds, pts, valid):
        chosen = p[v]
        assert len(np.unique(chosen, axis=0)) == len(chosen)
        if len(chosen):
            assert (np.abs(chosen[:, None] - cloud[None]).sum(-1).min(1) == 0).all()
    assert (pts[~valid] == 0).all()
    again, _ = sample_node_points(clouds, 64, np.random.default_rng(1))
    assert np.array_equal(pts, again)
    other, _ = sample_node_points(clouds, 64, np.random.default_rng(2))
    assert not np.array_equal(pts[1], other[1])


def _encode(shape_net, point_net, clouds, centers, x):
    pts, valid = sample_node_points(clouds, shape_net.cfg.points_per_node, np.random.default_rng(0))
    valid = torch.from_numpy(valid)
    centers = torch.from_numpy(centers.astype(np.float32))
    local = (torch.from_numpy(pts) - centers.unsqueeze(1)) * valid.unsqueeze(-1)
    with torch.no_grad():
        f, h = shape_net(local, valid)
        return f, h, point_net(local, valid, h, f, centers, x)


def test_shape_features_invariant_to_yaw_and_translation():
    torch.manual_seed(0)
    rng = np.random.default_rng(3)
    clouds = _clouds(rng, [80, 40, 200, 10])
    centers = np.stack([c.mean(0) for c in clouds]) + rng.normal(0, 2, (4, 3))
    x = torch.randn(4, 8)
    cfg = ShapeConfig()
    nets = ShapeEncoder(cfg).eval(), PointEncoder(cfg, 8).eval()
    f, h, z = _encode(*nets, clouds, centers, x)
    assert f.shape == (4, 32) and h.shape == (4, 64, 96) and z.shape == (4, 64, 32)
    T = yaw_transform(rng.uniform(-np.pi, np.pi), rng.uniform(-10, 10, 3))
    f2, h2, z2 = _encode(*nets, [transform_points(T, c) for c in clouds], transform_points(T, centers), x)
    torch.testing.assert_close(f, f2, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(h, h2, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(z, z2, atol=1e-4, rtol=1e-4)
    # but not to a tilt: the features know where "up" is
    tilt = np.eye(4)
    tilt[1:3, 1:3] = [[0, -1], [1, 0]]
    f3, _, _ = _encode(*nets, [transform_points(tilt, c) for c in clouds], transform_points(tilt, centers), x)
    assert (f - f3).abs().max() > 1e-3


def test_point_context_sees_the_surrounding_nodes():
    """The same node cloud next to a neighbour on its left or on its right: same F, other Z."""
    torch.manual_seed(0)
    cfg = ShapeConfig()
    nets = ShapeEncoder(cfg).eval(), PointEncoder(cfg, 8).eval()
    rng = np.random.default_rng(4)
    cloud = _clouds(rng, [100])[0]
    other = _clouds(rng, [50])[0]
    x = torch.randn(2, 8)
    left = _encode(*nets, [cloud, other - [2, 0, 0]], np.array([[0, 0, 0], [-2, 0, 0]]), x)
    right = _encode(*nets, [cloud, other + [2, 0, 0]], np.array([[0, 0, 0], [2, 0, 0]]), x)
    torch.testing.assert_close(left[0], right[0])
    assert (left[2][0] - right[2][0]).abs().max() > 1e-3


def test_padding_does_not_leak_into_features():
    torch.manual_seed(0)
    cfg = ShapeConfig(points_per_node=16, knn=4)
    shape_net, point_net = ShapeEncoder(cfg).eval(), PointEncoder(cfg, 8).eval()
    centers, x = torch.zeros(1, 3), torch.randn(1, 8)
    local = torch.randn(1, 16, 3)
    valid = torch.zeros(1, 16, dtype=torch.bool)
    valid[0, :7] = True
    garbage = local.clone()
    garbage[0, 7:] = 100.0
    with torch.no_grad():
        outs = []
        for pts in (local, garbage):
            f, h = shape_net(pts, valid)
            outs.append((f, h, point_net(pts, valid, h, f, centers, x)))
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b)
    assert (outs[0][2][0, 7:] == 0).all()
