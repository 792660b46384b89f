"""RViz / Foxglove views of an agent's registration as ROS messages (geometry in
sgreg_core/runtime/views.py): visualization_msgs/MarkerArray of its scene graph (in <id>/map)
and of the node matches of its verified links (in the merged frame), and the merged cloud as a
PointCloud2 with an "rgb" field (every map the agent knows of, each agent in its colour)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from sgreg_core.runtime.views import GraphView

from .pointcloud import pack_xyz_id


def _marker(ns: str, mid: int, kind: int, frame: str, stamp) -> Marker:
    m = Marker()
    m.header.frame_id, m.header.stamp = frame, stamp
    m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
    m.pose.orientation.w = 1.0
    return m


def _point(p) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _color(rgb, a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=a)


def graph_markers(view: GraphView, frame: str, stamp, ns: str = "graph") -> list[Marker]:
    """A translucent box per node coloured by its label, its label as text, and the edges."""
    clear = _marker("", 0, Marker.CUBE, frame, stamp)
    clear.action = Marker.DELETEALL       # an empty namespace: every marker of the last view goes
    out = [clear]
    for k, (c, e, rgb, label) in enumerate(zip(view.centers, view.extents, view.colors, view.labels)):
        box = _marker(f"{ns}/nodes", k, Marker.CUBE, frame, stamp)
        box.pose.position = _point(c)
        box.scale.x, box.scale.y, box.scale.z = (float(max(v, 0.02)) for v in e)
        box.color = _color(rgb, 0.45)
        text = _marker(f"{ns}/labels", k, Marker.TEXT_VIEW_FACING, frame, stamp)
        text.pose.position = _point(c + np.array([0.0, 0.0, e[2] / 2 + 0.15]))
        text.scale.z = 0.18
        text.color = _color((1.0, 1.0, 1.0))
        text.text = label
        out += [box, text]
    edges = _marker(f"{ns}/edges", 0, Marker.LINE_LIST, frame, stamp)
    edges.scale.x = 0.015
    edges.color = _color((0.6, 0.6, 0.6), 0.6)
    edges.points = [_point(view.centers[i]) for pair in view.edges for i in pair]
    return out + [edges]


def match_marker(lines: np.ndarray, peer: str, frame: str, stamp, rgb) -> Marker:
    """The node matches of the link to `peer` as line segments in the merged frame."""
    m = _marker(f"matches/{peer}", 0, Marker.LINE_LIST, frame, stamp)
    m.scale.x = 0.03
    m.color = _color(rgb, 0.9)
    m.points = [_point(p) for seg in lines for p in seg]
    return m


def markers_msg(markers: list[Marker]) -> MarkerArray:
    msg = MarkerArray()
    msg.markers = markers
    return msg


def cloud_msg(points: np.ndarray, rgb: np.ndarray, frame: str, stamp):
    """PointCloud2 (x, y, z, rgb): RViz's RGB8 and Foxglove's rgb colour modes read it."""
    return pack_xyz_id(points, rgb, "rgb", frame_id=frame, stamp=stamp)
