"""sgreg_ros: thin rclpy nodes over sgreg_core (parameters in, messages <-> core types, timers, QoS)."""

# Executables under lib/sgreg_ros (`ros2 run sgreg_ros <name>`); setup.py's console_scripts match.
EXECUTABLES = ("agent", "registration")
