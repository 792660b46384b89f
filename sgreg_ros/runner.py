"""Start-up and shutdown shared by the executables.

SIGINT and SIGTERM are taken over before anything heavy is imported, so that Ctrl-C at any
moment (while torch loads, while the model loads, during a dense estimate) ends the node with
exit code 0 and no traceback, within a second:
- the first signal asks the spin loop to stop, and arms a watchdog that ends the process after
  EXIT_GRACE_S if a long callback or start-up still holds it (the node has nothing to save);
- later signals change nothing: a terminal sends SIGINT to every process of its group and
  `ros2 launch` sends its own SIGINT (then SIGTERM) on top, which used to interrupt the
  clean-up with a KeyboardInterrupt traceback.
rclpy's own signal handlers are switched off; the node spins in short slices so the Python
handler runs promptly."""
from __future__ import annotations

import os
import signal
import sys
import threading

EXIT_GRACE_S = 0.7
SPIN_SLICE_S = 0.1


class StopRequest:
    """Set by SIGINT / SIGTERM; the first one arms the watchdog."""

    def __init__(self):
        self.requested = False

    def __call__(self, signum, frame) -> None:
        if self.requested:
            return
        self.requested = True
        watchdog = threading.Timer(EXIT_GRACE_S, os._exit, (0,))
        watchdog.daemon = True
        watchdog.start()

    def install(self) -> StopRequest:
        signal.signal(signal.SIGINT, self)
        signal.signal(signal.SIGTERM, self)
        return self


_STOP: StopRequest | None = None


def install_stop() -> StopRequest:
    """The process's StopRequest, installed on first use: the executables call this before
    anything else is imported, run_node again (a no-op then)."""
    global _STOP
    if _STOP is None:
        _STOP = StopRequest().install()
    return _STOP


def missing_params_files(args: list[str]) -> list[str]:
    """The --params-file arguments of a ROS command line that name no readable file: rclpy.init
    would fail on them with a traceback, after torch and the model had loaded."""
    return [path for flag, path in zip(args, args[1:])
            if flag == "--params-file" and not os.access(path, os.R_OK)]


def run_node(load_node_class, args=None) -> int:
    """load_node_class() imports the node's module (torch, the model) and returns its class."""
    stop = install_stop()
    missing = missing_params_files(sys.argv if args is None else args)
    if missing:
        print(f"[sgreg] refusing to start: parameter file {missing[0]!r} cannot be read",
              file=sys.stderr, flush=True)
        return 2
    try:
        from .params import ParameterError

        node_class = load_node_class()
        import rclpy
        import torch
        from rclpy.exceptions import NameValidationException
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
    except ModuleNotFoundError as exc:
        if (exc.name or "").partition(".")[0] in ("sgreg_core", "sgreg_ros", "sgreg_cli"):
            raise     # a module of sgreg's own: a bug or a broken install, not the environment
        # `ros2 run` starts lib/sgreg_ros/<exe> with the first python3 on PATH: in a shell where
        # the environment sgreg was installed into is not active, that is another Python
        venv = " (this Python is a venv: if it is sgreg's, install requirements/core.txt into it)" \
            if sys.prefix != sys.base_prefix else ""
        print(f"[sgreg] refusing to start: {exc} for {sys.executable}; run the node from the "
              "Python environment sgreg was installed into (source its bin/activate in this "
              f"shell, then install/setup.bash){venv}", file=sys.stderr, flush=True)
        return 2

    # One torch thread per node: the graphs are small, and each robot runs two nodes; several
    # threads per process only fight over the cores (measured several times slower under load).
    torch.set_num_threads(1)
    if stop.requested:
        return 0
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - rclpy's RCLError: e.g. a parameter file that is no YAML
        print(f"[sgreg] refusing to start: ROS could not start with these arguments: "
              f"{' '.join(str(exc).split())}", file=sys.stderr, flush=True)
        return 2
    node = None
    try:
        node = node_class()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop.requested and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_SLICE_S)
        return 0
    except (ParameterError, NameValidationException) as exc:   # the latter: e.g. __ns:=/1a
        print(f"[sgreg] refusing to start: {' '.join(str(exc).split())}", file=sys.stderr, flush=True)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
