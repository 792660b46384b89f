"""Scene graph construction on hand-made maps and on a synthetic scene."""
import time
import tracemalloc

import numpy as np
import pytest

from sgreg_core.geometry import yaw_transform, transform_points
from sgreg_core.maps.scene_graph import (
    GraphConfig, _object_edges, _structural_edges, build_scene_graph, is_structural,
)
from sgreg_core.types import InstanceMap


def _box_surface(center, size, yaw=0.0, n=3000, seed=0):
    """Points on the faces of a box rotated by yaw about z."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.5, 0.5, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(p[np.arange(n), axis]) * 0.5
    p *= size
    return transform_points(yaw_transform(yaw, center), p).astype(np.float32)


def _map(parts, labels):
    pts = np.concatenate(parts)
    inst = np.concatenate([np.full(len(p), k + 1, np.int32) for k, p in enumerate(parts)])
    return InstanceMap(points=pts, instance=inst, labels={k + 1: l for k, l in enumerate(labels)})


def test_extents_centers_rotated_box():
    yaw = np.radians(33)
    m = _map([_box_surface((1, 2, 0.5), (2.0, 0.8, 1.0), yaw)], ["table"])
    g = build_scene_graph(m, GraphConfig(voxel_size=0.02))
    assert g.num_nodes == 1 and g.labels == ["table"] and not g.structural[0]
    np.testing.assert_allclose(g.extents[0], [2.0, 0.8, 1.0], atol=0.05)
    np.testing.assert_allclose(g.centers[0], [1, 2, 0.5], atol=0.05)
    assert g.points[0].dtype == np.float32 and len(g.points[0]) < 3000


def test_small_and_unlabelled_instances_dropped():
    big = _box_surface((0, 0, 0), (1, 1, 1), n=500)
    few = _box_surface((3, 0, 0), (1, 1, 1), n=10)
    tiny = _box_surface((5, 0, 0), (0.03, 0.03, 0.03), n=200)
    unl = _box_surface((7, 0, 0), (1, 1, 1), n=500)
    m = _map([big, few, tiny, unl], ["a", "b", "c", "d"])
    m.labels.pop(4)
    g = build_scene_graph(m, GraphConfig(min_points=30, min_size=0.1))
    assert g.node_ids.tolist() == [1]
    assert len(g.points) == 1 and g.edges.shape == (0, 2)


def test_object_edges_follow_size_rule():
    # radius of a 1 m cube = sqrt(3)/2 = 0.87: neighbours closer than 1.73 m link
    parts = [_box_surface((x, 0, 0.5), (1, 1, 1), n=1500, seed=k) for k, x in enumerate([0.0, 1.5, 3.5])]
    g = build_scene_graph(_map(parts, ["box", "box", "box"]))
    assert g.edges.tolist() == [[0, 1]]


def test_structural_nodes_link_by_contact():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-3, 3, (20000, 2)), rng.normal(0, 0.005, 20000)].astype(np.float32)
    wall = np.c_[rng.uniform(-3, 3, 8000), np.full(8000, 3.0), rng.uniform(0, 2.5, 8000)].astype(np.float32)
    chair = _box_surface((0, 0, 0.45), (0.5, 0.5, 0.9), n=1500)
    shelf = _box_surface((2, 2.8, 1.6), (1, 0.3, 0.4), n=1500)   # hangs on the wall
    lamp = _box_surface((-2, -2, 2.0), (0.3, 0.3, 0.3), n=500)   # floats: touches nothing
    g = build_scene_graph(_map([floor, wall, chair, shelf, lamp], ["floor", "Wall", "chair", "shelf", "lamp"]))
    assert g.structural.tolist() == [True, True, False, False, False]
    e = set(map(tuple, g.edges.tolist()))
    assert (0, 1) in e and (0, 2) in e and (1, 3) in e
    assert (0, 4) not in e and (1, 4) not in e and (0, 3) not in e and (1, 2) not in e
    assert np.all(g.edges[:, 0] < g.edges[:, 1])


def test_is_structural():
    assert is_structural("floor") and is_structural(" Ceiling ") and is_structural("walls")
    assert not is_structural("floor mat") and not is_structural("table")


def test_empty_when_nothing_qualifies():
    m = _map([_box_surface((0, 0, 0), (1, 1, 1), n=5)], ["a"])
    g = build_scene_graph(m)
    assert g.num_nodes == 0 and g.edges.shape == (0, 2) and g.centers.shape == (0, 3)


def test_synthetic_scene_graph_is_fast_and_sane(synth_scene):
    t0 = time.perf_counter()
    g = build_scene_graph(synth_scene)
    dt = time.perf_counter() - t0
    assert g.num_nodes >= 15 and g.num_edges >= g.num_nodes
    assert np.all(g.extents[:, 0] >= g.extents[:, 1])
    assert g.structural.sum() >= 5
    # structural nodes touch something; most objects get an edge
    deg = np.bincount(g.edges.ravel(), minlength=g.num_nodes)
    assert (deg[g.structural] > 0).all() and (deg > 0).mean() > 0.9
    assert dt < 2.0  # generous: a shared CI core; the benchmark number is in the CLI


@pytest.mark.parametrize("seed", range(5))
def test_object_edges_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    centers = rng.uniform(0, 6, (30, 3))
    radius = rng.uniform(0.1, 3.0, 30)          # some above max_radius: the cap applies
    objects = rng.random(30) > 0.2
    cfg = GraphConfig()
    r = np.minimum(radius, cfg.max_radius)
    obj = np.flatnonzero(objects)
    ref = [[i, j] for i in obj for j in obj
           if i < j and np.linalg.norm(centers[i] - centers[j]) < cfg.edge_factor * max(r[i], r[j])]
    assert 0 < len(ref) < len(obj) * (len(obj) - 1) // 2
    assert _object_edges(centers, radius, objects, cfg).tolist() == ref   # same pairs, same order


@pytest.mark.parametrize("seed", range(5))
def test_structural_edges_match_brute_force(seed):
    # dyadic coordinates and cell: the grid arithmetic is exact, points sit on cell borders too
    rng = np.random.default_rng(seed)
    cell = 0.25
    points = rng.integers(0, 24, (300, 3)) * 0.125
    points[:20] += (1e9, -1e9, 5e8)              # far off: no packed grid could span the gap
    node = rng.integers(0, 30, 300)
    structural = np.zeros(30, bool)
    structural[rng.choice(30, 4, replace=False)] = True
    c = np.floor((points - points.min(0)) / cell)
    near = np.abs(c[:, None] - c[None]).max(2) <= 1   # 27-cell neighbourhood, point to point
    a, b = np.nonzero(near)
    ref = sorted({(node[x], node[y]) for x, y in zip(a, b) if structural[node[x]] and node[x] != node[y]})
    assert len(ref) > 10
    assert _structural_edges(points, node, structural, cell).tolist() == [list(p) for p in ref]


def _peak_mib(fn):
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def test_stray_points_far_away_cost_nothing():
    # 40 labelled floor points 10 km away must not size any grid; nothing is near them
    rng = np.random.default_rng(1)
    floor = np.c_[rng.uniform(-3, 3, (20000, 2)), rng.normal(0, 0.005, 20000)].astype(np.float32)
    chair = _box_surface((0, 0, 0.45), (0.5, 0.5, 0.9), n=1500)
    lamp = _box_surface((-2, -2, 2.0), (0.3, 0.3, 0.3), n=500)
    stray = (rng.uniform(0, 1, (40, 3)) + (1e4, 1e4, 0.5)).astype(np.float32)
    m = _map([np.r_[floor, stray], chair, lamp], ["floor", "chair", "lamp"])
    t0 = time.perf_counter()
    g = build_scene_graph(m)
    dt = time.perf_counter() - t0
    _, peak = _peak_mib(lambda: build_scene_graph(m))
    assert dt < 1.0 and peak < 200
    assert g.edges.tolist() == build_scene_graph(_map([floor, chair, lamp], ["floor", "chair", "lamp"])).edges.tolist()


def test_many_objects_without_quadratic_memory():
    # 4000 cubes (0.2 m, r = 0.17) on an 80 x 50 grid of pitch 0.3 m: 4-neighbours link (0.3 <
    # 2 r), diagonals (0.42) do not. A dense n x n distance matrix alone would take ~1 GB.
    lattice = np.stack(np.meshgrid(*[np.array([-0.1, 0.0, 0.1])] * 3), -1).reshape(-1, 3)
    cube = np.r_[lattice, lattice]                 # 54 points >= min_points
    gx, gy = np.meshgrid(np.arange(80), np.arange(50))
    centers = np.c_[gx.ravel() * 0.3, gy.ravel() * 0.3, np.full(4000, 0.1)]
    m = _map([(cube + c).astype(np.float32) for c in centers], ["box"] * 4000)
    g, peak = _peak_mib(lambda: build_scene_graph(m))
    assert g.num_nodes == 4000 and peak < 200
    k = np.arange(4000).reshape(50, 80)
    ref = np.r_[np.c_[k[:, :-1].ravel(), k[:, 1:].ravel()], np.c_[k[:-1].ravel(), k[1:].ravel()]]
    assert g.edges.tolist() == sorted(ref.tolist())


@pytest.fixture(scope="module")
def synth_scene():
    from sgreg_core.simulation.synth import generate_scene
    return generate_scene(5)
