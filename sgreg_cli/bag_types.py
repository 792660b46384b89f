"""The rosbags typestore for sgreg bags: ROS 2 Jazzy's standard types plus sgreg_msgs, registered
from the same .msg text that rosidl built (installed under share/sgreg_msgs/msg)."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

SGREG_TYPES = ("InstanceMap", "CoarseGraph", "DenseRequest", "DenseGraph", "RegistrationResult")


def msg_dir() -> Path:
    """The directory holding sgreg_msgs' .msg files (installed share/, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("sgreg_msgs")) / "msg"
        if installed.is_dir():
            return installed
    except Exception:  # ament index not set up: fall back to the source tree
        pass
    return Path(__file__).resolve().parent.parent / "msg_schemas" / "msg"


@lru_cache(maxsize=1)
def typestore():
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name in SGREG_TYPES:
        text = (msg_dir() / f"{name}.msg").read_text()
        types.update(get_types_from_msg(text, f"sgreg_msgs/msg/{name}"))
    store.register(types)
    return store
