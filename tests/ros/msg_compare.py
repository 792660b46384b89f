"""Turn any ROS 2 message object (rclpy, rosbags or mcap-ros2 decoded) into plain Python values,
so messages read back through different libraries can be compared field by field."""
from __future__ import annotations

import array

import numpy as np


def to_plain(msg, template):
    """Plain nested dict of `msg`, walking the field names of the rclpy message `template`."""
    if hasattr(template, "get_fields_and_field_types"):
        return {name: to_plain(getattr(msg, name), getattr(template, name))
                for name in template.get_fields_and_field_types()}
    if isinstance(template, (list, tuple)) and template and hasattr(template[0], "get_fields_and_field_types"):
        return [to_plain(m, t) for m, t in zip(msg, template)]
    if isinstance(msg, (bytes, bytearray, memoryview)):
        return bytes(msg)
    if isinstance(msg, (array.array, np.ndarray, list, tuple)):
        values = np.asarray(msg)
        if values.dtype == np.uint8 or (isinstance(msg, (list, tuple)) and msg and isinstance(msg[0], bytes)):
            return bytes(values.astype(np.uint8)) if values.dtype != object else list(msg)
        return values.tolist()
    if isinstance(msg, (np.floating, np.integer, np.bool_)):
        return msg.item()
    return msg
