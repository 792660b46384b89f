"""`python -m sgreg_ros agent|registration --ros-args ...`: what `sgreg agents` and `sgreg replay`
start, with the interpreter that runs them."""
import sys

from . import EXECUTABLES
from .main import run_executable

if len(sys.argv) < 2 or sys.argv[1] not in EXECUTABLES:
    sys.exit(f"usage: python -m sgreg_ros {{{'|'.join(EXECUTABLES)}}} [--ros-args ...]")
sys.exit(run_executable(sys.argv[1]))
