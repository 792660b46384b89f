"""SGRegModel: encode/match API, invariance, determinism, weights I/O, a tiny overfit."""
import json

import numpy as np
import pytest
import torch

from sgreg_core.geometry import yaw_transform
from sgreg_core.net import ModelConfig, SGRegModel, load_model, save_model, weights_id
from sgreg_core.net.losses import LossConfig, pair_losses
from sgreg_core.net.testing import hashed_text_encoder, moved_graph, toy_graph
from sgreg_core.types import SceneGraph


@pytest.fixture(scope="module")
def text():
    return hashed_text_encoder()


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """These graphs are tiny: one thread is faster, and the CI machine has few cores."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _model(text, **overrides):
    torch.manual_seed(0)
    return SGRegModel(ModelConfig.from_dict(overrides), text_encoder=text).eval()


def test_encode_shapes_and_dtypes(text):
    model = _model(text)
    graph = toy_graph(np.random.default_rng(0), n=15)
    cfg = model.cfg
    coarse = model.encode(graph, dense=False)
    assert coarse.descriptor.shape == (15, cfg.match.d_match) and coarse.descriptor.dtype == np.float32
    assert coarse.centers.shape == (15, 3) and not coarse.is_dense
    dense = model.encode(graph)
    k = cfg.shape.points_per_node
    assert dense.points.shape == (15, k, 3) and dense.z.shape == (15, k, cfg.shape.d_z)
    assert dense.valid.sum(1).tolist() == [min(len(p), k) for p in graph.points]
    assert np.array_equal(coarse.descriptor, dense.descriptor)
    assert np.array_equal(dense.node_ids, graph.node_ids)


def test_encode_is_deterministic_and_4dof_invariant(text):
    model = _model(text)
    rng = np.random.default_rng(1)
    graph = toy_graph(rng, n=20)
    a, b = model.encode(graph), model.encode(graph)
    assert np.array_equal(a.descriptor, b.descriptor) and np.array_equal(a.z, b.z)
    T = yaw_transform(rng.uniform(-np.pi, np.pi), rng.uniform(-10, 10, 3))
    c = model.encode(moved_graph(graph, T, rng, jitter=0.0))
    np.testing.assert_allclose(a.descriptor, c.descriptor, atol=1e-4)
    np.testing.assert_allclose(a.z, c.z, atol=1e-4)
    assert np.array_equal(a.valid, c.valid)
    np.testing.assert_allclose(a.points[a.valid] @ T[:3, :3].T + T[:3, 3], c.points[c.valid], atol=1e-4)


def test_encode_does_not_depend_on_the_node_order(text):
    """A graph that lists its nodes in another order (one not built by build_scene_graph) gives
    each node the same features."""
    model = _model(text)
    graph = toy_graph(np.random.default_rng(5), n=30, edge_radius=4.0)
    assert np.bincount(graph.edges.ravel()).max() >= 7  # anchors with more pairs than triplets
    perm = np.random.default_rng(6).permutation(30)
    a, b = model.encode(graph), model.encode(graph.reordered(perm))
    np.testing.assert_allclose(a.descriptor[perm], b.descriptor, atol=1e-5)
    np.testing.assert_allclose(a.z[perm], b.z, atol=1e-5)
    assert np.array_equal(a.points[perm], b.points) and np.array_equal(a.node_ids[perm], b.node_ids)


def test_point_features_from_a_dense_message_equal_encode(text):
    """A peer recomputes Z from points, centers and descriptors: same as the sender's."""
    model = _model(text)
    feats = model.encode(toy_graph(np.random.default_rng(7), n=12))
    z = model.point_features(feats.points.astype(np.float16), feats.valid,
                             feats.centers, feats.descriptor.astype(np.float16))
    np.testing.assert_allclose(z, feats.z, atol=5e-2)
    np.testing.assert_allclose(model.point_features(feats.points, feats.valid, feats.centers, feats.descriptor),
                               feats.z, atol=1e-5)


def test_encode_requires_eval_mode(text):
    model = _model(text).train()
    with pytest.raises(RuntimeError, match="eval"):
        model.encode(toy_graph(np.random.default_rng(0), n=5))


@pytest.mark.parametrize("overrides", [
    {"fusion": "early"}, {"fusion": "none"}, {"gnn": {"use_triplets": False}},
])
def test_ablation_variants_run(text, overrides):
    # untrained, no match would pass the shipped thresholds: the point matcher would not run
    model = _model(text, **overrides, match={"node_threshold": 1e-6, "point_threshold": 1e-6})
    graph = toy_graph(np.random.default_rng(2), n=12)
    feats = model.encode(graph)
    assert feats.descriptor.shape == (12, model.cfg.match.d_match)
    dense = model.match_dense(feats, feats)
    assert len(dense.nodes) > 0 and len(dense.points) > 0
    assert np.isfinite(dense.points.src_xyz).all() and dense.points.node_match.max() < len(dense.nodes)


def test_empty_and_tiny_graphs(text):
    model = _model(text)
    empty = SceneGraph(node_ids=np.zeros(0, np.int64), labels=[], scores=np.zeros(0, np.float32),
                       centers=np.zeros((0, 3), np.float32), extents=np.zeros((0, 3), np.float32),
                       points=[], edges=np.zeros((0, 2), np.int64), structural=np.zeros(0, bool))
    e = model.encode(empty)
    assert e.descriptor.shape == (0, model.cfg.match.d_match)
    g = model.encode(toy_graph(np.random.default_rng(3), n=1))
    assert np.isfinite(g.descriptor).all()
    dm = model.match_dense(e, g)
    assert len(dm.nodes) == 0 and len(dm.points) == 0


def test_weights_id_stable_and_sensitive(text):
    model = _model(text)
    wid = weights_id(model.state_dict())
    assert len(wid) == 12 and int(wid, 16) >= 0
    assert weights_id(_model(text).state_dict()) == wid == model.weights_id
    with torch.no_grad():
        model.point_matcher.dustbin += 1e-3
    assert model.weights_id != wid


def test_save_load_round_trip(tmp_path, text):
    model = _model(text, shape={"d_z": 8}, fusion="early")
    path = tmp_path / "w" / "model.safetensors"
    wid = save_model(model, path, meta={"note": "test"})
    info = json.loads(path.with_suffix(".json").read_text())
    assert info["weights_id"] == wid and info["note"] == "test"
    loaded = load_model(path, text_encoder=text)
    assert loaded.cfg == model.cfg and loaded.weights_id == wid and not loaded.training
    graph = toy_graph(np.random.default_rng(4), n=10)
    assert np.array_equal(model.encode(graph).z, loaded.encode(graph).z)
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path / "missing.safetensors")
    # the .json of another run beside these weights: refused, not loaded under its name
    other = _model(text, shape={"d_z": 8}, fusion="early")
    with torch.no_grad():
        other.point_matcher.dustbin += 1.0
    other_path = tmp_path / "other" / "model.safetensors"
    save_model(other, other_path)
    path.with_suffix(".json").write_text(other_path.with_suffix(".json").read_text())
    with pytest.raises(ValueError, match="come from different training runs"):
        load_model(path, text_encoder=text)


def test_config_round_trip_and_rejects_unknown_keys():
    cfg = ModelConfig.from_dict({"gnn": {"layers": 1, "dist_periods": [1.0, 5.0]}, "fusion": "none"})
    assert cfg.gnn.dist_periods == (1.0, 5.0)
    assert ModelConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ValueError, match="unknown"):
        ModelConfig.from_dict({"gnn": {"layer": 1}})
    with pytest.raises(ValueError, match="fusion"):
        ModelConfig(fusion="middle")


def test_float16_features_match_like_float32():
    """What a dense message carries in float16 matches as the float32 features do (the shipped
    model: an untrained one matches nothing, and the comparison would be of two empty sets)."""
    model = load_model()
    feats = model.encode(toy_graph(np.random.default_rng(5), n=10))
    half = type(feats)(node_ids=feats.node_ids, centers=feats.centers.astype(np.float16),
                       descriptor=feats.descriptor.astype(np.float16), points=feats.points.astype(np.float16),
                       valid=feats.valid, z=feats.z.astype(np.float16))
    a, b = model.match_dense(feats, feats), model.match_dense(half, half)
    assert len(a.nodes) > 0 and len(a.points) > 0
    assert np.array_equal(a.nodes.src_idx, b.nodes.src_idx) and np.array_equal(a.nodes.ref_idx, b.nodes.ref_idx)
    assert np.array_equal(a.points.node_match, b.points.node_match)
    np.testing.assert_allclose(a.points.src_xyz, b.points.src_xyz, atol=0.01)
    np.testing.assert_allclose(a.points.ref_xyz, b.points.ref_xyz, atol=0.01)


def _toy_pair(seed):
    rng = np.random.default_rng(seed)
    ref = toy_graph(rng, n=16)
    T = yaw_transform(rng.uniform(-np.pi, np.pi), rng.uniform(-5, 5, 3))
    src = moved_graph(ref, np.linalg.inv(T), rng)  # T maps src into ref
    return src, ref, T


def test_overfit_one_pair(text):
    """The losses drop on one pair and the trained model then matches its nodes."""
    torch.manual_seed(0)
    model = SGRegModel(ModelConfig(), text_encoder=text).train()
    src, ref, T = _toy_pair(6)
    gt = torch.stack([torch.arange(16), torch.arange(16)], 1)
    T_t = torch.as_tensor(T, dtype=torch.float32)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    cfg = LossConfig(pos_radius=0.1, neg_radius=0.2)
    history = []
    for step in range(40):
        rng = np.random.default_rng(step)  # a new point sample every step
        losses = pair_losses(model, model.prepare(src, rng=rng), model.prepare(ref, rng=rng),
                             T_t, gt, cfg)
        opt.zero_grad()
        losses["total"].backward()
        opt.step()
        history.append({k: v.item() for k, v in losses.items()})
    first, last = history[0], np.mean([h["total"] for h in history[-5:]])
    assert last < 0.5 * first["total"], (first, history[-1])
    assert history[-1]["gnn"] < 0.5 * first["gnn"] and history[-1]["ot"] < first["ot"]
    model.eval()
    nodes = model.match_coarse(model.encode(src), model.encode(ref))
    correct = (nodes.src_idx == nodes.ref_idx).sum()
    assert correct >= 12 and correct >= 0.8 * len(nodes)


def test_shipped_weights_load_with_their_recorded_id(text):
    from sgreg_core.net.model import DEFAULT_WEIGHTS

    info = json.loads(DEFAULT_WEIGHTS.with_suffix(".json").read_text())
    model = load_model(text_encoder=text)
    assert model.weights_id == info["weights_id"]
    assert model.cfg == ModelConfig.from_dict(info["config"])


def test_damaged_weights_are_one_clear_error(tmp_path):
    import shutil

    from sgreg_core.net.model import DEFAULT_WEIGHTS

    cut = tmp_path / "sgreg.safetensors"
    cut.write_bytes(DEFAULT_WEIGHTS.read_bytes()[:1000])
    shutil.copy(DEFAULT_WEIGHTS.with_suffix(".json"), cut.with_suffix(".json"))
    with pytest.raises(ValueError, match="cannot be loaded"):
        load_model(cut)
    shutil.copy(DEFAULT_WEIGHTS, cut)
    cut.with_suffix(".json").write_text("{not json")
    with pytest.raises(ValueError, match=r"sgreg.safetensors \(with sgreg.json\) cannot be loaded"):
        load_model(cut)


def test_match_thresholds_of_zero_keep_every_mutual_top_k_and_bad_ones_are_refused(text):
    """0 is no bound (it raised a math domain error); a threshold of 1 or more, or a top-k of 0,
    would match nothing: refused when the config is made (e.g. from a weights' .json)."""
    model = _model(text, match={"node_threshold": 0.0, "point_threshold": 0.0})
    feats = model.encode(toy_graph(np.random.default_rng(2), n=12))
    dense = model.match_dense(feats, feats)
    assert len(dense.nodes) >= 12 and len(dense.points) > 0
    for bad in ({"node_threshold": -0.1}, {"point_threshold": 1.0}, {"node_topk": 0}, {"d_match": 0}):
        with pytest.raises(ValueError, match="match: "):
            ModelConfig.from_dict({"match": bad})
