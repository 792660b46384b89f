"""One source for each parameter: the nodes declare their parameters from the config dataclasses,
config/sgreg.yaml is written from those declarations, and every value it sets is one the nodes
accept."""
from pathlib import Path

import pytest
import yaml

from sgreg_cli.commands.params import parameter_file
from sgreg_core.config import node_params
from sgreg_core.runtime.peers import PeersConfig
from sgreg_ros.agent_node import PARAMS as AGENT
from sgreg_ros.params import Param, ParameterError, check
from sgreg_ros.registration_node import PARAMS as REGISTRATION

YAML = Path(__file__).resolve().parents[2] / "config" / "sgreg.yaml"


@pytest.mark.parametrize("path", [YAML, *sorted((YAML.parent / "profiles").glob("*.yaml"))],
                         ids=lambda p: p.name)
def test_the_parameter_files_name_only_real_parameters_with_valid_values(path):
    """config/sgreg.yaml and every profile laid over it (config/profiles/)."""
    declared = {p.name: p for p in AGENT + REGISTRATION}
    values = yaml.safe_load(path.read_text())["/**"]["ros__parameters"]
    assert values, f"{path.name} sets no parameter"
    unknown = sorted(set(values) - set(declared))
    assert not unknown, f"{path.name} sets parameters no node declares: {unknown}"
    for name, value in values.items():
        check(declared[name], value)          # raises with a clear line when invalid


def test_the_parameter_file_is_written_from_the_declarations():
    assert YAML.read_text() == parameter_file(), \
        "config/sgreg.yaml is stale: run `sgreg params --out config/sgreg.yaml`"
    values = yaml.safe_load(parameter_file())["/**"]["ros__parameters"]
    assert values == {p.name: p.default for p in AGENT + REGISTRATION}


def test_declarations_come_from_the_dataclasses():
    by_name = {p.name: p for p in REGISTRATION}
    for name, (default, help_text, low, high, _, _) in node_params(PeersConfig).items():
        p = by_name[name]
        assert (p.default, p.description, p.low, p.high) == (default, help_text, low, high)
    assert {"coarse_rate_hz", "feature_encoding"} <= {p.name for p in AGENT}
    assert "dense_answers_per_s" not in by_name           # the registration node answers no requests
    assert "dense_min_interval_s" in by_name              # but waits for the peers' answer interval


@pytest.mark.parametrize("param,value", [
    (Param("x", 1.0, "", 0.0, 2.0), 3.0),
    (Param("x", 1, "", 0, 10), "5"),
    (Param("x", "float16", "", choices=("float16", "int8")), "bogus"),
])
def test_bad_values_are_refused_with_the_reason(param, value):
    with pytest.raises(ParameterError, match="'x'"):
        check(param, value)


def test_an_empty_peer_list_means_discovery_and_names_must_start_topics():
    from sgreg_core.runtime.auth import is_agent_id
    from sgreg_ros.params import frame_ok

    peers = next(p for p in REGISTRATION if p.name == "peers")
    assert check(peers, None) == []      # what rclpy hands over for "-p peers:=[]" (documented)
    assert [n for n in ("a", "robot_2", "B7") if is_agent_id(n)] == ["a", "robot_2", "B7"]
    assert not any(is_agent_id(n) for n in ("1a", "a-b", "a__b", "_a", "", "a/b"))
    assert frame_ok("sgreg_merged") and frame_ok("site/merged")
    assert not any(frame_ok(f) for f in ("", "a//b", "a-b", " merged"))


@pytest.mark.parametrize("names", [["_a", "b"], ["a__b", "b"], ["a", "a"], ["1a", "b"]])
def test_sgreg_agents_refuses_names_the_nodes_would_refuse(names, capsys):
    from sgreg_cli.main import main

    assert main(["agents", "--names", *names]) == 2       # before any node is started
    assert capsys.readouterr().err.startswith("sgreg agents: agent names must be distinct agent ids")


def test_sgreg_agents_refuses_what_its_nodes_could_not_use_before_starting_them(tmp_path, capsys, monkeypatch):
    """A node without its model or key stays up and reports ERROR (a robot's node should), so
    `sgreg agents` would have run on with nodes that do nothing."""
    from sgreg_cli import processes
    from sgreg_cli.main import main
    from sgreg_core.runtime.auth import init_keystore

    def no_node(*args, **kwargs):
        raise AssertionError("a node was started")

    monkeypatch.setattr(processes, "start_agents", no_node)
    init_keystore(tmp_path / "keys", ["a"])
    (tmp_path / "a_file").write_text("")
    for extra, words in ((["--weights", str(tmp_path / "w.safetensors")], "model weights need"),
                         (["--params-file", str(tmp_path / "none.yaml")], "cannot read --params-file"),
                         (["--keystore", str(tmp_path)], "is not a keystore"),
                         (["--keystore", str(tmp_path / "keys")], "no private key of agent 'b'"),
                         (["--log-dir", str(tmp_path / "a_file")], "cannot create folder")):
        assert main(["agents", "--names", "a", "b", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith("sgreg agents: ") and words in err and err.count("\n") == 1, err


def test_a_params_file_is_read_before_any_node_starts(tmp_path, capsys, monkeypatch):
    """Names no node has are warned about (a typo would silently leave the default); a file
    that is not a ROS parameter file is refused in one line."""
    from sgreg_cli import processes
    from sgreg_cli.main import main
    from sgreg_ros.params import unknown_parameters

    known = {p.name for p in AGENT + REGISTRATION}
    assert unknown_parameters(["agree_m", "use_sim_time", "qos_overrides./tf.publisher.depth"], known) == []
    assert unknown_parameters(["agre_m", "zzz"], known) == [
        "'agre_m' is not a parameter of sgreg's nodes: ignored (did you mean 'agree_m'?)",
        "'zzz' is not a parameter of sgreg's nodes: ignored"]
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**:\n  ros__parameters:\n    agre_m: 0.4\n    qos_overrides:\n      /tf:\n"
                    "        publisher:\n          depth: 10\n")
    assert processes.check_params_file(YAML) == []
    shared = tmp_path / "shared.yaml"     # blocks of other nodes are theirs; sgreg's are checked
    shared.write_text("/mapper:\n  ros__parameters:\n    voxel: 1\n"
                      "a:\n  registration:\n    ros__parameters:\n      agre_m: 0.4\n")
    assert processes.check_params_file(shared) == [unknown_parameters(["agre_m"], known)[0]]
    assert processes.check_params_file(typo) == [unknown_parameters(["agre_m"], known)[0]]

    class Started(Exception):
        pass

    def started(*args, **kwargs):
        raise Started

    monkeypatch.setattr(processes, "start_agents", started)
    with pytest.raises(Started):      # a warning, and the nodes start
        main(["agents", "--names", "a", "--params-file", str(typo)])
    assert capsys.readouterr().err == (f"sgreg agents: warning: --params-file {typo}: 'agre_m' is not a "
                                       "parameter of sgreg's nodes: ignored (did you mean 'agree_m'?)\n")
    for text, words in (("/**:\n  ros__parameters:\n    a: [1, 2\n", "not YAML (expected ',' or ']'"),
                        ("agree_m: 0.4\n", "no 'ros__parameters' mapping")):
        typo.write_text(text)
        assert main(["agents", "--names", "a", "--params-file", str(typo)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"sgreg agents: --params-file {typo}: {words}") and err.count("\n") == 1, err


def test_a_replay_scores_the_merge_with_the_settings_its_nodes_ran():
    """The merged-map score of `sgreg replay` / bench-replay re-runs the merger: with the merge
    settings the agent's registration node gets from the parameter file, as ROS applies its
    blocks (wildcards, a later block winning, bare or other nodes' names not), not the
    defaults; a value the node would refuse is a one-line error before any replay."""
    from sgreg_cli.processes import DEFAULT_PARAMS, merge_config_of
    from sgreg_core.runtime.merge import MergeConfig

    assert merge_config_of(None, "a") == MergeConfig()
    assert merge_config_of(DEFAULT_PARAMS.read_bytes(), "a") == MergeConfig()   # the shipped file
    params = (b"/**:\n  ros__parameters:\n    cycle_m: 3.0\n    merged_frame: world\n"
              b"/**/registration:\n  ros__parameters:\n    cycle_deg: 12.0\n"
              b"/a/registration:\n  ros__parameters:\n    cycle_m: 2\n"
              b"/**/agent:\n  ros__parameters:\n    max_link_age_s: 9.0\n"
              b"registration:\n  ros__parameters:\n    max_link_age_s: 8.0\n")
    a, b = merge_config_of(params, "a"), merge_config_of(params, "b")
    assert (a.cycle_m, a.cycle_deg, a.merged_frame, a.max_link_age_s) == (2.0, 12.0, "world", 0.0)
    assert (b.cycle_m, b.cycle_deg) == (3.0, 12.0)
    for bad in (b"/**:\n  ros__parameters:\n    cycle_m: abc\n", b"/**:\n  ros__parameters:\n    cycle_m: -1.0\n",
                b"not: [a parameter file\n", b"\xff\xfe"):
        with pytest.raises(ValueError):
            merge_config_of(bad, "a")
