"""The package as ROS finds it: what `ros2 run sgreg_ros <exe>` and `ros2 launch sgreg_ros ...`
resolve in the prefix on AMENT_PREFIX_PATH (the venv, written by setup.sh as colcon would
install it), and package.xml's dependencies against the requirements."""
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from ament_index_python.packages import get_package_prefix, get_package_share_directory

from sgreg_ros import EXECUTABLES

ROOT = Path(__file__).resolve().parents[2]
# requirement -> its rosdep key; the others have none and are listed in package.xml's comment
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "PyYAML": "python3-yaml",
               "psutil": "python3-psutil", "torch": "python3-torch", "tqdm": "python3-tqdm",
               "matplotlib": "python3-matplotlib", "rosbags": "python3-rosbags-pip",
               "mcap-ros2-support": "mcap-ros2-support", "mcap": "mcap-ros2-support"}
TEST_TOOLS = {"pytest", "pytest-timeout", "pytest-xdist"}


def test_ros2_run_and_launch_find_what_the_repository_ships():
    prefix = Path(get_package_prefix("sgreg_ros"))
    share = Path(get_package_share_directory("sgreg_ros"))
    for exe in (*EXECUTABLES, "sgreg"):
        path = prefix / "lib" / "sgreg_ros" / exe
        assert path.is_file() and os.access(path, os.X_OK), path
        res = subprocess.run([str(path), "--help"], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0 and res.stdout.startswith("usage:"), (exe, res.stderr[-500:])
    shipped = ["package.xml", "config/sgreg.yaml", *(f"config/profiles/{p.name}" for p in
                                                      (ROOT / "config" / "profiles").glob("*.yaml")),
               *(f"launch/{p.name}" for p in (ROOT / "launch").glob("*.py"))]
    assert len(shipped) >= 5
    for name in shipped:
        assert (share / name).read_bytes() == (ROOT / name).read_bytes(), f"{share / name} is not the repository's"


def test_package_xml_declares_every_python_requirement():
    text = (ROOT / "package.xml").read_text()
    root = ET.fromstring(text)
    declared = {e.text for e in root.iter() if e.tag in ("depend", "exec_depend")}
    without_key = set(re.search(r"no-rosdep-key:([^\n]*?)(-->|\n)", text).group(1).split())
    for req in ("core.txt", "torch.txt"):
        for line in (ROOT / "requirements" / req).read_text().splitlines():
            name = re.split(r"[=<>~ ]", line.split("#")[0].strip(), maxsplit=1)[0]
            if not name or name in TEST_TOOLS:
                continue
            assert ROSDEP_KEYS.get(name) in declared or name in without_key, \
                f"package.xml neither depends on {name} (rosdep key) nor names it among those without one"


def test_an_executable_started_by_another_python_says_which_environment_it_needs():
    """In a colcon install, `ros2 run` starts lib/sgreg_ros/<exe> (executables/<exe>) with the
    first python3 on PATH; in a shell where the venv sgreg was installed into is not active,
    that Python has ROS but not torch and the rest: one line that says what to do, exit 2, no
    traceback. Here torch is taken away from this Python. A module of sgreg's own that will not
    import is a bug, not the environment: its traceback stays."""
    def start(exe, blocked):
        script = ROOT / "executables" / exe
        code = (f"import sys; sys.modules[{blocked!r}] = None; "
                f"sys.argv = [{str(script)!r}, '--ros-args', '-r', '__ns:=/a']; "
                f"exec(compile(open({str(script)!r}).read(), {str(script)!r}, 'exec'))")
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)

    for exe in EXECUTABLES:
        res = start(exe, "torch")
        assert res.returncode == 2, (exe, res.stderr[-1000:])
        assert "refusing to start" in res.stderr and "torch" in res.stderr \
            and "bin/activate" in res.stderr and "Traceback" not in res.stderr, res.stderr[-1000:]
    res = start("agent", "sgreg_core.runtime.agent")
    assert res.returncode not in (0, 2) and "Traceback" in res.stderr and "refusing" not in res.stderr, \
        res.stderr[-1000:]
