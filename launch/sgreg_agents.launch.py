"""Launch the agent and registration nodes of N agents (full ROS 2 install):

    ros2 launch sgreg_ros sgreg_agents.launch.py agents:=a,b,c [params_file:=...] [weights_path:=...]

Each agent gets its own namespace (/a, /b, ...); one parameter file serves them all. Without
ros2launch (ROS from wheels), `sgreg agents --names a b c` starts the same processes."""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    agents = [a.strip() for a in LaunchConfiguration("agents").perform(context).split(",") if a.strip()]
    params = LaunchConfiguration("params_file").perform(context)
    weights = LaunchConfiguration("weights_path").perform(context)
    overrides = {"weights_path": weights} if weights else {}
    return [Node(package="sgreg_ros", executable=exe, namespace=agent, name=exe,
                 parameters=[params, overrides], output="screen", emulate_tty=True)
            for agent in agents for exe in ("agent", "registration")]


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("sgreg_ros"), "config", "sgreg.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("agents", default_value="a,b", description="comma-separated agent ids"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="parameter file of every node (default: the shipped "
                                          "config/sgreg.yaml; a profile: config/profiles/*.yaml)"),
        DeclareLaunchArgument("weights_path", default_value="", description="empty: the shipped model"),
        OpaqueFunction(function=_nodes),
    ])
