"""Look-alike placements (sgreg_core/pose/repeats.py): a reference that repeats the source's room
shows a rival placement as good as the estimate's, one that does not shows none; the gates for
unrepeated maps apply only where no rival comes close."""
import numpy as np
import pytest

from sgreg_core.pipeline import PipelineConfig
from sgreg_core.pose import CloudVerifier, PoseConfig, apply_T, make_T
from sgreg_core.geometry import yaw_rotation
from sgreg_core.pose.repeats import RepeatConfig, placements, rival_fitness

from test_pose_guided import room_objects

SHIFT = np.array([9.0, 0.0, 0.0])   # the twin room, beyond the first one's walls


def descriptors(rng, n):
    return rng.normal(size=(n, 16))


def twin(points):
    return np.concatenate([points, points + SHIFT])


def test_identical_rooms_show_the_twin_placement_as_a_rival():
    rng = np.random.default_rng(1)
    _, _, ctr = room_objects(rng, 10)
    desc = descriptors(rng, 10)
    T = make_T(yaw_rotation(-0.6), np.array([1.0, 4.0, 0.0]))
    ref_c, ref_d = apply_T(T, twin(ctr)), np.concatenate([desc, desc])
    src = ctr[:7] + rng.normal(0, 0.05, (7, 3))
    place = placements(T, src, desc[:7], ref_c, ref_d)
    assert place.support == 7 and place.rivals[0][1] == 7
    T_twin = make_T(T[:3, :3], T[:3, 3] + T[:3, :3] @ SHIFT)
    assert min(np.linalg.norm(T_r[:3, 3] - T_twin[:3, 3]) for T_r, _ in place.rivals) < 0.3
    # the rival's clouds fit as well as the estimate's: the reference repeats the source
    room, _, _ = room_objects(np.random.default_rng(1), 10)
    verifier = CloudVerifier(room, apply_T(T, twin(room)), 0.1, 0.1, 600, 0, 0.2, 1)
    cfg = RepeatConfig()
    own = verifier(T).footprint_fitness
    assert own > 0.8 and rival_fitness(place, T, verifier, PoseConfig(verify_voxel=0.1), cfg) > 0.8 * own


@pytest.mark.parametrize("alike", ["own descriptors", "all alike"])
def test_the_rivals_of_a_room_that_does_not_repeat_fit_its_clouds_badly(alike):
    rng = np.random.default_rng(2)
    room, _, ctr = room_objects(rng, 10)
    desc = descriptors(rng, 10) if alike == "own descriptors" else np.ones((10, 16))
    T = make_T(yaw_rotation(0.3), np.array([-2.0, 1.0, 0.0]))
    src = ctr[:7] + rng.normal(0, 0.05, (7, 3))                     # a partial view
    place = placements(T, src, desc[:7], apply_T(T, ctr), desc, RepeatConfig(top_k=10))
    assert place.support == 7 and place.rivals     # chance placements of a few objects exist
    verifier = CloudVerifier(room, apply_T(T, room), 0.1, 0.1, 600, 0, 0.2, 1)
    own = verifier(T).footprint_fitness
    assert rival_fitness(place, T, verifier, PoseConfig(verify_voxel=0.1), RepeatConfig()) < 0.6 * own


def test_non_finite_nodes_take_no_part_and_empty_graphs_give_nothing():
    rng = np.random.default_rng(3)
    _, _, ctr = room_objects(rng, 8)
    desc = descriptors(rng, 8)
    src = ctr.copy()
    src[0] = np.nan
    place = placements(np.eye(4), src, desc, ctr, desc)
    assert place.support == 7
    assert placements(np.eye(4), np.zeros((0, 3)), np.zeros((0, 16)), ctr, desc).support == 0
    assert placements(np.full((4, 4), np.nan), ctr, desc, ctr, desc).support == 0


@pytest.mark.parametrize("bad", [{"top_k": 0}, {"bound": 0.0}, {"after": ("ok",)},
                                 {"after": ("too_few_nodes",)}, {"min_confidence": 1.5},
                                 {"footprint_rim": -1}, {"max_repeat": 0.0}, {"rivals": 0},
                                 {"icp_distances": ()}, {"footprint_probe": -0.1},
                                 {"footprint_probe": float("nan")}])
def test_repeat_config_rejects_what_cannot_work(bad):
    with pytest.raises(ValueError):
        RepeatConfig(**bad)


def test_the_laxer_gates_count_the_fitness_with_the_footprint_probe():
    """The second estimate's probe is RepeatConfig's, or the first estimate's when that is
    0; its rim and confidence floor are RepeatConfig's."""
    from dataclasses import replace
    strict = PoseConfig()
    relaxed = RepeatConfig().relaxed(strict)
    assert relaxed.footprint_probe == 0.5 and relaxed.footprint_rim == 1
    assert relaxed.verdict.min_confidence == 0.8 and strict.footprint_probe == 0.0
    assert RepeatConfig(footprint_probe=0.0).relaxed(replace(strict, footprint_probe=0.3)).footprint_probe == 0.3


def test_the_pipeline_relaxes_its_gates_only_where_the_reference_does_not_repeat_the_source():
    from dataclasses import replace

    from sgreg_core.net.model import DenseMatches, NodeFeatures, NodeMatches, PointMatches
    from sgreg_core.pipeline import register_features
    from sgreg_core.pose.geometric import GeometricConfig
    from test_pose_guided import K, sample

    rng = np.random.default_rng(4)
    room, objects, ctr = room_objects(rng, 12)
    desc = descriptors(rng, 12)
    T = make_T(yaw_rotation(0.8), np.array([2.0, 1.0, 0.0]))
    pts = sample(rng, objects)
    n = len(ctr)

    class RightMatcher:
        """Right node and point matches of the first n reference nodes."""
        def match_dense(self, src, ref, timings=None):
            idx = np.arange(n)
            nodes = NodeMatches(idx, idx, np.full(n, 0.9, np.float32), src.centers, ref.centers[:n])
            pair = np.repeat(idx, K)
            p = np.tile(np.arange(K), n)
            return DenseMatches(nodes, PointMatches(src.points[pair, p], ref.points[pair, p],
                                                    np.full(pair.size, 0.5, np.float32), pair))

    def features(points, centers, d):
        return NodeFeatures(node_ids=np.arange(len(centers), dtype=np.int64), centers=centers,
                            descriptor=d, points=points, valid=np.ones(points.shape[:2], bool),
                            z=np.zeros(points.shape[:2] + (2,), np.float32))

    src = features(pts, ctr, desc)
    # a confidence model under which this pair falls between the strict and the relaxed gate
    # (the geometric pose, which finds this furnished room on its own, is left out)
    strict = PipelineConfig(repeats=RepeatConfig(enabled=False),
                            geometric=GeometricConfig(enabled=False)).with_verdict(
        confidence_weights=(-21.0, 2.5, 15.0, -0.5, -2.4, 1.4))
    on = replace(strict, repeats=RepeatConfig(min_confidence=0.5))    # on by default
    one = features(apply_T(T, pts.reshape(-1, 3)).reshape(pts.shape), apply_T(T, ctr), desc)
    two = features(apply_T(T, twin(pts.reshape(-1, 3))).reshape((2 * n,) + pts.shape[1:]),
                   apply_T(T, twin(ctr)), np.concatenate([desc, desc]))
    refused = register_features(RightMatcher(), src, one, room, apply_T(T, room), strict)
    assert not refused.success and refused.reason == "low_confidence" and not refused.unrepeated
    assert 0.5 < refused.confidence < 0.9

    reg = register_features(RightMatcher(), src, one, room, apply_T(T, room), on)
    assert reg.success and reg.unrepeated and reg.repeat < on.repeats.max_repeat, reg.repeat
    assert np.linalg.norm(reg.T[:3, 3] - T[:3, 3]) < 0.05
    assert reg.to_json()["unrepeated"] is True and "repeats" in reg.pose_timing_ms

    # the same view in the first of two identical rooms: the twin fits as well, nothing passes
    in_twins = register_features(RightMatcher(), src, two, room, apply_T(T, twin(room)), on)
    assert not in_twins.success and not in_twins.unrepeated
    assert in_twins.repeat >= on.repeats.max_repeat
    # nor does the geometric pose verify the twin room
    geo = register_features(RightMatcher(), src, two, room, apply_T(T, twin(room)),
                            replace(on, geometric=GeometricConfig()))
    assert not geo.success or np.linalg.norm(geo.T[:3, 3] - T[:3, 3]) < 0.05, (geo.reason, geo.geometric)

    # a reference that holds the floor up to two walls it never mapped: only with the probe do
    # those walls count neither for nor against the right pose under the laxer gates
    unmapped = ((room[:, 0] < 0.05) | (room[:, 1] < 0.05)) & (room[:, 2] > 0.02)
    cut = apply_T(T, room[~unmapped])
    unprobed = replace(on, repeats=replace(on.repeats, footprint_probe=0.0))
    without = register_features(RightMatcher(), src, one, room, cut, unprobed)
    assert not without.success and without.reason == "low_confidence"
    probed = register_features(RightMatcher(), src, one, room, cut, on)
    assert probed.success and probed.unrepeated and probed.footprint_fitness > without.footprint_fitness


def test_look_alikes_that_fix_no_pose_give_no_hypothesis():
    """One reference node (every source node's look-alike): two pairs onto the same point fix no
    yaw, so nothing can be said about repeats (the pipeline takes that as a repeat)."""
    rng = np.random.default_rng(5)
    _, _, ctr = room_objects(rng, 6)
    desc = descriptors(rng, 6)
    place = placements(np.eye(4), ctr, desc, ctr[:1], desc[:1])
    assert place.hypotheses == 0 and place.rivals == []


def test_far_is_measured_at_the_nodes_not_at_a_distant_origin():
    """A source frame whose origin lies 15 m from its nodes: a 6-degree turn about that origin
    moves the nodes 1.6 m, a rival; the same turn about the nodes' centroid is none."""
    from sgreg_core.pose.estimator import far_apart_many as _far

    cfg = RepeatConfig()
    centroid = np.array([15.0, 0.0, 0.5])
    R = yaw_rotation(np.radians(6.0))
    assert _far(R, np.zeros(3), np.eye(3), np.zeros(3), centroid, cfg)
    about_nodes = centroid - R @ centroid
    assert not _far(R, about_nodes, np.eye(3), np.zeros(3), centroid, cfg)


def test_a_large_graph_is_placed_from_a_sample_of_its_pairs():
    """4500 look-alike pairs would make 10 million pairs of pairs: a seeded sample is scored."""
    rng = np.random.default_rng(6)
    n = 1500
    ctr = np.c_[rng.uniform(0, 60, (n, 2)), rng.uniform(0, 2, n)]
    desc = descriptors(rng, n)
    place = placements(np.eye(4), ctr, desc, ctr, desc)
    assert place.support == n and 0 < place.hypotheses <= RepeatConfig().max_hypotheses
    again = placements(np.eye(4), ctr, desc, ctr, desc)
    assert [s for _, s in again.rivals] == [s for _, s in place.rivals]     # seeded


def test_a_repeat_the_clouds_cannot_judge_is_no_proof_of_none(monkeypatch):
    """The repeat check verifies on its own, smaller sample of the source (600 points): a source
    of mostly floor whose sample keeps too few upright points to verify, or a pose that lands
    none on the reference's footprint core, scored 0 for the estimate and 0 for every rival, and
    0 / 0 read as "no repeat": the relaxed gates took the estimate. It cannot be told (NaN)."""
    import sgreg_core.pipeline as pipeline_mod
    from sgreg_core.pose.repeats import Placements
    from sgreg_core.pose.verify import ReferenceCloud

    step = np.arange(0.0, 10.0, 0.05)
    X, Y = np.meshgrid(step, step)
    floor = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    W, Z = np.meshgrid(step, np.arange(0.0, 2.0, 0.05))
    walls = [np.c_[W.ravel(), np.zeros(W.size), Z.ravel()], np.c_[np.zeros(W.size), W.ravel(), Z.ravel()],
             np.c_[W.ravel(), np.full(W.size, 10.0), Z.ravel()], np.c_[np.full(W.size, 10.0), W.ravel(), Z.ravel()]]
    pose_cfg = PipelineConfig().pose_config()
    reference = ReferenceCloud(np.vstack([floor] + walls), pose_cfg.verify_voxel, pose_cfg.footprint_cell)
    patch = np.arange(2.0, 8.0, 0.1)
    Xs, Ys = np.meshgrid(patch, patch)
    # a floor patch and a short stretch of wall near the middle of the room
    source = np.vstack([np.c_[Xs.ravel(), Ys.ravel(), np.zeros(Xs.size)],
                        np.c_[np.repeat(np.arange(4.0, 5.0, 0.1), 10), np.full(100, 4.0),
                              np.tile(np.arange(0.2, 1.2, 0.1), 10)]])
    rival = np.eye(4)
    rival[:3, 3] = [3.0, 0.0, 0.0]
    rcfg = RepeatConfig()
    monkeypatch.setattr(pipeline_mod, "placements", lambda *a, **k: Placements(
        support=9, centroid=source.mean(0), hypotheses=1, rivals=[(rival, 9)]))
    repeat = pipeline_mod._repeat(np.eye(4), None, None, source, reference, pose_cfg, rcfg)
    assert np.isnan(repeat)
