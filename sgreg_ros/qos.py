"""QoS of every sgreg topic, in one place.

- mapping/instances: reliable, depth 2, volatile. Each message is a full snapshot; only the
  newest matters, but a lost one costs a second of map growth, so reliable.
- sgreg/coarse: reliable, depth 1, transient local. A late joiner (or a restarted peer) gets
  the latest coarse graph at once instead of waiting a period; older ones are worthless to it.
  Subscribers keep 4: a registration node busy with a dense estimate (a second or so) then
  still sees every sequence number, so duplicates, gaps and restarts are all noticed.
- sgreg/dense_request: reliable, depth 10, volatile. Small; each must arrive once.
- sgreg/dense: reliable, depth 2, volatile. Large and only sent on request; never replayed to
  late joiners (that would resend megabytes nobody asked for).
- sgreg/transform, sgreg/registration: reliable, depth 10, volatile.
- /diagnostics: reliable, depth 10, volatile, like diagnostic_updater's, so that
  rqt_robot_monitor, the diagnostic aggregator and Foxglove all match it.
- /tf: reliable, depth 100, volatile, as tf2_ros's TransformBroadcaster (RViz, tf2 listeners).
- /tf_static (bags only): reliable, depth 1, transient local, as tf2_ros's static broadcaster.
- sgreg/markers, sgreg/merged_cloud: reliable, depth 1, transient local: a viewer that opens
  late gets the last picture at once.
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def _qos(depth: int, transient: bool = False) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


INSTANCES = _qos(2)
COARSE = _qos(1, transient=True)
COARSE_SUB = _qos(4, transient=True)
DENSE_REQUEST = _qos(10)
DENSE = _qos(2)
RESULTS = _qos(10)
DIAGNOSTICS = _qos(10)
TF = _qos(100)
TF_STATIC = _qos(1, transient=True)
VIEW = _qos(1, transient=True)
