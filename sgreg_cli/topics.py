"""Topic names as a user types them on the command line, resolved as a node in the root
namespace resolves them (ros2 topic / ros2 bag do the same): `b/mapping/instances` is
`/b/mapping/instances`. A name ROS would refuse is an argparse error, in one line."""
from __future__ import annotations

import argparse
import re

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(rf"/?{_TOKEN}(/{_TOKEN})*")


def topic_name(text: str) -> str:
    """argparse type: the absolute topic name of `text`."""
    if not _NAME.fullmatch(text) or "__" in text:
        raise argparse.ArgumentTypeError(f"{text!r} is not a ROS topic name (tokens of letters, digits "
                                         "and '_' that do not start with a digit, joined by '/')")
    return text if text.startswith("/") else "/" + text
