"""Typed configs from plain dicts (sgreg_core/config.py): a value of the wrong type, NaN, or a
node parameter outside its declared range is refused with the field named, before any
component runs with it."""
import math

import pytest

from sgreg_core.bench.cases import CaseConfig
from sgreg_core.bench.register_bench import BenchConfig
from sgreg_core.config import from_dict
from sgreg_core.maps.scene_graph import GraphConfig
from sgreg_core.pipeline import PipelineConfig


@pytest.mark.parametrize("data, field", [
    ({"min_nodes": "abc"}, "PipelineConfig.min_nodes must be an integer"),
    ({"min_nodes": 3.5}, "PipelineConfig.min_nodes must be an integer"),
    ({"mode": 1}, "PipelineConfig.mode must be a string"),
    ({"graph": {"voxel_size": "abc"}}, "GraphConfig.voxel_size must be a number"),
    ({"graph": {"voxel_size": math.nan}}, "GraphConfig.voxel_size must be a number"),
    ({"graph": {"voxel_size": True}}, "GraphConfig.voxel_size must be a number"),
    ({"graph": {"voxel_size": 0.0}}, "GraphConfig.voxel_size must lie in [0.01, 0.5]"),
    ({"geometric": {"enabled": "yes"}}, "GeometricConfig.enabled must be true or false"),
    ({"pose": {"clique_deltas": [0.2, "x"]}}, "PoseConfig.clique_deltas must be a list, each a number"),
    ({"pose": {"clique_deltas": 0.2}}, "PoseConfig.clique_deltas must be a list, each a number"),
    ({"pose": {"gnc_inlier_gate": 10 ** 400}}, "PoseConfig.gnc_inlier_gate is too large for a number"),
])
def test_a_value_of_the_wrong_type_or_range_is_refused_naming_the_field(data, field):
    with pytest.raises(ValueError) as err:
        from_dict(PipelineConfig, data)
    assert str(err.value).startswith(field)


def test_values_of_the_right_type_are_taken():
    cfg = from_dict(PipelineConfig, {"min_nodes": 4, "graph": {"voxel_size": 0.1, "box_angles": 45},
                                     "pose": {"clique_deltas": [0.2, 1]}, "geometric": {"turns_deg": [180]}})
    assert cfg.min_nodes == 4 and cfg.graph.voxel_size == 0.1 and cfg.graph.box_angles == 45
    assert cfg.pose.clique_deltas == (0.2, 1) and cfg.geometric.turns_deg == (180,)
    # a whole number given for a float is that float: the saved config and its digests are the
    # same whether a YAML file said 45 or 45.0
    assert type(cfg.pose.clique_deltas[1]) is float and type(cfg.graph.box_angles) is int
    assert type(cfg.min_nodes) is int
    assert from_dict(PipelineConfig, {"graph": {"voxel_size": 0.5}}).graph.voxel_size == 0.5   # the bound itself
    # infinity is a setting (a gate that never closes), NaN never
    assert from_dict(PipelineConfig, {"pose": {"gnc_inlier_gate": math.inf}}).pose.gnc_inlier_gate == math.inf


@pytest.mark.parametrize("make", [
    lambda: GraphConfig(box_angles=0), lambda: GraphConfig(edge_factor=0.0),
    lambda: GraphConfig(contact_dist=math.inf), lambda: GraphConfig(min_points=0),
    lambda: PipelineConfig(min_nodes=0), lambda: PipelineConfig(kept_noise_bound=0.0),
    lambda: PipelineConfig(kept_noise_bound=math.nan), lambda: CaseConfig(n=0), lambda: CaseConfig(seed=-1),
    lambda: CaseConfig(max_translation=math.nan), lambda: CaseConfig(overlap=(0.8, 0.3)),
    lambda: BenchConfig(threads=0)])
def test_settings_that_would_divide_by_zero_or_score_nothing_are_refused(make):
    with pytest.raises(ValueError):
        make()


def test_whole_numbers_become_floats_also_where_a_setting_may_be_none():
    """YAML's `[1, 2]` for an optional pair of floats is that pair of floats (one setting, one
    saved config); a number too large for a float is refused by name, in configs and suites."""
    from sgreg_cli.commands.make_bag import BagSpec
    from sgreg_core.bench.replay_suite import build_spec
    from sgreg_core.simulation.observe import TrajectoryConfig

    start = from_dict(TrajectoryConfig, {"start": [1, 2]}).start
    assert start == (1.0, 2.0) and all(type(v) is float for v in start)
    assert from_dict(TrajectoryConfig, {"start": None}).start is None
    spec = build_spec(BagSpec, {"scan": "s", "start_a": [1, 0]})
    assert all(type(v) is float for v in spec.start_a)
    with pytest.raises(ValueError, match="start_a is too large for a number"):
        build_spec(BagSpec, {"scan": "s", "start_a": [10 ** 400, 0]})
