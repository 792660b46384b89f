"""Start and stop the node processes of N agents on one machine: what a launch file does on a
full ROS 2 install, for `sgreg agents` and `sgreg replay`."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from sgreg_ros import EXECUTABLES

def _shipped_params() -> Path | None:
    """config/sgreg.yaml of the repository, else of the installed package (colcon), else None."""
    repo = Path(__file__).resolve().parent.parent / "config" / "sgreg.yaml"
    if repo.exists():
        return repo
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        installed = Path(get_package_share_directory("sgreg_ros")) / "config" / "sgreg.yaml"
    except PackageNotFoundError:
        return None
    return installed if installed.exists() else None


DEFAULT_PARAMS = _shipped_params()


@dataclass
class NodeProcess:
    agent: str
    executable: str
    proc: subprocess.Popen
    log_path: Path | None = None


def check_params_file(path: str | Path | None) -> list[str]:
    """ValueError in one line when the nodes could not read `path` as a ROS parameter file
    (else they fail only once started, each in its own log); else one warning line per name in
    it for sgreg's nodes that they do not have (sgreg_ros.params.unknown_parameters), checked
    against the shipped file, which holds every one (a test keeps it so)."""
    if not path:
        return []
    from sgreg_ros.params import parameter_file_names, unknown_parameters

    try:
        given = parameter_file_names(path)
    except OSError as exc:
        raise ValueError(f"cannot read --params-file {path}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise ValueError(f"--params-file {path}: {exc}") from None
    return [] if DEFAULT_PARAMS is None else unknown_parameters(given, parameter_file_names(DEFAULT_PARAMS))


def node_config_of(cls, params: bytes | None, agent: str):
    """The cls (a config whose fields the registration node declares as parameters, e.g.
    MergeConfig, PeersConfig) that agent's registration node runs when started with the
    parameter file of these contents (None: no file, the defaults), so that a replay scores what
    the agents ran. ValueError (one line) when a value in it is not one the node takes: the node
    would have refused to start."""
    from sgreg_ros.params import ParameterError, check, params_of, parameter_values_for

    if params is None:
        return cls()
    try:
        values = parameter_values_for(params.decode(), f"/{agent}/registration")
    except UnicodeDecodeError:
        raise ValueError("parameter file: not text") from None
    picked = {}
    for p in params_of(cls):
        if p.name in values:
            try:
                picked[p.name] = check(p, values[p.name])
            except ParameterError as exc:
                raise ValueError(f"parameter file: {exc}") from None
    return cls(**picked)


def merge_config_of(params: bytes | None, agent: str):
    """The MergeConfig that agent's registration node runs (node_config_of)."""
    from sgreg_core.runtime.merge import MergeConfig

    return node_config_of(MergeConfig, params, agent)


def read_params(params_file: str | Path | None) -> bytes | None:
    """The bytes of the parameter file nodes started with params_file read (None: the shipped
    one), None when there is none; ValueError (one line) when it cannot be read."""
    path = params_file or DEFAULT_PARAMS
    try:
        return None if path is None else Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read --params-file {path}: {exc.strerror or exc}") from None


def node_command(executable: str, agent: str, params_file: str | Path | None = DEFAULT_PARAMS,
                 overrides: dict | None = None) -> list[str]:
    """The command line of one node: `python -m sgreg_ros <exe> --ros-args -r __ns:=/<agent> ...`.
    params_file None: no parameter file, only the nodes' defaults and `overrides`."""
    cmd = [sys.executable, "-m", "sgreg_ros", executable, "--ros-args", "-r", f"__ns:=/{agent}"]
    if params_file:
        cmd += ["--params-file", str(params_file)]
    for key, value in (overrides or {}).items():
        if isinstance(value, bool):
            value = str(value).lower()
        elif isinstance(value, (list, tuple)):
            value = "[" + ",".join(f"'{v}'" if isinstance(v, str) else str(v) for v in value) + "]"
        cmd += ["-p", f"{key}:={value}"]
    return cmd


def start_agents(names: list[str], params_file=DEFAULT_PARAMS, overrides: dict | None = None,
                 log_dir: Path | None = None, executables=EXECUTABLES,
                 log_suffix: str = "") -> list[NodeProcess]:
    """One process per (agent, executable), each in its own process group."""
    procs = []
    for name in names:
        for exe in executables:
            log_path = None
            out = None
            if log_dir is not None:
                log_dir.mkdir(parents=True, exist_ok=True)
                log_path = log_dir / f"{name}_{exe}{log_suffix}.log"
                out = open(log_path, "w")
            proc = subprocess.Popen(node_command(exe, name, params_file, overrides),
                                    stdout=out, stderr=subprocess.STDOUT if out else None,
                                    env=dict(os.environ), start_new_session=True)
            procs.append(NodeProcess(name, exe, proc, log_path))
    return procs


def stop(procs: list[NodeProcess], timeout: float = 10.0) -> None:
    """SIGINT every node (a clean rclpy shutdown), then SIGKILL what is left after `timeout`."""
    for p in procs:
        if p.proc.poll() is None:
            try:
                os.killpg(p.proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(p.proc.pid, signal.SIGKILL)
            p.proc.wait()


def kill(procs: list[NodeProcess]) -> None:
    """SIGKILL, no clean shutdown: a crash."""
    for p in procs:
        try:
            os.killpg(p.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        p.proc.wait()
