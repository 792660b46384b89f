"""Poses that two node-center matches fix (sgreg_core/pose/pairs.py), as candidates of the
estimator (PoseConfig.pair_hypotheses) and in the coarse pipeline's second pass: three right
center matches are found when five wrong ones agree on another pose."""
from dataclasses import replace

import numpy as np
import pytest

from sgreg_core.net.model import NodeMatches
from sgreg_core.pipeline import COARSE_PAIRS_AFTER, PipelineConfig, register_features
from sgreg_core.pose import PoseConfig, apply_T, estimate_pose, make_T
from sgreg_core.geometry import yaw_rotation
from sgreg_core.pose.pairs import pair_poses, placement_support, yaw_hypotheses

from test_pose_estimator import pose_error
from test_pose_guided import features, hidden_truth, room_objects, sample


def test_yaw_hypotheses_recover_a_pose_from_two_matches_and_count_its_support():
    rng = np.random.default_rng(0)
    T = make_T(yaw_rotation(0.8), np.array([1.0, 2.0, 0.3]))
    src = rng.uniform(0, 5, (6, 3))
    R, t = yaw_hypotheses(src, apply_T(T, src), np.arange(6), 0.1, 0.5, 4000)
    assert len(R) > 0 and np.allclose(R, T[:3, :3]) and np.allclose(t, T[:3, 3])
    assert (placement_support(R, t, src, apply_T(T, src)[:, None], 0.1) == 6).all()
    # pairs within one node, or too short to fix a yaw, fix nothing
    assert len(yaw_hypotheses(src, apply_T(T, src), np.zeros(6, int), 0.1, 0.5, 4000)[0]) == 0
    assert len(yaw_hypotheses(src, apply_T(T, src), np.arange(6), 0.1, 50.0, 4000)[0]) == 0


def test_pair_poses_rank_by_support_and_keep_each_pose_once():
    *_, src, ref, T = hidden_truth(2, noise=0.0)
    poses = pair_poses(src, ref, 0.3, 3)
    assert len(poses) >= 2
    errors = [pose_error(P, T)[0] for P in poses]
    assert errors[0] > 0.3                            # the wrong five come first...
    assert sum(e < 1e-6 for e in errors) == 1         # ...and the three right pairs' pose once
    first = pair_poses(src, ref, 0.3, 3, limit=1)
    assert len(first) == 1 and np.allclose(first[0], poses[0])
    # centers 5 cm off: the right pose is still among them, the wrong one too
    *_, src_n, ref_n, _ = hidden_truth(2)
    near = [pose_error(P, T)[0] < 0.3 for P in pair_poses(src_n, ref_n, 0.3, 3)]
    assert any(near) and not all(near)
    # a pair needs a third center agreeing, and a pose is fixed only by centers far enough apart
    assert pair_poses(src_n[:2], ref_n[:2], 0.3, 3) == []
    assert pair_poses(src[:1], ref[:1], 0.3, 2) == []
    assert pair_poses(src_n[:1], ref_n[:1], 0.3, 2) == []


def test_a_noisy_consensus_takes_one_place_only():
    """Centers 10 cm off: the wrong five's pairs bring different subsets of them within the
    bound; those are one consensus, so the right pose still gets the second place."""
    *_, src, ref, T = hidden_truth(2, noise=0.1)
    poses = pair_poses(src, ref, 0.3, 3, limit=2)
    assert len(poses) == 2 and pose_error(poses[0], T)[0] > 1.0 and pose_error(poses[1], T)[0] < 0.3


def test_pair_hypotheses_let_the_clouds_pick_the_right_pose_of_three_center_matches():
    room, room_T, src, ref, T = hidden_truth(2)
    coarse = replace(PipelineConfig().coarse_pose, verify_voxel=0.1, icp=True,
                     verdict=replace(PipelineConfig().coarse_pose.verdict, min_inliers=3, min_objects=3))
    plain = estimate_pose(src, ref, src_cloud=room, ref_cloud=room_T, cfg=coarse)
    assert not plain.success and plain.reason in COARSE_PAIRS_AFTER
    assert pose_error(plain.T, T)[0] > 0.3
    paired = estimate_pose(src, ref, src_cloud=room, ref_cloud=room_T,
                           cfg=replace(coarse, pair_hypotheses=8))
    assert paired.success, paired.reason
    assert pose_error(paired.T, T)[0] < 0.1 and paired.evidence.objects == 3
    with pytest.raises(ValueError):
        PoseConfig(pair_hypotheses=-1)
    with pytest.raises(ValueError):
        PipelineConfig(coarse_pairs=-1)


class CenterMatcher:
    """Stands in for the network's coarse matching: node i matched to node i, with scores."""

    def match_coarse(self, src, ref, timings=None):
        idx = np.arange(len(src.centers))
        return NodeMatches(idx, idx, np.full(idx.size, 0.9, np.float32), src.centers, ref.centers)


def test_a_refused_coarse_estimate_is_tried_again_with_the_pairs_poses():
    """Four right node-center matches among six that agree on a wrong pose: the coarse pipeline
    refuses the wrong clique's pose, then finds the right one in its second pass."""
    rng = np.random.default_rng(4)
    room, objects, ctr = room_objects(rng, 10)
    T = make_T(yaw_rotation(-2.2), np.array([1.0, 4.0, 0.0]))
    wrong = make_T(yaw_rotation(0.9), np.array([3.0, -1.0, 0.0]))
    src_c = ctr + rng.normal(0, 0.05, ctr.shape)
    ref_c = np.concatenate([apply_T(T, ctr[:4]), apply_T(wrong, ctr[4:])])
    pts = sample(rng, objects)
    src, ref = features(pts, src_c), features(apply_T(T, pts.reshape(-1, 3)).reshape(pts.shape), ref_c)
    off = PipelineConfig(mode="coarse", coarse_pairs=0)
    plain = register_features(CenterMatcher(), src, ref, room, apply_T(T, room), off)
    assert not plain.success and plain.reason in COARSE_PAIRS_AFTER and "pairs" not in plain.pose_timing_ms
    reg = register_features(CenterMatcher(), src, ref, room, apply_T(T, room), replace(off, coarse_pairs=8))
    assert reg.success and reg.mode == "coarse" and "pairs" in reg.pose_timing_ms, reg.reason
    assert pose_error(reg.T, T)[0] < 0.1 and reg.inlier_nodes == 4
    # without clouds to rank them the pairs' poses are not tried
    blind = register_features(CenterMatcher(), src, ref, None, None, replace(off, coarse_pairs=8))
    assert "pairs" not in blind.pose_timing_ms
    # centers on one vertical line fix no yaw: GNC finds no fit, and neither would a second pass
    src_line, ref_line = src_c.copy(), ref_c.copy()
    src_line[:, :2], ref_line[:, :2] = src_c[0, :2], ref_c[0, :2]
    line = register_features(CenterMatcher(), features(pts, src_line), features(pts, ref_line), room,
                             apply_T(T, room), replace(off, coarse_pairs=8))
    assert line.reason in COARSE_PAIRS_AFTER and "pairs" not in line.pose_timing_ms, line.reason
