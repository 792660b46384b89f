"""sensor_msgs/PointCloud2 <-> numpy for the clouds sgreg sends: float32 x, y, z plus one uint32
field (the instance id or the node id).

Big clouds are assigned as `bytes` (a few ms per 5 MB); assigning numpy arrays to ROS message
fields costs per-element checks (~0.4 s per 5 MB).
"""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

POINT_STEP = 16  # 3 x float32 + 1 x uint32


class PointCloudError(ValueError):
    """A PointCloud2 that is not the x, y, z (float32) + <id> (uint32) layout sgreg uses."""


def pack_xyz_id(points: np.ndarray, ids: np.ndarray, id_field: str, frame_id: str = "",
                stamp=None) -> PointCloud2:
    """Pack (N, 3) float32 points and (N,) ids into an unorganised PointCloud2."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    ids = np.asarray(ids).reshape(-1)
    if ids.shape[0] != points.shape[0]:
        raise PointCloudError(f"{points.shape[0]} points but {ids.shape[0]} ids")
    record = np.empty(points.shape[0], dtype=_record_dtype(id_field))
    record["x"], record["y"], record["z"] = points[:, 0], points[:, 1], points[:, 2]
    record[id_field] = ids.astype(np.uint32)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.height = 1
    msg.width = int(points.shape[0])
    msg.fields = [
        PointField(name="x", offset=0, datatype=PointField.FLOAT32, count=1),
        PointField(name="y", offset=4, datatype=PointField.FLOAT32, count=1),
        PointField(name="z", offset=8, datatype=PointField.FLOAT32, count=1),
        PointField(name=id_field, offset=12, datatype=PointField.UINT32, count=1),
    ]
    msg.is_bigendian = False
    msg.point_step = POINT_STEP
    msg.row_step = POINT_STEP * msg.width
    msg.is_dense = True
    msg.data = record.tobytes()
    return msg


def unpack_xyz_id(msg: PointCloud2, id_field: str) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float32 points and (N,) uint32 ids from a PointCloud2; raises PointCloudError."""
    offsets = {f.name: (f.offset, f.datatype) for f in msg.fields}
    want = {"x": PointField.FLOAT32, "y": PointField.FLOAT32, "z": PointField.FLOAT32,
            id_field: PointField.UINT32}
    for name, datatype in want.items():
        if name not in offsets:
            raise PointCloudError(f"PointCloud2 has no '{name}' field")
        if offsets[name][1] != datatype:
            raise PointCloudError(f"PointCloud2 field '{name}' has datatype {offsets[name][1]}")
    # which of two fields of one name is meant, or what the other values of a field with count
    # > 1 are, nobody can say: such a cloud is refused, not read one way
    named = [f.name for f in msg.fields if f.name in want]
    if len(named) != len(want) or any(f.count != 1 for f in msg.fields if f.name in want):
        raise PointCloudError(f"PointCloud2 fields {sorted(want)} must each appear once with count 1")
    if msg.is_bigendian:
        raise PointCloudError("big-endian PointCloud2 is not supported")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = bytes(msg.data) if not isinstance(msg.data, (bytes, bytearray, memoryview)) else msg.data
    if step < POINT_STEP or len(data) != n * step:
        raise PointCloudError(f"PointCloud2 data is {len(data)} bytes, expected {n} x {step}")
    starts = sorted(offsets[k][0] for k in want)     # 4-byte fields that must not overlap
    if any(not 0 <= offsets[k][0] <= step - 4 for k in want) or min(np.diff(starts)) < 4:
        raise PointCloudError(f"PointCloud2 field offsets {[offsets[k][0] for k in want]} do not fit "
                              f"a point of {step} bytes")
    dtype = np.dtype({
        "names": list(want),
        "formats": ["<f4", "<f4", "<f4", "<u4"],
        "offsets": [offsets[k][0] for k in want],
        "itemsize": step,
    })
    record = np.frombuffer(data, dtype=dtype, count=n)
    points = np.stack([record["x"], record["y"], record["z"]], axis=1).astype(np.float32)
    return points, record[id_field].astype(np.uint32)


def _record_dtype(id_field: str) -> np.dtype:
    return np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), (id_field, "<u4")])
