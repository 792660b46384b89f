"""Front-end noise: confusions, merges, invented instances, tilt, per-kind streams, presets."""
import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from sgreg_core.geometry import invert_transform, transform_points
from sgreg_core.maps.scene_graph import is_structural
from sgreg_core.simulation.noise import (CONFUSIONS, INVENT_LABELS, PARAPHRASES, NoiseConfig, apply_noise,
                                         confusions_of, tilt_about, tilt_transform)
from sgreg_core.simulation.pairs import PairConfig, make_pair
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.types import InstanceMap


@pytest.fixture(scope="module")
def scene():
    return generate_scene(11)


@pytest.fixture(scope="module")
def office():
    return generate_scene(4, SynthConfig(kind="office", rooms=2))


def _noisy(imap, seed=0, **rates):
    return apply_noise(imap, NoiseConfig(**rates), np.random.default_rng(seed))


def _centers(imap):
    return {k: imap.points[imap.instance == k].mean(axis=0) for k in imap.labels}


def test_rates_zero_leave_the_map_unchanged(scene):
    # tilt moves points, so apply_noise leaves it to make_pair
    out = _noisy(scene, merge_dist=5.0, invent_radius=(1.0, 2.0), tilt=2.0)
    np.testing.assert_array_equal(out.points, scene.points)
    np.testing.assert_array_equal(out.instance, scene.instance)
    assert out.labels == scene.labels and out.scores == scene.scores


def test_confusion_table_is_wrong_but_plausible():
    assert len(CONFUSIONS) >= 30
    required = {"chair": {"sofa", "armchair", "stool"}, "table": {"desk", "counter", "coffee table"},
                "cabinet": {"shelves", "dresser", "wardrobe", "bookshelf"}, "door": {"wall", "cabinet", "wardrobe"},
                "picture": {"window", "mirror", "whiteboard", "tv"}, "bed": {"sofa"}, "monitor": {"tv", "picture"},
                "lamp": {"plant"}, "sink": {"toilet", "bathtub"}, "pillow": {"bag", "box"},
                "trash can": {"box", "bag"}, "curtain": {"window", "door"}, "sofa": {"chair", "bed"},
                "wall": {"door", "window"}, "plant": {"lamp"}, "toilet": {"sink"}, "tv": {"monitor", "picture"}}
    for label, alts in required.items():
        assert alts <= set(CONFUSIONS[label]), label
    # every name a front end may write, paraphrases included, is confused with a different class;
    # structure only as walls <-> the doors and windows in them
    openings = {"door", "window", *PARAPHRASES["door"], *PARAPHRASES["window"]}
    for label in set(CONFUSIONS) | {p for ps in PARAPHRASES.values() for p in ps} | set(PARAPHRASES):
        for alt in confusions_of(label):
            assert alt != label and alt not in PARAPHRASES.get(label, [])
            assert not is_structural(label) or alt in ("door", "window"), (label, alt)
            assert not is_structural(alt) or (alt == "wall" and label in openings), (label, alt)
    assert all(k == k.strip().lower() for k in CONFUSIONS)
    assert confusions_of("floor") == confusions_of("Ceiling") == []
    assert confusions_of(" Chair ") == CONFUSIONS["chair"]
    assert set(confusions_of("desk chair")) == set(CONFUSIONS["office chair"])  # a paraphrase of a listed one


def test_confuse_replaces_labels_by_plausible_other_classes(scene):
    out = _noisy(scene, confuse=1.0)
    np.testing.assert_array_equal(out.instance, scene.instance)
    changed = 0
    for k, label in scene.labels.items():
        if confusions_of(label):
            assert out.labels[k] in confusions_of(label) and out.labels[k] != label
            assert out.labels[k] not in PARAPHRASES.get(label.lower(), [])
            changed += 1
        else:
            assert out.labels[k] == label
    assert changed >= 15
    fractions = [np.mean([_noisy(scene, s, confuse=0.15).labels[k] != v for k, v in scene.labels.items()
                          if confusions_of(v)]) for s in range(8)]
    assert 0.05 < np.mean(fractions) < 0.3
    tiny = InstanceMap(points=np.zeros((2, 3), np.float32), instance=np.array([1, 2], np.int32),
                       labels={1: "Chair", 2: "FLOOR"})
    out = _noisy(tiny, confuse=1.0)
    assert out.labels[1] in CONFUSIONS["chair"] and out.labels[2] == "FLOOR"


@pytest.mark.parametrize("merge_dist", [1.0, 1.5])
def test_merge_joins_nearby_object_instances_into_the_larger(office, merge_dist):
    out = _noisy(office, merge=1.0, merge_dist=merge_dist)
    centers, sizes = _centers(office), {k: int((office.instance == k).sum()) for k in office.labels}
    groups = {}
    for k in office.labels:
        new = np.unique(out.instance[office.instance == k])
        assert len(new) == 1                                   # an instance is merged whole
        groups.setdefault(int(new[0]), []).append(k)
    merged = [g for g in groups.values() if len(g) > 1]
    assert len(merged) >= 5 and len(out.labels) < len(office.labels)
    for new, members in groups.items():
        assert new in members and out.labels[new] == office.labels[new]
        if len(members) > 1:
            assert not any(is_structural(office.labels[k]) for k in members)
            assert sizes[new] == max(sizes[k] for k in members)
            c = np.array([centers[k] for k in members])
            near = np.linalg.norm(c[:, None] - c[None], axis=2) <= merge_dist
            assert connected_components(near)[0] == 1             # joined by links within merge_dist
    assert np.array_equal(_noisy(office, merge=1.0, merge_dist=0.01).instance, office.instance)


def test_invent_carves_new_instances_from_structure_only(scene):
    out = _noisy(scene, invent=0.5)
    new = sorted(set(out.labels) - set(scene.labels))
    assert len(new) in (int(0.5 * len(scene.labels)), int(0.5 * len(scene.labels)) + 1)
    obj = np.isin(scene.instance, [k for k, v in scene.labels.items() if not is_structural(v)])
    np.testing.assert_array_equal(out.instance[obj], scene.instance[obj])
    for k in new:
        pts = out.instance == k
        assert out.labels[k] in INVENT_LABELS
        source = np.unique(scene.instance[pts])
        assert len(source) == 1 and (source[0] == 0 or is_structural(scene.labels[int(source[0])]))
        assert np.ptp(out.points[pts], axis=0).max() <= 2 * 0.8 + 1e-6
    objects_only = InstanceMap(points=np.random.default_rng(0).random((50, 3)).astype(np.float32),
                               instance=np.repeat([1, 2], 25).astype(np.int32), labels={1: "chair", 2: "table"})
    assert _noisy(objects_only, invent=1.0).labels == objects_only.labels


def test_kinds_draw_from_their_own_streams(scene):
    alone = _noisy(scene, 3, confuse=0.5)
    mixed = _noisy(scene, 3, confuse=0.5, merge=0.5, invent=0.5, overseg=0.3, drop=0.2)
    kept = set(scene.labels) & set(mixed.labels)
    assert len(kept) >= 10 and sum(alone.labels[k] != scene.labels[k] for k in kept) >= 3
    assert all(alone.labels[k] == mixed.labels[k] for k in kept)
    obj = np.isin(scene.instance, [k for k, v in scene.labels.items() if not is_structural(v)])
    merged = _noisy(scene, 3, merge=0.5)
    assert not np.array_equal(merged.instance, scene.instance)
    np.testing.assert_array_equal(_noisy(scene, 3, merge=0.5, invent=1.0, confuse=0.5).instance[obj],
                                  merged.instance[obj])
    np.testing.assert_array_equal(_noisy(scene, 3, jitter=0.01).points,
                                  _noisy(scene, 3, jitter=0.01, merge=0.5, overseg=0.5, confuse=0.5).points)


def test_tilt_transform():
    rng = np.random.default_rng(0)
    angles = []
    for tilt in (2.0, 0.3):
        for _ in range(50):
            T = tilt_transform(NoiseConfig(tilt=tilt), rng)
            rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
            assert abs(rotvec[2]) < 1e-12 and np.allclose(T[:3, 3], 0)     # a horizontal axis
            angles.append(np.degrees(np.linalg.norm(rotvec)))
    assert 0.5 <= min(angles[:50]) and max(angles[:50]) <= 2.0 and max(angles[:50]) > 1.5
    assert max(angles[50:]) <= 0.3 and min(angles[50:]) < 0.1
    np.testing.assert_array_equal(tilt_transform(NoiseConfig(), rng), np.eye(4))
    c = np.array([1.0, -2.0, 0.5])
    T = tilt_about(c, tilt_transform(NoiseConfig(tilt=2.0), rng))
    np.testing.assert_allclose(transform_points(T, c[None]), c[None], atol=1e-12)


@pytest.mark.parametrize("tilt", [0.0, 2.0])
def test_pair_ground_truth_with_tilt(scene, tilt):
    pair = make_pair(scene, PairConfig(noise=NoiseConfig(tilt=tilt)), np.random.default_rng(6))
    upright = make_pair(scene, PairConfig(), np.random.default_rng(6))
    # tilt comes after the ground-truth node pairs and draws from its own stream
    np.testing.assert_array_equal(pair.gt_node_pairs, upright.gt_node_pairs)
    for view in ("src", "ref"):
        deg = pair.meta[f"{view}_tilt_deg"]
        assert (0.5 <= deg <= 2.0) if tilt else deg == 0
        assert np.degrees(np.arccos(np.array(pair.meta[f"{view}_tilt"])[2, 2])) == pytest.approx(deg)
    moved = transform_points(pair.T_src_ref, pair.src.points.astype(np.float64))
    # the reference frame is the common frame tilted: undoing it lands on the scene's own samples
    common = transform_points(invert_transform(np.array(pair.meta["ref_tilt"])), moved)
    assert cKDTree(scene.points).query(common)[0].max() < 1e-3

    def surface_gaps(p, T):
        """Per source point of a matched instance, its distance to the matched reference instance."""
        src = transform_points(T, p.src.points.astype(np.float64))
        return np.concatenate([cKDTree(p.ref.points[p.ref.instance == r]).query(src[p.src.instance == s])[0]
                               for s, r in p.matches(0.3)])

    # matched instances overlap in part only; the overlapping part lies on the reference's surfaces,
    # exactly as well as without tilt
    gaps = surface_gaps(pair, pair.T_src_ref)
    assert len(pair.matches(0.3)) >= 10 and np.quantile(gaps, 0.25) < 0.025 and (gaps < 0.03).mean() > 0.4
    np.testing.assert_allclose(gaps, surface_gaps(upright, upright.T_src_ref), atol=1e-4)
    if tilt:  # the 4-DoF part alone misses the surfaces
        A = invert_transform(np.array(pair.meta["ref_tilt"])) @ pair.T_src_ref @ np.array(pair.meta["src_tilt"])
        assert (surface_gaps(pair, A) < 0.03).mean() < 0.8 * (gaps < 0.03).mean()


def test_preset_parsing():
    assert NoiseConfig.preset("") == NoiseConfig()
    cfg = NoiseConfig.preset("confuse,merge=0.2,tilt=1.5,jitter")
    assert (cfg.confuse, cfg.merge, cfg.tilt, cfg.tilt_min, cfg.jitter) == (0.15, 0.2, 1.5, 0.5, 0.01)
    assert cfg.invent == cfg.overseg == cfg.drop == cfg.paraphrase == cfg.partial == 0
    assert NoiseConfig.preset(["invent", " tilt "]) == NoiseConfig(invent=0.1, tilt=2.0)
    front = NoiseConfig.preset(NoiseConfig.FRONTEND)
    assert set(NoiseConfig.FRONTEND.split(",")) == set(NoiseConfig.PRESETS)
    assert all(getattr(front, k) == v > 0 for k, v in NoiseConfig.PRESETS.items())
    old = NoiseConfig.preset("jitter,overseg,drop,paraphrase,partial")
    assert (old.jitter, old.overseg, old.drop, old.paraphrase, old.partial) == (0.01, 0.1, 0.1, 0.3, 0.2)
    with pytest.raises(ValueError, match="unknown noise option 'merges'.*'confuse'.*'tilt'"):
        NoiseConfig.preset("confuse,merges")
    with pytest.raises(ValueError, match="not a number"):
        NoiseConfig.preset("merge=lots")
    with pytest.raises(ValueError, match="out of range"):
        NoiseConfig.preset("drop=1.5")
    with pytest.raises(ValueError, match="tilt: rate 1000.0 out of range"):     # degrees, <= 90
        NoiseConfig.preset("tilt=1000")
    assert NoiseConfig.preset("invent=2").invent == 2.0          # a count per instance, not a probability
