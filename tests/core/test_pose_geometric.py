"""The geometric pose (sgreg_core/pose/geometric.py) and its place in the pipeline: when no node
match is right (a front end confused or merged every shared object) the dense estimate is
recovered from the clouds' geometry; nothing is verified against another room, a near-tie is
refused, and the gates are the geometric ones."""
from dataclasses import replace

import numpy as np
import pytest

from sgreg_core.net.model import DenseMatches, NodeMatches, PointMatches
from sgreg_core.pipeline import PipelineConfig, register_features
from sgreg_core.pose import CloudVerifier, ReferenceCloud, apply_T, make_T
from sgreg_core.geometry import yaw_rotation
from sgreg_core.pose.geometric import (GeometricConfig, geometric_confidence, geometric_hypothesis,
                                       judge_geometric)
from sgreg_core.pose.verdict import Evidence, VerdictConfig

from test_pose_estimator import ROOM, box_room, pose_error
from test_pose_guided import K, features, room_objects, sample


class WrongMatcher:
    """Stands in for the network's matching only: every node match pairs different objects,
    and so does every point match, as when a front end garbled every shared object."""

    def __init__(self, rng, n):
        self.rng, self.n = rng, n

    def match_dense(self, src, ref, timings=None):
        idx = np.arange(self.n)
        other = self.rng.permutation(np.roll(idx, 1))
        nodes = NodeMatches(idx, other, np.full(self.n, 0.9, np.float32), src.centers,
                            ref.centers[other])
        pair = np.repeat(idx, 10)
        p_src, p_ref = self.rng.integers(0, K, (2, pair.size))
        points = PointMatches(src.points[pair, p_src], ref.points[other[pair], p_ref],
                              np.full(pair.size, 0.5, np.float32), pair)
        return DenseMatches(nodes, points)


def garbled_pair(seed=2):
    """A furnished room seen from two frames, with node features whose matches will all be
    wrong: (source room cloud, reference room cloud, T, source features, reference features)."""
    rng = np.random.default_rng(seed)
    room, objects, ctr = room_objects(rng)
    T = make_T(yaw_rotation(2.5), np.array([5.0, 1.0, 0.0]))
    src = features(sample(rng, objects), ctr)
    ref_pts = apply_T(T, sample(rng, objects).reshape(-1, 3)).reshape(objects.shape[0], K, 3)
    return room, apply_T(T, room), T, src, features(ref_pts, apply_T(T, ctr))


def test_the_solver_finds_the_pose_of_a_furnished_room_and_none_of_too_few_points():
    room, ref_room, T, _, _ = garbled_pair()
    est = geometric_hypothesis(room, ref_room, GeometricConfig())
    assert est is not None
    dt, dr = pose_error(est, T)
    assert dt < 0.05 and dr < 1.0
    assert geometric_hypothesis(room[:10], ref_room, GeometricConfig()) is None
    bad = room.copy()
    bad[:] = np.nan
    assert geometric_hypothesis(bad, ref_room, GeometricConfig()) is None


def test_a_sparse_source_is_not_handed_to_the_solver(monkeypatch):
    """A sparse sample of a room (what a live dense message carries) describes too little
    surface: the solver is not even tried."""
    import kiss_matcher

    room, ref_room, *_ = garbled_pair()
    sparse = room[np.random.default_rng(0).choice(len(room), 1000, replace=False)]   # 953 voxels

    def called(*args, **kwargs):
        raise RuntimeError("solver called")

    monkeypatch.setattr(kiss_matcher, "KISSMatcher", called)
    assert geometric_hypothesis(sparse, ref_room, GeometricConfig()) is None
    with pytest.raises(RuntimeError, match="solver called"):
        geometric_hypothesis(sparse, ref_room, GeometricConfig(min_voxels=0))


CRASHERS = """
import sys, numpy as np
sys.path.insert(0, {here!r})
from test_pose_geometric import garbled_pair
from sgreg_core.pose.geometric import GeometricConfig, geometric_hypothesis
room = garbled_pair()[0]
rng = np.random.default_rng(0)
one_voxel = np.ones((60, 3))
scattered = rng.random((200, 3)) * 5.0      # points 1 m apart: no surface around any of them
two_blobs = np.r_[np.zeros((30, 3)), np.full((30, 3), 5.0)] + rng.random((60, 3)) * 0.01
for cloud in (one_voxel, scattered, two_blobs):
    for src, ref in ((room, cloud), (cloud, room)):
        print(geometric_hypothesis(src, ref, GeometricConfig(min_voxels=0)), flush=True)
"""


def test_clouds_with_too_little_surface_never_reach_the_solver():
    """KISS-Matcher segfaults (the process ends, nothing to catch) on clouds of a few voxels or
    of scattered points, on either side: run in a process of its own, every one is refused."""
    import subprocess
    import sys
    from pathlib import Path

    code = CRASHERS.format(here=str(Path(__file__).parent))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, f"the solver crashed (exit {out.returncode}): {out.stderr[-500:]}"
    assert out.stdout.split() == ["None"] * 6
    with pytest.raises(ValueError, match="min_surface"):
        GeometricConfig(min_surface=0)


def test_a_pair_without_one_right_node_match_is_registered_from_geometry():
    room, ref_room, T, src, ref = garbled_pair()
    off = replace(PipelineConfig(), geometric=GeometricConfig(enabled=False))
    plain = register_features(WrongMatcher(np.random.default_rng(3), 8), src, ref, room,
                              ref_room, off)
    assert not plain.success and not plain.geometric and "geometric" not in plain.pose_timing_ms
    reg = register_features(WrongMatcher(np.random.default_rng(3), 8), src, ref, room, ref_room,
                            PipelineConfig())    # on by default
    assert reg.success and reg.geometric and reg.mode == "dense" and reg.refined
    dt, dr = pose_error(reg.T, T)
    assert dt < 0.05 and dr < 1.0
    assert reg.confidence >= PipelineConfig().pose.verdict.min_confidence
    assert reg.footprint_fitness >= GeometricConfig().min_fitness
    assert reg.to_json()["geometric"] is True and "geometric" in reg.pose_timing_ms
    # no wrong node match agrees with the pose: the runtime keeps none of them
    assert len(reg.inlier_mask) == len(reg.corr) and reg.inlier_nodes == 0
    assert len(reg.inlier_corr()) == 0


def test_nothing_is_verified_against_another_room():
    room, _, T, src, ref = garbled_pair()
    other = apply_T(T, box_room(np.random.default_rng(9), size=np.array([5.0, 4.0, 2.5])))
    reg = register_features(WrongMatcher(np.random.default_rng(3), 8), src, ref, room, other,
                            PipelineConfig())
    assert not reg.success and not reg.geometric and "geometric" in reg.pose_timing_ms


def test_the_gates_refuse_poor_support_ties_and_low_confidence():
    cfg, verdict = GeometricConfig(), VerdictConfig()
    good = Evidence(fitness=0.9, footprint_share=0.8)
    assert judge_geometric(good, verdict, cfg) == "ok"
    assert judge_geometric(replace(good, fitness=0.6), verdict, cfg) == "verification_failed"
    assert judge_geometric(replace(good, footprint_share=0.1), verdict, cfg) == "verification_failed"
    assert judge_geometric(replace(good, fitness=float("nan")), verdict, cfg) == "verification_failed"
    tie = replace(good, competitor_fitness=0.85, ambiguity=0.85 / 0.9)
    assert judge_geometric(tie, verdict, cfg) == "ambiguous"
    # the confidence rises with the fitness and falls with a rival's
    assert geometric_confidence(replace(good, fitness=0.95), cfg) > geometric_confidence(good, cfg)
    assert geometric_confidence(replace(good, ambiguity=0.5), cfg) < geometric_confidence(good, cfg)
    strict = replace(verdict, min_confidence=1.0)
    assert judge_geometric(good, strict, cfg) == "low_confidence"


def test_a_rival_that_fits_as_well_makes_a_tie(monkeypatch):
    """A semantic hypothesis far from the geometric pose that the clouds support as well (a
    symmetric room) refuses the geometric pose."""
    import sgreg_core.pose.geometric as geometric
    room, ref_room, T, src, ref = garbled_pair()
    flipped = make_T(yaw_rotation(np.pi), np.zeros(3))
    pose_cfg = PipelineConfig().pose
    reference = ReferenceCloud(ref_room, pose_cfg.verify_voxel, pose_cfg.footprint_cell)
    # a rival as well supported as the pose: the verifier scores every pose as it scores T
    score = CloudVerifier.__call__
    monkeypatch.setattr(CloudVerifier, "__call__", lambda self, _: score(self, T))
    empty = np.zeros((0, 3))
    res = geometric.geometric_estimate(empty, empty, np.zeros(0, np.int64), room, reference,
                                       [T @ flipped], pose_cfg, GeometricConfig())
    assert res is not None and res.reason == "ambiguous" and not res.success
    assert res.T_competitor is not None and res.evidence.ambiguity >= 0.99


def test_a_room_that_looks_the_same_half_a_turn_round_is_a_tie_without_any_semantic_rival():
    """The semantic route proposed nothing: the geometric pose's own turns are its rivals. A
    room whose furniture repeats half a turn round is refused as a tie; the same room without
    the repeat is registered."""
    from sgreg_core.pose.geometric import geometric_estimate

    rng = np.random.default_rng(4)
    room, _, _ = room_objects(rng)
    symmetric = np.concatenate([room, np.c_[ROOM[:2] - room[:, :2], room[:, 2]]])
    T = make_T(yaw_rotation(0.8), np.array([3.0, -2.0, 0.0]))
    pose_cfg = PipelineConfig().pose
    empty, none = np.zeros((0, 3)), np.zeros(0, np.int64)

    def estimate(cloud, cfg=GeometricConfig()):
        reference = ReferenceCloud(apply_T(T, cloud), pose_cfg.verify_voxel, pose_cfg.footprint_cell)
        return geometric_estimate(empty, empty, none, cloud, reference, [], pose_cfg, cfg)

    tie = estimate(symmetric)
    assert tie is not None and tie.reason == "ambiguous" and not tie.success
    assert tie.evidence.ambiguity >= GeometricConfig().max_ambiguity
    assert estimate(symmetric, GeometricConfig(turns_deg=())).success   # what the turns catch
    plain = estimate(room)
    assert plain.success and plain.evidence.ambiguity < GeometricConfig().max_ambiguity
    dt, dr = pose_error(plain.T, T)
    assert dt < 0.05 and dr < 1.0


@pytest.mark.parametrize("bad", [{"voxel": 0}, {"min_fitness": 1.5}, {"after": ("ambiguous",)},
                                 {"confidence_weights": (1.0, 2.0)}, {"icp_distances": ()},
                                 {"min_points": 2}, {"min_voxels": -1},
                                 {"turns_deg": (360.0,)}, {"turns_deg": (float("nan"),)}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        GeometricConfig(**bad)
