"""A separate process for the DDS round-trip test: subscribes to in/<Type> for every sgreg_msgs
type and republishes each message, deserialised and re-serialised by rclpy, on out/<Type>."""
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy

import sgreg_msgs.msg as msgs

TYPES = ("InstanceMap", "CoarseGraph", "DenseRequest", "DenseGraph", "RegistrationResult")


def main():
    rclpy.init()
    node = rclpy.create_node("sgreg_echo")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {}
    for name in TYPES:
        cls = getattr(msgs, name)
        pubs[name] = node.create_publisher(cls, f"out/{name}", qos)
        node.create_subscription(cls, f"in/{name}", lambda m, n=name: pubs[n].publish(m), qos)
    print("echo ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
