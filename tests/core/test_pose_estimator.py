"""End-to-end behaviour of sgreg_core.pose.estimate_pose: accuracy under outliers, verdicts on
degenerate or unrelated inputs, 4-DoF mode, verification on clouds."""
import json
from dataclasses import replace

import numpy as np
import pytest

from sgreg_cli.main import main
from sgreg_core.geometry import yaw_rotation
from sgreg_core.pose import (CloudVerifier, PoseConfig, ReferenceCloud, apply_T, estimate_pose,
                             make_T)
from sgreg_core.pose.verdict import Evidence, VerdictConfig, judge, support

ROOM = np.array([8.0, 6.0, 3.0])


def pose_error(T, T_gt):
    dR = T[:3, :3].T @ T_gt[:3, :3]
    ang = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return np.linalg.norm(T[:3, 3] - T_gt[:3, 3]), ang


def random_room_pose(rng, tilt=0.0):
    """Random yaw in [-180, 180) plus a room-scale translation (and optional small tilt)."""
    R = yaw_rotation(rng.uniform(-np.pi, np.pi))
    if tilt:
        c, s = np.cos(tilt), np.sin(tilt)
        R = R @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return make_T(R, rng.uniform(-5, 5, 3))


def correspondences(rng, n, outlier_ratio, T, noise=0.01):
    """n correspondences in a room; outliers pair a source point with a random point of the
    same (transformed) room, so they are spatially indistinguishable from inliers."""
    src = rng.uniform(0, ROOM, (n, 3))
    ref = apply_T(T, src) + rng.normal(0, noise, (n, 3))
    k = int(round(outlier_ratio * n))
    ref[:k] = apply_T(T, rng.uniform(0, ROOM, (k, 3)))
    return src, ref, k


def box_room(rng, n_wall=4000, n_objects=8, size=ROOM):
    """Points on the floor/walls of a room plus random boxes in it (surface samples)."""
    def box(center, extent, m):
        p = rng.uniform(-0.5, 0.5, (m, 3))
        ax = rng.integers(0, 3, m)
        p[np.arange(m), ax] = np.sign(p[np.arange(m), ax] + 1e-9) * 0.5
        return center + p * extent
    parts = [box(size / 2, size, n_wall)]
    for _ in range(n_objects):
        ext = rng.uniform([0.3, 0.3, 0.4], [1.5, 1.0, 1.2])
        ctr = np.r_[rng.uniform(ext[:2] / 2 + 0.2, size[:2] - ext[:2] / 2 - 0.2), ext[2] / 2]
        parts.append(box(ctr, ext, 500))
    return np.concatenate(parts)


@pytest.mark.parametrize("n", [300, 1000])
@pytest.mark.parametrize("outlier_ratio", [0.0, 0.5, 0.8, 0.9, 0.95])
def test_recovers_pose_under_outliers(n, outlier_ratio):
    rng = np.random.default_rng(int(1000 * outlier_ratio) + n)
    T = random_room_pose(rng)
    src, ref, k = correspondences(rng, n, outlier_ratio, T)
    res = estimate_pose(src, ref)
    dt, dr = pose_error(res.T, T)
    assert res.success and res.reason == "ok", res
    assert dt < 0.05 and dr < 1.0
    assert res.used_pyramid == (outlier_ratio > 0.7)
    truth = np.arange(n) >= k
    assert res.inlier_mask[truth].mean() > 0.95
    assert res.inlier_mask[~truth].sum() <= 3
    assert res.timing_ms["total"] > 0


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n", [200, 1000])
def test_random_correspondences_are_rejected(seed, n):
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, ROOM, (n, 3))
    ref = rng.uniform(0, ROOM, (n, 3)) + rng.uniform(-5, 5, 3)
    res = estimate_pose(src, ref)
    assert not res.success
    assert res.reason in ("too_few_inliers", "degenerate_geometry")


def test_unrelated_rooms_with_clouds_are_rejected():
    rng = np.random.default_rng(11)
    room_a, room_b = box_room(rng), box_room(rng, size=np.array([6.0, 5.0, 2.6]))
    ia = rng.integers(0, len(room_a), 600)
    ib = rng.integers(0, len(room_b), 600)
    res = estimate_pose(room_a[ia], room_b[ib], src_cloud=room_a, ref_cloud=room_b)
    assert not res.success
    assert res.reason in ("too_few_inliers", "degenerate_geometry", "verification_failed")


def test_consistent_but_local_cluster_is_rejected():
    """A wrongly matched object pair gives many mutually consistent correspondences, all in
    one spot: enough inliers, but no room-scale support."""
    rng = np.random.default_rng(12)
    T = random_room_pose(rng)
    src = rng.uniform(0, ROOM, (200, 3))
    ref = rng.uniform(-5, 5, (200, 3))
    blob = rng.uniform([3, 3, 0.5], [3.15, 3.15, 0.65], (40, 3))
    src[:40], ref[:40] = blob, apply_T(T, blob)
    res = estimate_pose(src, ref, cfg=PoseConfig(nms_radius=0.0))
    assert res.inliers >= 40
    assert not res.success and res.reason == "degenerate_geometry"


def test_verification_on_clouds_accepts_true_and_rejects_wrong_pose():
    rng = np.random.default_rng(13)
    room = box_room(rng)
    T = random_room_pose(rng)
    ref_cloud = apply_T(T, room) + rng.normal(0, 0.005, room.shape)
    src, ref, _ = correspondences(rng, 400, 0.9, T)
    res = estimate_pose(src, ref, src_cloud=room, ref_cloud=ref_cloud,
                        cfg=PoseConfig(icp=True))
    dt, dr = pose_error(res.T, T)
    assert res.success and dt < 0.05 and dr < 1.0
    assert res.fitness > 0.8 and res.footprint_fitness >= res.fitness
    # ICP refined the estimate here (when it is taken: test_icp_is_taken_only_when_it_lowers_neither_fitness)
    assert pose_error(res.T_estimate, T)[0] < 0.05
    assert res.refined and not np.array_equal(res.T, res.T_estimate)
    # Same correspondences, but the reference cloud is a different room: verification fails.
    other = box_room(np.random.default_rng(99), size=np.array([5.0, 4.0, 2.5]))
    bad = estimate_pose(src, ref, src_cloud=room, ref_cloud=apply_T(T, other))
    assert not bad.success and bad.reason == "verification_failed"


def test_low_overlap_is_judged_on_the_reference_footprint():
    """The reference saw only a third of the room: most of the source has nothing to land on,
    so plain fitness is low, but every source point over the reference's floor plan is on its
    surfaces, and that is what the verdict weighs. Pushed out beside the reference, the
    same source proves nothing and is refused."""
    rng = np.random.default_rng(21)
    room = box_room(rng)
    T = random_room_pose(rng)
    seen = room[room[:, 0] < ROOM[0] / 3]
    ref_cloud = apply_T(T, seen) + rng.normal(0, 0.005, seen.shape)
    src, ref, _ = correspondences(rng, 300, 0.5, T)
    inside = src[:, 0] < ROOM[0] / 3
    src, ref = src[inside], ref[inside]
    res = estimate_pose(src, ref, src_cloud=room, ref_cloud=ref_cloud, cfg=PoseConfig(icp=True))
    assert res.success, res.reason
    assert res.fitness < 0.5 <= res.footprint_fitness and res.footprint_share > 0.2
    assert pose_error(res.T, T)[0] < 0.05
    # the right pose by correspondences, but the clouds say the views lie side by side
    beside = T @ make_T(np.eye(3), [ROOM[0] + 1.0, 0.0, 0.0])
    shifted = estimate_pose(src, apply_T(beside @ np.linalg.inv(T), ref), src_cloud=room,
                            ref_cloud=ref_cloud)
    assert not shifted.success and shifted.reason == "verification_failed"
    assert shifted.footprint_share < 0.2


def test_floor_on_floor_is_no_evidence():
    """Two scenes share a big floor but their furniture stands elsewhere: the floor would make
    any pose look supported, so horizontal surfaces are left out of the scores."""
    rng = np.random.default_rng(23)
    floor = np.c_[rng.uniform(0, 6, (6000, 2)), np.zeros(6000)]

    def cabinet(x, y):   # the four sides of a 1 x 0.6 x 1.2 m box, as a scanner sees them
        p = rng.uniform([0, 0, 0], [1.0, 0.6, 1.2], (1500, 3))
        side = rng.integers(0, 4, 1500)
        p[side == 0, 0], p[side == 1, 0] = 0.0, 1.0
        p[side == 2, 1], p[side == 3, 1] = 0.0, 0.6
        return p + [x, y, 0.0]

    here = np.concatenate([floor, cabinet(1.0, 1.0)])
    there = np.concatenate([floor, cabinet(4.0, 4.0)])
    same = CloudVerifier(here, here, voxel=0.05)(np.eye(4))
    other = CloudVerifier(here, there, voxel=0.05)(np.eye(4))
    assert same.footprint_fitness > 0.9
    assert other.footprint_fitness < 0.2   # the floor alone would have given ~0.8


def test_a_wall_the_reference_never_saw_does_not_count_against_a_right_pose():
    """The reference holds the floor from x = 0.3 m but not the wall at x = 0.1 (its instance
    dropped, the view cut off): at the right pose the source's wall lands in the middle of the
    footprint's one-cell margin (cells of 0.2 m from x = 0), unsupported. With footprint_rim = 1
    the margin is left out of the fitness, so the right pose keeps its support; a pose shifted by a metre still puts
    furniture where the reference has none. The setting reaches the verifier from PoseConfig."""
    rng = np.random.default_rng(24)
    room = box_room(rng) + [0.1, 0.0, 0.0]
    seen = room[room[:, 0] > 0.3]
    fitness = {rim: CloudVerifier(room, seen, voxel=0.05, footprint_rim=rim)(np.eye(4))
               .footprint_fitness for rim in (0, 1)}
    assert fitness[0] < fitness[1] - 0.05 and fitness[1] > 0.97
    shifted = CloudVerifier(room, seen, voxel=0.05, footprint_rim=1)(
        make_T(np.eye(3), [1.0, 0.0, 0.0]))
    assert shifted.footprint_fitness < 0.5
    # through estimate_pose, a prebuilt reference serves both rims
    src, ref, _ = correspondences(rng, 300, 0.3, np.eye(4))
    reference = ReferenceCloud(seen, 0.05, 0.2)
    for rim in (0, 1):
        res = estimate_pose(src, ref, src_cloud=room, ref_cloud=reference,
                            cfg=PoseConfig(footprint_rim=rim))
        assert res.footprint_fitness == pytest.approx(fitness[rim], abs=0.02)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="rim"):
            PoseConfig(footprint_rim=bad)
        with pytest.raises(ValueError, match="rim"):
            CloudVerifier(room, seen, footprint_rim=bad)


def test_probe_leaves_out_a_wall_at_the_edge_of_what_the_reference_saw_only():
    """footprint_probe: a source surface counts only where the reference's footprint lies on
    both sides of it. The reference holds the floor up to the wall at x = 0.1 but not the
    wall: at the right pose that wall is one-sided, left out, and the fitness is the rest's,
    also when the source comes in its own, turned frame (its normals must turn with the pose:
    probed along the wall, it would count). A partition the source has in the middle of the
    room (the reference saw floor on both sides of it, and no wall) still counts against the
    pose, as does a pose a metre off."""
    rng = np.random.default_rng(25)
    room = box_room(rng) + [0.1, 0.0, 0.0]
    seen = room[room[:, 0] > 0.3]
    fit = {p: CloudVerifier(room, seen, voxel=0.05, footprint_probe=p)(np.eye(4)).footprint_fitness
           for p in (0.0, 0.5)}
    assert fit[0.0] < fit[0.5] - 0.05 and fit[0.5] > 0.97
    # the floor right up to the wall, and no wall; the source in a frame turned by 90 deg
    floor_to_wall = room[~((room[:, 0] < 0.12) & (room[:, 2] > 0.02))]
    T = make_T(yaw_rotation(np.radians(90.0)), [2.0, -1.0, 0.0])      # source frame -> room
    turned = apply_T(np.linalg.inv(T), room)
    assert CloudVerifier(turned, floor_to_wall, voxel=0.05)(T).footprint_fitness < 0.9
    probed = CloudVerifier(turned, floor_to_wall, voxel=0.05, footprint_probe=0.5)
    assert probed(T).footprint_fitness > 0.97
    partition = np.c_[np.full(800, 4.0), rng.uniform(1, 5, 800), rng.uniform(0, 3, 800)]
    inside = {p: CloudVerifier(np.concatenate([room, partition]), room, voxel=0.05,
                               footprint_probe=p)(np.eye(4)).footprint_fitness for p in (0.0, 0.5)}
    assert inside[0.5] < 0.9 and inside[0.5] <= inside[0.0]
    shifted = CloudVerifier(room, seen, voxel=0.05, footprint_probe=0.5)(make_T(np.eye(3), [1.0, 0.0, 0.0]))
    assert shifted.footprint_fitness < 0.5
    res = estimate_pose(*correspondences(rng, 300, 0.3, np.eye(4))[:2], src_cloud=room,
                        ref_cloud=ReferenceCloud(seen, 0.05, 0.2), cfg=PoseConfig(footprint_probe=0.5))
    assert res.footprint_fitness == pytest.approx(fit[0.5], abs=0.02)
    for bad in (-0.5, float("nan"), True):
        with pytest.raises(ValueError, match="probe"):
            PoseConfig(footprint_probe=bad)
        with pytest.raises(ValueError, match="probe"):
            CloudVerifier(room, seen, footprint_probe=bad)


def test_prebuilt_reference_cloud_gives_the_same_verdict():
    rng = np.random.default_rng(22)
    room = box_room(rng)
    T = random_room_pose(rng)
    ref_cloud = apply_T(T, room)
    src, ref, _ = correspondences(rng, 300, 0.7, T)
    cfg = PoseConfig(icp=True)
    a = estimate_pose(src, ref, src_cloud=room, ref_cloud=ref_cloud, cfg=cfg)
    b = estimate_pose(src, ref, src_cloud=room,
                      ref_cloud=ReferenceCloud(ref_cloud, cfg.verify_voxel, cfg.footprint_cell),
                      cfg=cfg)
    assert a.success and b.success
    np.testing.assert_allclose(a.T, b.T, atol=1e-9)
    assert a.footprint_fitness == pytest.approx(b.footprint_fitness)


def test_4dof_mode():
    rng = np.random.default_rng(14)
    T = random_room_pose(rng)
    src, ref, _ = correspondences(rng, 500, 0.9, T, noise=0.02)
    res = estimate_pose(src, ref, cfg=PoseConfig(dof=4))
    assert res.success
    np.testing.assert_allclose(res.T[2, :3], [0, 0, 1], atol=1e-12)
    dt, dr = pose_error(res.T, T)
    assert dt < 0.05 and dr < 1.0
    # A tilted truth cannot be represented in 4-DoF, SE(3) mode still finds it.
    Tt = random_room_pose(rng, tilt=np.radians(10))
    src, ref, _ = correspondences(rng, 300, 0.5, Tt)
    assert pose_error(estimate_pose(src, ref).T, Tt)[1] < 1.0
    assert pose_error(estimate_pose(src, ref, cfg=PoseConfig(dof=4)).T, Tt)[1] > 5.0


@pytest.mark.parametrize("src,ref,reason", [
    (np.zeros((2, 3)), np.zeros((2, 3)), "too_few_correspondences"),
    (np.zeros((0, 3)), np.zeros((0, 3)), "too_few_correspondences"),
    (np.zeros((5, 3)), np.zeros((4, 3)), "invalid_input"),
    (np.zeros((5, 2)), np.zeros((5, 2)), "invalid_input"),
    ("not points", None, "invalid_input"),
    (np.full((10, 3), np.nan), np.zeros((10, 3)), "too_few_correspondences"),
])
def test_invalid_inputs_return_verdict(src, ref, reason):
    res = estimate_pose(src, ref)
    assert not res.success and res.reason == reason
    np.testing.assert_array_equal(res.T, np.eye(4))


def test_collinear_correspondences_are_degenerate():
    t = np.linspace(0, 5, 50)
    src = np.c_[t, 0.5 * t, np.ones(50)]
    res = estimate_pose(src, src + [1.0, 2.0, 0.0])
    assert not res.success and res.reason == "degenerate_geometry"


def test_nan_rows_are_dropped_not_fatal():
    rng = np.random.default_rng(15)
    T = random_room_pose(rng)
    src, ref, _ = correspondences(rng, 300, 0.5, T)
    src[::10, 1] = np.nan
    ref[5::10, 0] = np.inf
    res = estimate_pose(src, ref)
    assert res.success and pose_error(res.T, T)[0] < 0.05
    assert res.num_correspondences <= 240
    assert not res.inlier_mask[::10].any()


def test_weights_and_noise_bounds_are_validated_and_used():
    rng = np.random.default_rng(16)
    T = random_room_pose(rng)
    src, ref, k = correspondences(rng, 300, 0.5, T)
    assert estimate_pose(src, ref, weights=np.ones(5)).reason == "invalid_input"
    assert estimate_pose(src, ref, noise_bounds=np.ones(5)).reason == "invalid_input"
    # Zero weight on all inliers leaves only outliers to fit.
    w = np.ones(300)
    w[k:] = 0.0
    assert not estimate_pose(src, ref, weights=w).success
    res = estimate_pose(src, ref, noise_bounds=np.full(300, 0.05))
    assert res.success and pose_error(res.T, T)[0] < 0.05


def test_malformed_weights_bounds_and_hypotheses_are_refused_not_raised():
    rng = np.random.default_rng(17)
    T = random_room_pose(rng)
    src, ref, _ = correspondences(rng, 300, 0.5, T)
    assert estimate_pose(src, ref, weights="abc").reason == "invalid_input"
    assert estimate_pose(src, ref, noise_bounds={"a": 1}).reason == "invalid_input"
    # a broken earlier pass is no candidate: the estimate is made from scratch
    bad = [np.full((4, 4), np.nan), np.eye(3), "pose"]
    res = estimate_pose(src, ref, hypotheses=bad)
    assert res.success and pose_error(res.T, T)[0] < 0.05
    # one pose where a list was meant, or no poses at all, is no reason to raise either
    for given in (bad, np.full((4, 4), np.nan), 5, T):
        res = estimate_pose(src, ref, hypotheses=np.full((4, 4), np.nan), given=given)
        assert res.success and pose_error(res.T, T)[0] < 0.05


@pytest.mark.parametrize("bad", [{"footprint_cell": 0.0}, {"footprint_cell": float("nan")},
                                 {"verify_tau": 0.0}, {"noise_bound": -0.1},
                                 {"icp_distance": float("inf")}, {"verify_voxel": -0.05},
                                 {"clique_deltas": (0.1, 0.0)}, {"dof": 5},
                                 {"gnc_inlier_gate": float("nan")}, {"verify_max_points": 2}])
def test_pose_config_refuses_distances_that_would_turn_a_check_off(bad):
    """A zero footprint cell puts a whole map in one cell: a source 100 m away would land on
    the footprint."""
    with pytest.raises(ValueError, match="pose"):
        PoseConfig(**bad)
    PoseConfig(nms_radius=0.0, verify_voxel=0.0, gnc_inlier_gate=np.inf)   # off, and always


def test_a_stray_point_far_out_neither_slows_the_footprint_nor_leaves_the_plan():
    """The footprint grid spans the cloud: one point 3 km out made it 15000 x 15000 cells (27 s);
    one beyond any map (geometry.MAX_COORD_M) overflowed it."""
    import time

    room = box_room(np.random.default_rng(18))
    clean = ReferenceCloud(room)
    for far in (3e3, 9e3, 1e12, 1e39):
        t0 = time.perf_counter()
        ref = ReferenceCloud(np.r_[room, [[far, far, 0.0]]])
        assert time.perf_counter() - t0 < 5.0 and ref.valid
        assert ref.footprint.grid.shape == clean.footprint.grid.shape
        assert ref.footprint.contains(room).all()
        ver = CloudVerifier(room, ref)(np.eye(4))
        assert ver.footprint_fitness == CloudVerifier(room, clean)(np.eye(4)).footprint_fitness
    # two rooms 7 km apart, as many points in each: the plan of one of them, not of neither
    twin = ReferenceCloud(np.r_[room, room + [5e3, 5e3, 0.0]])
    assert twin.footprint.contains(room).all() != twin.footprint.contains(room + [5e3, 5e3, 0.0]).all()


def test_bench_pose_cli(tmp_path, capsys):
    out = tmp_path / "pose.json"
    assert main(["bench-pose", "--n", "200", "--outliers", "0.5", "0.9", "--trials", "2",
                 "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["outlier_ratio"] for r in rows] == [0.5, 0.9]
    assert all(r["success_rate"] == 1.0 and r["rte_m_median"] < 0.05 for r in rows)
    assert "clique ms" in capsys.readouterr().out
    assert main(["bench-pose", "--outliers", "1.5", "--out", str(out)]) == 2


def test_bench_pose_counts_a_claimed_success_at_a_wrong_pose_as_a_failure(tmp_path, monkeypatch):
    import sgreg_core.pose as pose

    real = pose.estimate_pose

    def claims_everything(src, ref, cfg=None):
        res = real(src, ref, cfg=cfg)
        res.T, res.success = np.eye(4), True       # a pose nobody asked for, said to be right
        return res

    monkeypatch.setattr(pose, "estimate_pose", claims_everything)
    out = tmp_path / "pose.json"
    assert main(["bench-pose", "--n", "100", "--outliers", "0.5", "--trials", "2", "--out", str(out)]) == 0
    [row] = json.loads(out.read_text())["rows"]
    assert row["claimed_rate"] == 1.0 and row["success_rate"] == 0.0


def object_correspondences(rng, T, centers, per_object=12, noise=0.01, size=0.15):
    """Correspondences on objects (about `size` m) at `centers`, consistent with T, and their
    groups."""
    src = np.concatenate([c + rng.normal(0, size, (per_object, 3)) for c in centers])
    groups = np.repeat(np.arange(len(centers)), per_object)
    return src, apply_T(T, src) + rng.normal(0, noise, src.shape), groups


@pytest.mark.parametrize("rival_objects,reason", [(5, "ambiguous"), (2, "ok")])
def test_near_tie_between_two_hypotheses_is_refused(rival_objects, reason):
    """Objects matched to their look-alikes (a symmetric room) agree on a second pose: when
    that pose is as well supported as the first, no pose is trusted; a clearly weaker rival
    does not stop a clear winner."""
    rng = np.random.default_rng(rival_objects)
    T1 = random_room_pose(rng)
    T2 = T1 @ make_T(yaw_rotation(np.pi), np.zeros(3))     # the same room turned half a turn
    s1, r1, g1 = object_correspondences(rng, T1, rng.uniform(0, ROOM, (5, 3)))
    s2, r2, g2 = object_correspondences(rng, T2, rng.uniform(0, ROOM, (rival_objects, 3)))
    res = estimate_pose(np.r_[s1, s2], np.r_[r1, r2], groups=np.r_[g1, g2 + 100],
                        cfg=PoseConfig(nms_radius=0.0))
    assert res.reason == reason, res.evidence
    assert res.evidence.objects == 5 and res.evidence.competitor_objects == rival_objects
    assert pose_error(res.T, T1)[0] < 0.05 and pose_error(res.T_competitor, T2)[0] < 0.05


def test_a_near_tie_with_a_competitor_the_clouds_refute_is_refused_only_by_default():
    """Seven wrong node matches agreeing on a pose that the clouds refute (fitness 0.3) against
    four right ones at fitness 0.95: a tie by object count, no tie once the competitor must be
    plausible; a competitor with no clouds to refute it (NaN) always counts."""
    ev = Evidence(inliers=120, inlier_ratio=0.3, objects=4, spread=0.4, fitness=0.95,
                  footprint_share=0.6, competitor_objects=7, competitor_fitness=0.3)
    ev.ambiguity = support(7, 0.3) / support(4, 0.95)
    assert ev.ambiguity > VerdictConfig().max_ambiguity
    assert judge(ev, VerdictConfig(), have_clouds=True) == "ambiguous"
    lenient = VerdictConfig(competitor_min_fitness=0.5)
    assert judge(ev, lenient, have_clouds=True) == "ok"
    assert judge(replace(ev, competitor_fitness=0.6), lenient, have_clouds=True) == "ambiguous"
    assert judge(replace(ev, competitor_fitness=float("nan")), lenient, have_clouds=False) == "ambiguous"


@pytest.mark.parametrize("bad", [{"min_fitness": 1.5}, {"min_confidence": float("nan")},
                                 {"competitor_min_fitness": -0.1}, {"min_inliers": 0},
                                 {"min_spread": -1.0}, {"max_ambiguity": -0.1},
                                 {"competitor_deg": 0.0}, {"confidence_weights": (1.0, 2.0)}])
def test_verdict_config_refuses_values_that_would_verify_anything_or_nothing(bad):
    with pytest.raises(ValueError, match="verdict"):
        VerdictConfig(**bad)
    VerdictConfig(min_inliers=3, min_objects=1, min_spread=0, min_fitness=0,
                  min_footprint_share=0, max_ambiguity=100, min_confidence=0)  # the permissive replay


def test_inliers_from_too_few_objects_are_refused():
    rng = np.random.default_rng(3)
    T = random_room_pose(rng)
    src, ref, groups = object_correspondences(rng, T, rng.uniform(0, ROOM, (2, 3)), per_object=40,
                                              size=0.5)
    res = estimate_pose(src, ref, groups=groups, cfg=PoseConfig(nms_radius=0.0))
    assert pose_error(res.T, T)[0] < 0.05           # the pose is right, but two objects are
    assert res.reason == "too_few_objects"          # not enough to trust it
    assert estimate_pose(src, ref, cfg=PoseConfig(nms_radius=0.0)).success   # points alone would


def test_the_clique_pyramid_sees_the_most_confident_correspondences_only():
    """6000 correspondences, 92 % outliers: the pyramid runs on the 1000 most confident (the
    inliers weigh more, as matched nodes do) and still finds the pose, at a fraction of the
    quadratic cost; the cliques' indices point into all 6000."""
    rng = np.random.default_rng(3)
    T = random_room_pose(rng)
    src, ref, k = correspondences(rng, 6000, 0.92, T)
    w = np.where(np.arange(6000) >= k, 1.0, 0.5) * rng.uniform(0.5, 1.0, 6000)
    capped = estimate_pose(src, ref, weights=w, cfg=PoseConfig(max_clique_correspondences=1000))
    dt, dr = pose_error(capped.T, T)
    assert capped.success and capped.used_pyramid and dt < 0.05 and dr < 1.0, capped.reason
    assert max(capped.clique_sizes) <= 1000
    assert capped.inlier_mask[k:].mean() > 0.95          # inliers found among all of them
    from sgreg_core.pose.estimator import _clique_pyramid
    level = _clique_pyramid(src, ref, np.full(6000, 0.1), w, (0.2,), PoseConfig(max_clique_correspondences=1000))[0]
    assert level.indices.size >= 100 and set(level.indices) <= set(np.argsort(-w)[:1000])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_second_pass_on_the_first_pass_hypotheses_matches_a_pass_from_scratch(seed):
    """The coarse retry adds pair poses to the first pass's GNC and clique poses instead of
    fitting those again: the same candidates in the same order, so the same estimate."""
    rng = np.random.default_rng(seed)
    src, ref, _ = correspondences(rng, 60, 0.8, random_room_pose(rng))   # the pyramid runs
    first = estimate_pose(src, ref, cfg=PoseConfig())
    assert first.used_pyramid and len(first.hypotheses) >= 2
    with_pairs = PoseConfig(pair_hypotheses=8)
    fresh = estimate_pose(src, ref, cfg=with_pairs)
    again = estimate_pose(src, ref, cfg=with_pairs, hypotheses=first.hypotheses)
    assert again.candidates == fresh.candidates > len(first.hypotheses)
    assert again.reason == fresh.reason and again.inliers == fresh.inliers
    assert np.array_equal(again.T, fresh.T) and again.confidence == fresh.confidence
    assert not again.used_pyramid and np.array_equal(again.hypotheses, first.hypotheses)


def test_a_given_pose_is_weighed_beside_the_fitted_ones():
    """A merged estimate's many confident node-center matches may all agree on a wrong pose
    while the fewer kept points agree on the right one: GNC and every clique then fit the wrong
    pose. The pose the kept points came from, given, is one more candidate, and the clouds
    pick it. A malformed given pose is no candidate."""
    rng = np.random.default_rng(31)
    room = box_room(rng)
    T = random_room_pose(rng)
    ref_cloud = apply_T(T, room) + rng.normal(0, 0.005, room.shape)
    T_wrong = T @ make_T(yaw_rotation(np.radians(150.0)), [1.0, 0.5, 0.0])
    right_src = room[rng.choice(len(room), 25, replace=False)]
    wrong_src = rng.uniform(0, ROOM, (60, 3))
    src = np.r_[right_src, wrong_src]
    ref = np.r_[apply_T(T, right_src), apply_T(T_wrong, wrong_src)] + rng.normal(0, 0.01, (85, 3))
    weights = np.r_[np.full(25, 0.1), np.ones(60)]
    groups = np.r_[np.arange(25) // 5, 100 + np.arange(60) // 10]   # five objects, six
    cfg = PoseConfig(icp=True)
    alone = estimate_pose(src, ref, weights, room, ref_cloud, cfg, groups=groups)
    assert not alone.success and pose_error(alone.T, T)[1] > 90
    given = estimate_pose(src, ref, weights, room, ref_cloud, cfg, groups=groups,
                          given=[np.full((4, 4), np.nan), T @ make_T(np.eye(3), [0.05, 0.0, 0.0])])
    assert given.success and given.candidates == alone.candidates + 1
    assert pose_error(given.T, T)[0] < 0.1 and given.evidence.objects == 5


def test_icp_is_taken_only_when_it_lowers_neither_fitness(monkeypatch):
    """On a small map ICP can slide a right pose along a wall, gaining a little plain fitness
    while the footprint fitness the verdict judges falls: the estimate keeps its own pose."""
    import sgreg_core.pose.estimator as est_mod
    from sgreg_core.pose.verify import Verification

    rng = np.random.default_rng(13)
    room = box_room(rng)
    T = random_room_pose(rng)
    ref_cloud = apply_T(T, room) + rng.normal(0, 0.005, room.shape)
    src, ref, _ = correspondences(rng, 400, 0.5, T)
    slid = T @ make_T(np.eye(3), [0.8, 0.0, 0.0])
    real_verifier = est_mod.cloud_verifier

    def verifier_seeing_a_slide(src_cloud, ref_cloud, cfg, footprint_drop):
        v = real_verifier(src_cloud, ref_cloud, cfg)
        right = v(T)

        def judge(pose):
            if np.allclose(pose, slid):   # a point more fitness, a tenth less on the footprint
                return Verification(fitness=right.fitness + 0.01, score=right.score,
                                    footprint_share=right.footprint_share,
                                    footprint_fitness=right.footprint_fitness - footprint_drop)
            return v(pose)
        return type("SlidVerifier", (), {"__call__": lambda self, pose: judge(pose),
                                         "valid": True, "src": v.src, "reference": v.reference})()

    monkeypatch.setattr(est_mod, "refine_icp", lambda verifier, T0, cfg: slid)
    for drop, taken in ((0.1, False), (0.0, True)):
        monkeypatch.setattr(est_mod, "cloud_verifier",
                            lambda s, r, c, d=drop: verifier_seeing_a_slide(s, r, c, d))
        res = estimate_pose(src, ref, src_cloud=room, ref_cloud=ref_cloud, cfg=PoseConfig(icp=True))
        assert res.refined is taken
        assert pose_error(res.T, T)[0] == pytest.approx(0.8 if taken else 0.0, abs=0.05)


# ---- twin rooms: the competitor, where it is measured, and clouds too small to judge --------

def surface_grid(corner, u, v, step=0.05):
    """Points every `step` m on the parallelogram corner + a*u + b*v, a, b in [0, 1]."""
    corner, u, v = (np.asarray(x, np.float64) for x in (corner, u, v))
    a = np.linspace(0.0, 1.0, int(np.linalg.norm(u) / step) + 1)
    b = np.linspace(0.0, 1.0, int(np.linalg.norm(v) / step) + 1)
    A, B = (m.reshape(-1, 1) for m in np.meshgrid(a, b))
    return corner + A * u + B * v


def furnished_room(x0, width=5.0, depth=4.0, height=2.5, cubes=((0.8, 0.8), (2.5, 1.0), (4.0, 3.0),
                                                               (1.5, 3.0), (3.2, 2.0), (4.2, 1.0))):
    """(walls, [cube surfaces]) of a room starting at x = x0, with 0.6 m cubes on its floor."""
    corners = [(x0, 0.0), (x0 + width, 0.0), (x0 + width, depth), (x0, depth)]
    up = (0.0, 0.0, height)
    walls = np.concatenate([surface_grid((*p, 0.0), np.subtract(q, p).tolist() + [0.0], up)
                            for p, q in zip(corners, corners[1:] + corners[:1])])
    s = 0.6
    def cube(x, y):
        o = np.array([x0 + x - s / 2, y - s / 2, 0.0])
        ex, ey, ez = np.eye(3) * s
        return np.concatenate([surface_grid(o, ex, ey), surface_grid(o + ez, ex, ey),
                               surface_grid(o, ex, ez), surface_grid(o + ey, ex, ez),
                               surface_grid(o, ey, ez), surface_grid(o + ex, ey, ez)])
    return walls, [cube(x, y) for x, y in cubes]


def twin_rooms_case(rng, T_true, noise, twin_objects=4):
    """The reference holds two identical rooms side by side; the source saw the first one (by
    T_true). Correspondences: 5 objects to their own room, twin_objects to the twin room."""
    walls_a, cubes_a = furnished_room(0.0)
    walls_b, cubes_b = furnished_room(5.5)
    ref_cloud = np.concatenate([walls_a, walls_b] + cubes_a + cubes_b)
    back = np.linalg.inv(T_true)
    seen = np.concatenate([walls_a] + cubes_a)
    src_cloud = apply_T(back, seen) + rng.normal(0.0, noise, seen.shape)
    src, ref, groups = [], [], []
    for k, (own, target) in enumerate([(j, cubes_a[j]) for j in range(5)]
                                      + [(j, cubes_b[j]) for j in range(twin_objects)]):
        pick = rng.choice(len(target), 12, replace=False)
        src.append(apply_T(back, cubes_a[own][pick]))
        ref.append(target[pick])
        groups.append(np.full(12, k))
    return np.concatenate(src), np.concatenate(ref), np.concatenate(groups), src_cloud, ref_cloud


def test_an_estimate_short_of_confidence_has_its_competitor_measured_too():
    """The competitor was looked for only once every test, confidence included, had passed: an
    estimate refused for confidence reported no tie (ambiguity 0, so a confidence too high),
    and the runtime takes such an estimate when a peer's link vouches for it. Between twin rooms
    (5 objects to the right room, 4 to its twin) it is a near-tie."""
    from sgreg_core.pipeline import PipelineConfig
    rng = np.random.default_rng(0)
    T_true = make_T(yaw_rotation(np.radians(30.0)), [1.0, 2.0, 0.0])
    src, ref, groups, src_cloud, ref_cloud = twin_rooms_case(rng, T_true, noise=0.05)
    cfg = PipelineConfig().pose_config()
    res = estimate_pose(src, ref, None, src_cloud, ref_cloud, cfg, groups=groups)
    assert pose_error(res.T, T_true)[0] < 0.1
    assert res.T_competitor is not None and res.evidence.ambiguity > cfg.verdict.max_ambiguity
    assert res.reason == "ambiguous" and res.confidence < 0.5


def test_competitors_are_told_apart_at_the_data_not_at_the_frames_origin():
    """Data 30 m from the source frame's origin: a 2 deg turn about the data moves them 9 cm
    (the same pose; the origin moves 1 m), a 5 deg turn about the origin slides them 2.6 m (a
    competitor; the origin stays put)."""
    from sgreg_core.pose.estimator import far_apart
    cfg = VerdictConfig()
    T = make_T(yaw_rotation(0.3), [-30.0, 5.0, 0.0])
    data = np.array([30.0, 0.0, 1.0])
    def turned_about(point, deg):
        R = yaw_rotation(np.radians(deg))
        return T @ make_T(R, point - R @ point)
    assert not far_apart(turned_about(data, 2.0), T, cfg, data)
    assert far_apart(turned_about(np.zeros(3), 5.0), T, cfg, data)
    assert far_apart(turned_about(data, 12.0), T, cfg, data)      # a turn is a turn anywhere


def test_the_rival_search_goes_past_starts_that_icp_brings_back_to_the_winner(monkeypatch):
    """Only the first two competing hypotheses were refined: two starts that ICP brings back
    onto the winner hid a true rival third in line (ambiguity 0)."""
    import sgreg_core.pose.estimator as est
    T_win = np.eye(4)
    starts = [make_T(yaw_rotation(np.radians(d)), np.zeros(3)) for d in (40.0, 80.0, 120.0)]
    rival = make_T(yaw_rotation(np.pi), [1.0, 0.0, 0.0])
    refined = []
    def icp(verifier, T, cfg):
        refined.append(T)
        return T_win if any(T is S for S in starts) else T
    monkeypatch.setattr(est, "refine_icp", icp)

    class Clouds:            # every pose fits its clouds alike
        valid = True
        def __call__(self, T):
            return est.Verification(0.9, 0.9, 0.6, 0.9)

    s = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [2.0, 2.0, 1.0]])
    g = np.arange(4)
    cfg = PoseConfig(icp=True)
    found = est._rival(s, apply_T(rival, s), np.full(4, 0.1), g, starts + [rival], T_win, Clouds(), cfg)
    assert found is not None and np.allclose(found[0], rival) and found[1] == 4
    assert len(refined) == 4
    # at most RIVAL_TRIES starts are refined, and one near a start already tried is not
    refined.clear()
    near = [S @ make_T(yaw_rotation(np.radians(1.0)), np.zeros(3)) for S in starts]
    assert est._rival(s, s, np.full(4, 0.1), g, [starts[0], near[0]] + starts[1:] + [starts[0]] * 3,
                      T_win, Clouds(), cfg) is None
    assert len(refined) == 3


def test_a_handful_of_source_points_verifies_nothing():
    """Correspondences on 5 objects that agree on a pose 1.5 m off, with a source cloud of six
    of their own points: they lie on the reference's surfaces by construction, and six points
    scored a fitness of 1.0. A cloud this small cannot be verified."""
    from sgreg_core.pipeline import PipelineConfig
    from sgreg_core.pose.verify import MIN_SCORED_POINTS
    rng = np.random.default_rng(0)
    walls, cubes = furnished_room(0.0)
    ref_cloud = np.concatenate([walls] + cubes)
    T_wrong = make_T(yaw_rotation(np.radians(30.0)), [2.5, 2.0, 0.0])
    src, ref, groups = [], [], []
    for j in range(5):
        pick = rng.choice(len(cubes[j]), 12, replace=False)
        ref.append(cubes[j][pick])
        src.append(apply_T(np.linalg.inv(T_wrong), cubes[j][pick]))
        groups.append(np.full(12, j))
    src, ref, groups = map(np.concatenate, (src, ref, groups))
    cfg = PipelineConfig().pose_config()
    res = estimate_pose(src, ref, None, src[:6], ref_cloud, cfg, groups=groups)
    assert res.reason == "verification_failed" and not res.success
    wall_points = walls[rng.choice(len(walls), 4 * MIN_SCORED_POINTS, replace=False)]
    assert CloudVerifier(wall_points, ref_cloud).valid
    assert not CloudVerifier(wall_points[: MIN_SCORED_POINTS - 1], ref_cloud).valid
