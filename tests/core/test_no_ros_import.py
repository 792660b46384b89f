"""sgreg_core is a pure library: importing it (every one of its modules) must pull in no ROS
module. The command-line tool (sgreg_cli) and the nodes (sgreg_ros) are where ROS enters."""
import subprocess
import sys

ROS_PREFIXES = ("rclpy", "rosidl", "rcl_interfaces", "sgreg_msgs", "std_msgs", "sensor_msgs",
                "geometry_msgs", "builtin_interfaces", "sgreg_ros", "rosbags", "mcap_ros2")

CODE = """
import importlib, pkgutil, sys
import sgreg_core
for m in pkgutil.walk_packages(sgreg_core.__path__, "sgreg_core."):
    importlib.import_module(m.name)
print("\\n".join(sorted(sys.modules)))
"""


def test_importing_sgreg_core_pulls_in_no_ros():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
    modules = out.stdout.split()
    assert "sgreg_core" in modules
    leaked = [m for m in modules if m.split(".")[0] in ROS_PREFIXES]
    assert not leaked, f"sgreg_core imported ROS modules: {leaked[:10]}"
