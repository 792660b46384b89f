"""The shipped RViz config and Foxglove layout show what the nodes publish: the merged frame's
name and the view topics of the registration node."""
import json
from pathlib import Path

import yaml

from sgreg_core.runtime.merge import MergeConfig

ROOT = Path(__file__).resolve().parents[2]


def topics_in(obj) -> set[str]:
    found = set()
    if isinstance(obj, dict):
        for k, v in obj.items():
            if isinstance(k, str) and k.startswith("/"):
                found.add(k)
            found |= topics_in(v)
    elif isinstance(obj, list):
        for v in obj:
            found |= topics_in(v)
    elif isinstance(obj, str) and obj.startswith("/") and "/sgreg/" in obj:
        found.add(obj)
    return found


def test_rviz_config_shows_the_merged_frame_and_the_view_topics():
    cfg = yaml.safe_load((ROOT / "rviz" / "sgreg.rviz").read_text())
    manager = cfg["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == MergeConfig().merged_frame
    topics = {d["Topic"]["Value"] for d in manager["Displays"] if "Topic" in d}
    assert {"/a/sgreg/merged_cloud", "/a/sgreg/markers", "/b/sgreg/markers"} <= topics
    classes = {d["Class"] for d in manager["Displays"]}
    assert {"rviz_default_plugins/TF", "rviz_default_plugins/MarkerArray",
            "rviz_default_plugins/PointCloud2"} <= classes


def test_foxglove_layout_shows_the_merged_frame_and_the_view_topics():
    layout = json.loads((ROOT / "foxglove" / "sgreg.json").read_text())
    panel = layout["configById"]["3D!sgreg"]
    assert panel["followTf"] == MergeConfig().merged_frame
    assert {"/a/sgreg/merged_cloud", "/a/sgreg/markers"} <= set(panel["topics"])
    assert "/a/sgreg/registration.confidence" in json.dumps(layout)
    # every panel in the layout tree is configured
    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])
    assert set(leaves(layout["layout"])) <= set(layout["configById"])
