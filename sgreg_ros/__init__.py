"""sgreg_ros: thin rclpy nodes over sgreg_core (parameters in, messages <-> core types, timers, QoS)."""

# `ros2 run sgreg_ros <name>` (lib/sgreg_ros/<name>); on PATH they are `sgreg-<name>` (setup.py)
EXECUTABLES = ("agent", "registration")
