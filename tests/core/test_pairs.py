"""Registration pairs: disjoint samples, correct ground truth, noise, I/O, determinism."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from sgreg_core.geometry import transform_points
from sgreg_core.maps.instance_map import labelled_mask
from sgreg_core.simulation.noise import PARAPHRASES, NoiseConfig, apply_noise
from sgreg_core.simulation.pairs import (PairConfig, make_pair, node_iou, read_pair,
                                         write_pair)
from sgreg_core.simulation.synth import generate_scene


@pytest.fixture(scope="module")
def scene():
    return generate_scene(11)


@pytest.mark.parametrize("disjoint", ["band", "halves"])
def test_views_share_no_sample_and_gt_transform_aligns(scene, disjoint):
    pair = make_pair(scene, PairConfig(overlap=0.5, disjoint=disjoint), np.random.default_rng(3))
    src_in_ref = transform_points(pair.T_src_ref, pair.src.points.astype(np.float64))
    original = cKDTree(scene.points.astype(np.float64))
    d, _ = original.query(src_in_ref)
    assert d.max() < 1e-3                      # T_src_ref really maps src into the common frame
    d_ref, _ = cKDTree(pair.ref.points).query(src_in_ref)
    assert d_ref.min() > 1e-6                  # and no sample is in both views
    assert len(pair.src.points) + len(pair.ref.points) <= len(scene.points)
    yaw = np.degrees(np.arctan2(pair.T_src_ref[1, 0], pair.T_src_ref[0, 0]))
    assert np.linalg.norm(pair.T_src_ref[:2, 3]) <= 10.0 and -180 <= yaw <= 180


def test_ids_renumbered_disjoint_and_gt_pairs_consistent(scene):
    pair = make_pair(scene, PairConfig(), np.random.default_rng(4))
    assert not set(pair.src.labels) & set(pair.ref.labels)
    m = pair.matches(0.3)
    assert len(m) >= 10
    # a true match keeps its label (no paraphrase noise here)
    assert all(pair.src.labels[s] == pair.ref.labels[r] for s, r in m)
    assert set(m[:, 0]) <= set(pair.src.labels) and set(m[:, 1]) <= set(pair.ref.labels)
    assert (pair.gt_iou >= 0.1).all() and (pair.gt_iou <= 1).all()


def test_overlap_controls_shared_instances(scene):
    small = make_pair(scene, PairConfig(overlap=0.2), np.random.default_rng(5))
    large = make_pair(scene, PairConfig(overlap=0.9), np.random.default_rng(5))
    assert len(large.matches()) > len(small.matches())


def test_node_iou_hand_case():
    a = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05]])      # voxels (0,0,0), (1,0,0)
    b = np.array([[0.12, 0.02, 0.02], [0.25, 0.05, 0.05], [0.35, 0.05, 0.05]])  # (1,0,0),(2,0,0),(3,0,0)
    pairs, iou = node_iou(a, np.array([7, 7]), b, np.array([9, 9, 8]), voxel=0.1)
    assert pairs.tolist() == [[7, 9]]
    np.testing.assert_allclose(iou, [1 / 3])


def test_noise_options(scene):
    rng = np.random.default_rng(0)
    n_inst = len(scene.labels)
    over = apply_noise(scene, NoiseConfig(overseg=1.0), rng)
    assert len(over.labels) > 1.8 * n_inst
    drop = apply_noise(scene, NoiseConfig(drop=0.5), rng)
    assert 0.2 * n_inst < len(drop.labels) < 0.8 * n_inst and labelled_mask(drop).sum() < labelled_mask(scene).sum()
    part = apply_noise(scene, NoiseConfig(partial=1.0, partial_keep=(0.5, 0.5)), rng)
    assert 0.45 < labelled_mask(part).sum() / labelled_mask(scene).sum() < 0.56
    jit = apply_noise(scene, NoiseConfig(jitter=0.01), rng)
    assert 0.005 < np.std(jit.points - scene.points) < 0.015
    para = apply_noise(scene, NoiseConfig(paraphrase=1.0), rng)
    changed = [k for k in scene.labels if para.labels[k] != scene.labels[k]]
    assert changed and all(para.labels[k] in PARAPHRASES[scene.labels[k].lower()] for k in changed)
    assert len(PARAPHRASES) >= 30
    with pytest.raises(ValueError, match="unknown noise"):
        NoiseConfig.preset("jitter,nonsense")


def test_seeded_and_round_trip(scene, tmp_path):
    cfg = PairConfig(noise=NoiseConfig.preset("jitter,overseg,drop,paraphrase,partial"))
    a = make_pair(scene, cfg, np.random.default_rng(8))
    b = make_pair(scene, cfg, np.random.default_rng(8))
    np.testing.assert_array_equal(a.src.points, b.src.points)
    np.testing.assert_array_equal(a.gt_node_pairs, b.gt_node_pairs)
    write_pair(a, tmp_path / "pair_000")
    r = read_pair(tmp_path / "pair_000")
    np.testing.assert_allclose(r.T_src_ref, a.T_src_ref)
    np.testing.assert_array_equal(r.gt_node_pairs, a.gt_node_pairs)
    np.testing.assert_allclose(r.gt_iou, a.gt_iou, atol=1e-6)
    assert r.src.labels == a.src.labels and r.meta["overlap"] == 0.5
