"""Guided point matching (sgreg_core/pose/guided.py) and its place in the pipeline: when the
learned point matches are wrong but the node matches and their centers are right, the dense
estimate is recovered, and nothing is verified when the clouds disagree."""
from dataclasses import replace

import numpy as np
import pytest

from sgreg_core.net.model import DenseMatches, NodeFeatures, NodeMatches, PointMatches
from sgreg_core.pipeline import PipelineConfig, register_features
from sgreg_core.geometry import yaw_rotation
from sgreg_core.pose import CloudVerifier, PoseConfig, ReferenceCloud, apply_T, make_T
from sgreg_core.pose.geometric import GeometricConfig
from sgreg_core.pose.guided import GuidedConfig, center_poses, guided_matches

from test_pose_estimator import box_room, pose_error

K = 48   # sampled points per node


def room_objects(rng, n=8):
    """A box room with n objects; returns (all points, (n, K, 3) object samples, centers)."""
    ext = rng.uniform([0.4, 0.4, 0.5], [1.2, 1.0, 1.1], (n, 3))
    ctr = np.c_[rng.uniform(1.0, [7.0, 5.0], (n, 2)), ext[:, 2] / 2]
    faces = rng.uniform(-0.5, 0.5, (n, 400, 3))
    ax = rng.integers(0, 3, (n, 400))
    np.put_along_axis(faces, ax[..., None], np.sign(np.take_along_axis(faces, ax[..., None], -1)) * 0.5, -1)
    objects = ctr[:, None] + faces * ext[:, None]
    room = np.concatenate([box_room(rng, n_objects=0), objects.reshape(-1, 3)])
    return room, objects, ctr


def sample(rng, objects):
    """K points of each object, a fresh draw (two views share no point sample)."""
    pick = np.stack([rng.choice(objects.shape[1], K, replace=False) for _ in objects])
    return np.take_along_axis(objects, pick[..., None], 1)


def test_guided_matches_pair_points_of_the_same_object_at_the_right_pose_only():
    rng = np.random.default_rng(0)
    _, objects, _ = room_objects(rng, 4)
    T = make_T(yaw_rotation(0.7), np.array([2.0, -1.0, 0.1]))
    src = sample(rng, objects)
    ref = apply_T(T, sample(rng, objects).reshape(-1, 3)).reshape(4, K, 3)
    sv, rv = np.ones((4, K), bool), np.ones((4, K), bool)
    rv[:, K // 2:] = False   # padding is never paired
    k, s, r, d = guided_matches(T, src, sv, ref, rv, 0.1)
    assert len(k) > K and set(k.tolist()) == {0, 1, 2, 3}
    assert (d <= 0.1).all() and np.allclose(np.linalg.norm(apply_T(T, s) - r, axis=1), d)
    assert np.isin(r.round(6), ref[:, : K // 2].reshape(-1, 3).round(6)).all(1).all()
    shifted = make_T(T[:3, :3], T[:3, 3] + np.array([1.5, 0, 0]))
    assert len(guided_matches(shifted, src, sv, ref, rv, 0.1)[0]) == 0
    # a non-finite point marked valid is skipped, and its node's other points still pair
    ref[0, 0] = np.nan
    k_nan = guided_matches(T, src, sv, ref, rv, 0.1)[0]
    assert (k_nan == 0).sum() >= (k == 0).sum() - 3 > 0
    sv[:] = False
    assert len(guided_matches(T, src, sv, ref, rv, 0.1)[0]) == 0


def test_center_poses_bring_decimetre_centers_onto_the_clouds():
    rng = np.random.default_rng(1)
    room, _, ctr = room_objects(rng)
    T = make_T(yaw_rotation(-2.0), np.array([-3.0, 4.0, 0.0]))
    src_c = ctr + rng.normal(0, 0.15, ctr.shape)            # centers of partly seen objects
    ref_c = apply_T(T, ctr + rng.normal(0, 0.15, ctr.shape))
    ref_c[5:] = apply_T(T, ctr[rng.permutation(3)])           # three wrong node matches
    pose = PoseConfig(verify_voxel=0.1)
    verifier = CloudVerifier(room, apply_T(T, room), 0.1, 0.1, 1500, 0, 0.2, 0)
    poses = center_poses(src_c, ref_c, np.ones(len(ctr)), verifier, pose, GuidedConfig())
    assert 1 <= len(poses) <= 2
    dt, dr = pose_error(poses[0][0], T)
    assert dt < 0.05 and dr < 1.0
    # a non-finite center is dropped, not fatal; fewer than three left: nothing to hypothesise
    src_c[0] = np.nan
    assert pose_error(center_poses(src_c, ref_c, np.ones(len(ctr)), verifier, pose,
                                   GuidedConfig())[0][0], T)[0] < 0.05
    assert center_poses(src_c[:3], ref_c[:3], np.ones(3), verifier, pose, GuidedConfig()) == []


def hidden_truth(seed, noise=0.05):
    """Room clouds in both frames and 12 center matches: 3 right (noise m off), 5 that agree
    on a wrong pose, 4 at random: (room, room seen from the reference, src, ref, T)."""
    rng = np.random.default_rng(seed)
    room, _, ctr = room_objects(rng)
    T = make_T(yaw_rotation(1.1), np.array([2.0, -3.0, 0.0]))
    wrong = make_T(yaw_rotation(-0.4), np.array([-1.0, 2.5, 0.0]))
    src = np.concatenate([ctr, rng.uniform(0, 6, (4, 3))]) + rng.normal(0, noise, (12, 3))
    ref = np.concatenate([apply_T(T, ctr[:3]), apply_T(wrong, ctr[3:]), rng.uniform(0, 6, (4, 3))])
    return room, apply_T(T, room), src, ref, T


def test_center_poses_find_three_right_center_matches_that_a_bigger_wrong_clique_hides():
    room, room_T, src_c, ref_c, T = hidden_truth(2)
    pose = PoseConfig(verify_voxel=0.1)
    verifier = CloudVerifier(room, room_T, 0.1, 0.1, 1500, 0, 0.2, 0)
    w = np.ones(len(src_c))
    # the largest clique is the wrong one: without the pairs' poses the right one is missed
    off = center_poses(src_c, ref_c, w, verifier, pose, GuidedConfig(pair_poses=0))
    assert all(pose_error(P, T)[0] > 0.3 for P, _ in off)
    best = center_poses(src_c, ref_c, w, verifier, pose, GuidedConfig())[0][0]
    assert pose_error(best, T)[0] < 0.05
    # ranked on the clouds are only the best supported pair poses: the wrong consensus alone
    short = center_poses(src_c, ref_c, w, verifier, pose, GuidedConfig(pair_poses=1, pair_candidates=1))
    assert all(pose_error(P, T)[0] > 0.3 for P, _ in short)
    with pytest.raises(ValueError):
        GuidedConfig(min_pair_support=1)
    with pytest.raises(ValueError):
        GuidedConfig(pair_poses=3, pair_candidates=2)


class ScriptedMatcher:
    """Stands in for the network's matching only: right node matches (their centers), and
    point matches that are all wrong, as under a front end's merged and cut instances."""

    def __init__(self, rng, n):
        self.rng, self.n = rng, n

    def match_dense(self, src, ref, timings=None):
        idx = np.arange(self.n)
        nodes = NodeMatches(idx, idx, np.full(self.n, 0.9, np.float32), src.centers, ref.centers)
        pair = np.repeat(idx, 10)
        p_src, p_ref = self.rng.integers(0, K, (2, pair.size))
        other = (pair + 1 + self.rng.integers(0, self.n - 1, pair.size)) % self.n   # wrong object
        points = PointMatches(src.points[pair, p_src], ref.points[other, p_ref],
                              np.full(pair.size, 0.5, np.float32), pair)
        return DenseMatches(nodes, points)


def features(points, centers):
    n = len(centers)
    return NodeFeatures(node_ids=np.arange(n, dtype=np.int64) + 10, centers=centers.astype(np.float32),
                        descriptor=np.zeros((n, 4), np.float32), points=points.astype(np.float32),
                        valid=np.ones((n, K), bool), z=np.zeros((n, K, 2), np.float32))


def right_nodes_wrong_points():
    """A room seen twice, its nodes' centers decimetres off, and the pose between the views:
    (room, node centers, T, source features, reference features)."""
    rng = np.random.default_rng(2)
    room, objects, ctr = room_objects(rng)
    T = make_T(yaw_rotation(2.5), np.array([5.0, 1.0, 0.0]))
    src = features(sample(rng, objects), ctr + rng.normal(0, 0.15, ctr.shape))
    ref_pts = apply_T(T, sample(rng, objects).reshape(-1, 3)).reshape(objects.shape[0], K, 3)
    ref = features(ref_pts, apply_T(T, ctr + rng.normal(0, 0.15, ctr.shape)))
    return room, ctr, T, src, ref


def test_a_pair_with_only_wrong_point_matches_is_registered_by_guided_matching():
    room, ctr, T, src, ref = right_nodes_wrong_points()
    ref_room = apply_T(T, room)
    # without guided matching (and the geometric pose, which would find this room too) it fails
    off = replace(PipelineConfig(), guided=GuidedConfig(enabled=False),
                  geometric=GeometricConfig(enabled=False))
    plain = register_features(ScriptedMatcher(np.random.default_rng(3), len(ctr)), src, ref, room,
                              ref_room, off)
    assert not plain.success and not plain.guided
    on = PipelineConfig()    # guided matching is on by default
    reg = register_features(ScriptedMatcher(np.random.default_rng(3), len(ctr)), src, ref, room,
                            ref_room, on)
    assert reg.success and reg.guided and reg.mode == "dense"
    dt, dr = pose_error(reg.T, T)
    assert dt < 0.05 and dr < 1.0
    assert reg.inlier_nodes >= GuidedConfig().min_objects and reg.to_json()["guided"] is True
    assert "guided" in reg.pose_timing_ms and len(reg.inlier_mask) == len(reg.corr)
    # pairs made at the pose are no evidence for a later estimate: a runtime keeps none of them
    assert 0 < reg.guided_pairs < len(reg.corr)
    assert len(reg.inlier_corr()) == reg.inlier_mask[: len(reg.corr) - reg.guided_pairs].sum()
    # a prebuilt reference (what the nodes pass) gives the same estimate
    prebuilt = ReferenceCloud(ref_room, on.pose.verify_voxel, on.pose.footprint_cell)
    again = register_features(ScriptedMatcher(np.random.default_rng(3), len(ctr)), src, ref, room,
                              prebuilt, on)
    assert again.guided and np.allclose(again.T, reg.T)
    # the same matches against a room whose surfaces are elsewhere: the guided pass runs, and
    # its estimate is refused
    other = apply_T(T, box_room(np.random.default_rng(9), size=np.array([5.0, 4.0, 2.5])))
    bad = register_features(ScriptedMatcher(np.random.default_rng(3), len(ctr)), src, ref, room,
                            other, on)
    assert not bad.success and not bad.guided and "guided" in bad.pose_timing_ms


def test_only_the_guided_estimate_waives_ties_with_competitors_the_clouds_refute(monkeypatch):
    """The learned estimate refuses every near-tie; the guided one only those whose competitor
    reaches GuidedConfig.competitor_min_fitness (the wiring of the rule, pose/verdict.py)."""
    import sgreg_core.pipeline as pipeline
    room, ctr, T, src, ref = right_nodes_wrong_points()
    seen, estimate = [], pipeline.estimate_pose

    def recording(*args, **kwargs):
        seen.append((args[5] if len(args) > 5 else kwargs["cfg"]).verdict)
        return estimate(*args, **kwargs)

    monkeypatch.setattr(pipeline, "estimate_pose", recording)
    cfg = replace(PipelineConfig(), guided=GuidedConfig(competitor_min_fitness=0.7))
    reg = register_features(ScriptedMatcher(np.random.default_rng(3), len(ctr)), src, ref, room,
                            apply_T(T, room), cfg)
    assert reg.guided and len(seen) == 2
    assert seen[0].competitor_min_fitness == 0.0 and seen[1].competitor_min_fitness == 0.7
    with pytest.raises(ValueError):
        GuidedConfig(competitor_min_fitness=1.5)


def test_an_estimate_that_passes_is_left_alone():
    rng = np.random.default_rng(6)
    room, objects, ctr = room_objects(rng)
    T = make_T(yaw_rotation(0.4), np.array([0.5, -2.0, 0.0]))
    pts = sample(rng, objects)
    src = features(pts, ctr)
    ref = features(apply_T(T, pts.reshape(-1, 3)).reshape(pts.shape), apply_T(T, ctr))

    class RightMatcher(ScriptedMatcher):
        def match_dense(self, src, ref, timings=None):
            dm = super().match_dense(src, ref)
            pair = np.repeat(np.arange(self.n), K)
            p = np.tile(np.arange(K), self.n)
            dm.points = PointMatches(src.points[pair, p], ref.points[pair, p],
                                     np.full(pair.size, 0.5, np.float32), pair)
            return dm

    reg = register_features(RightMatcher(rng, len(ctr)), src, ref, room, apply_T(T, room),
                            PipelineConfig())
    assert reg.success and not reg.guided and reg.guided_pairs == 0
    assert "guided" not in reg.pose_timing_ms and len(reg.corr) == len(ctr) * K


def test_guided_matching_answers_only_the_reasons_it_is_given_and_needs_its_objects():
    rng = np.random.default_rng(4)
    room, objects, ctr = room_objects(rng)
    T = make_T(yaw_rotation(-1.0), np.array([1.0, 3.0, 0.0]))
    src = features(sample(rng, objects), ctr + rng.normal(0, 0.15, ctr.shape))
    ref_pts = apply_T(T, sample(rng, objects).reshape(-1, 3)).reshape(objects.shape[0], K, 3)
    ref = features(ref_pts, apply_T(T, ctr + rng.normal(0, 0.15, ctr.shape)))

    def run(**guided):
        cfg = replace(PipelineConfig(), guided=GuidedConfig(enabled=True, **guided),
                      geometric=GeometricConfig(enabled=False))
        return register_features(ScriptedMatcher(np.random.default_rng(5), len(ctr)), src, ref,
                                 room, apply_T(T, room), cfg)

    first = run(after=())     # guided matching may answer nothing: the first verdict stands
    assert not first.success and not first.guided
    assert run().success
    assert not run(after=tuple(r for r in GuidedConfig().after if r != first.reason)).guided
    too_many = run(min_objects=len(ctr) + 1)
    assert not too_many.success and not too_many.guided


@pytest.mark.parametrize("bad", [{"after": ("ok",)}, {"after": ("no_such_reason",)},
                                 {"radius": 0.0}, {"poses": 0}, {"icp_distances": ()},
                                 {"clique_deltas": (0.2, -0.1)}])
def test_guided_config_rejects_what_cannot_work(bad):
    with pytest.raises(ValueError, match="guided"):
        GuidedConfig(**bad)
