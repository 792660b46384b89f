"""Start-up and shutdown shared by the executables: init, build the node, spin, and turn Ctrl-C,
SIGTERM and bad parameters into a clean exit."""
from __future__ import annotations

import sys

import rclpy
import torch
from rclpy.executors import ExternalShutdownException

from .params import ParameterError


def run_node(factory, args=None) -> int:
    # One torch thread per node: the graphs are small, and each robot runs two nodes; several
    # threads per process only fight over the cores (measured several times slower under load).
    torch.set_num_threads(1)
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
        return 0
    except ParameterError as exc:
        print(f"[sgreg] refusing to start: {exc}", file=sys.stderr, flush=True)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
