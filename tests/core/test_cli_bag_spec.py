"""sgreg make-bag's input checks, before any simulation: the settings of a bag (BagSpec) and
the pseudo ground truth that moves a second capture (rescan_gt.json)."""
import json

import numpy as np
import pytest

from sgreg_cli.commands.make_bag import BagSpec, BagSpecError, rescan_transform
from sgreg_cli.main import main


@pytest.mark.parametrize("setting", [
    {"speed": -1.0}, {"speed": 0.0}, {"speed": float("nan")}, {"clearance": 100.0},
    {"mapping_period": -1.0}, {"mapping_period": 0.0}, {"mapping_period": float("nan")},
    {"range": 0.0}, {"range": -5.0}, {"fov": 0.0}, {"range_b": 0.0}, {"fov_b": 400.0},
    {"voxel": -0.1}, {"waypoints": 2.5}, {"seed": -1}, {"speed": "fast"}, {"speed": True},
    {"agents": 0}, {"agents": 27}, {"agents": 2.5},
])
def test_bag_settings_out_of_range_are_refused(setting):
    name = next(iter(setting))
    with pytest.raises(BagSpecError, match=rf"^{name} \(--{name.replace('_', '-')}\) must be"):
        BagSpec(scan="scan", **setting)


@pytest.mark.parametrize("start", [(1.0,), (float("nan"), 0.0), ("x", 1.0), (1.0, 2.0, 3.0)])
def test_start_points_that_are_not_two_finite_numbers_are_refused(start):
    with pytest.raises(BagSpecError, match=r"^start_b \(--start-b\) must be two finite numbers"):
        BagSpec(scan="scan", start_b=start)


def test_settings_that_would_be_ignored_are_refused():
    """Recorded in the bag's ground truth, yet without effect on its walks."""
    with pytest.raises(BagSpecError, match=r"^gt \(--gt\) moves a second capture"):
        BagSpec(scan="scan", gt="rescan_gt.json")
    with pytest.raises(BagSpecError, match=r"^start_b \(--start-b\) is where b starts its own path"):
        BagSpec(scan="scan", start_b=(1.0, 1.0))
    BagSpec(scan="scan", start_b=(1.0, 1.0), opposite=False)


def test_make_bag_leaves_no_partial_bag_and_checks_its_folder_first(tmp_path, capsys, monkeypatch):
    """Ctrl-C while writing removes the half-written bag (a rerun would refuse it as existing);
    an output folder that cannot be made is said before simulating."""
    from sgreg_cli import bags
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    write_instance_map(generate_scene(0, SynthConfig(density=100.0)), tmp_path / "scene")
    (tmp_path / "a_file").write_text("x")
    assert main(["make-bag", str(tmp_path / "scene"), "--out", str(tmp_path / "a_file" / "bag")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sgreg make-bag: cannot create folder") and "simulating" not in err, err

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(bags, "seal_chunks", interrupted)
    assert main(["make-bag", str(tmp_path / "scene"), "--out", str(tmp_path / "bag")]) == 130
    assert capsys.readouterr().err.endswith("sgreg make-bag: interrupted\n")
    assert not (tmp_path / "bag").exists()


def test_a_start_point_outside_the_scene_is_refused_before_simulating(tmp_path, capsys):
    """The walk would start at the free cell nearest to it, far from where it was asked."""
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    write_instance_map(generate_scene(0, SynthConfig(density=100.0)), tmp_path / "scene")
    assert main(["make-bag", str(tmp_path / "scene"), "--out", str(tmp_path / "bag"),
                 "--start-a", "500,0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "start_a (500, 0) lies outside the scene (x in [" in err, err
    assert not (tmp_path / "bag").exists()


def test_default_and_shipped_bag_settings_are_accepted():
    """The settings every shipped bag was made with (its ground truth's config), not a copy."""
    from pathlib import Path

    BagSpec(scan="scan")
    shipped = sorted((Path(__file__).resolve().parents[2] / "bags").glob("*/ground_truth.json"))
    assert len(shipped) >= 4
    for gt in shipped:
        BagSpec(**json.loads(gt.read_text())["config"])


def test_make_bag_refuses_a_bad_flag_in_one_line(tmp_path, capsys):
    assert main(["make-bag", str(tmp_path), "--out", str(tmp_path / "bag"), "--speed", "-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("sgreg make-bag: speed (--speed) must be")
    assert not (tmp_path / "bag").exists()
    # a scan that is not there, or a bag folder that is: one line, nothing said of simulating
    (tmp_path / "bag").mkdir()
    for argv in (["make-bag", str(tmp_path / "none"), "--out", str(tmp_path / "new")],
                 ["make-bag", str(tmp_path), "--out", str(tmp_path / "bag")]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("sgreg make-bag: "), err


RIGID = [[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


@pytest.mark.parametrize("content, why", [
    ([], "is not a pseudo ground truth"),
    ({"pairs": ["x"]}, "is not a pseudo ground truth"),
    ({"pairs": {"src": "b"}}, "is not a pseudo ground truth"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": True}]}, "not a 4x4 rigid transform"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": [[1, 0], [0, 1]]}]},
     "not a 4x4 rigid transform"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": np.zeros((4, 4)).tolist()}]},
     "not a 4x4 rigid transform"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": (2 * np.eye(4)).tolist()}]},
     "not a 4x4 rigid transform"),
    # "no" is a truthy string: read as accepted, the bag's ground truth would be a rejected pair's
    ({"pairs": [{"src": "b", "ref": "a", "accepted": "no", "T_src_to_ref": RIGID}]},
     "'accepted' of a x b must be true or false, got 'no'"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": False, "reasons": "overlap 0.1"}]}, "rejects a x b: overlap 0.1$"),
    ({"pairs": [{"src": "b", "ref": "a", "accepted": False, "reasons": [3, "low"]}]}, "rejects a x b: 3; low$"),
])
def test_a_malformed_pseudo_ground_truth_is_refused(tmp_path, content, why):
    gt = tmp_path / "rescan_gt.json"
    gt.write_text(json.dumps(content))
    with pytest.raises(BagSpecError, match=why):
        rescan_transform(str(tmp_path / "a"), str(tmp_path / "b"), str(gt))


def test_an_accepted_rigid_pseudo_ground_truth_is_used_either_way(tmp_path):
    gt = tmp_path / "rescan_gt.json"
    gt.write_text(json.dumps({"pairs": [{"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": RIGID}]}))
    np.testing.assert_allclose(rescan_transform("x/a", "x/b", str(gt)), RIGID)
    np.testing.assert_allclose(rescan_transform("x/b", "x/a", str(gt)) @ RIGID, np.eye(4), atol=1e-12)
