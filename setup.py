"""One ament_python package, sgreg_ros, that also carries the pure library sgreg_core and the
command-line tool sgreg_cli."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sgreg_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="SG-Reg semantic scene-graph registration as ROS 2 multi-agent nodes",
    license="MIT",
    python_requires=">=3.11",
    packages=find_packages(include=["sgreg_core", "sgreg_core.*", "sgreg_ros", "sgreg_ros.*",
                                    "sgreg_cli", "sgreg_cli.*"]),
    package_data={"sgreg_core": ["weights/*.safetensors", "weights/*.json", "weights/*.npz"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/profiles", glob("config/profiles/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
        (f"share/{PACKAGE}/foxglove", glob("foxglove/*.json")),
        # `ros2 run sgreg_ros agent`: the short names live only here, not on PATH
        (f"lib/{PACKAGE}", glob("executables/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    entry_points={
        "console_scripts": [
            "sgreg = sgreg_cli.main:main",
            "sgreg-agent = sgreg_ros.main:agent",
            "sgreg-registration = sgreg_ros.main:registration",
        ],
    },
)
