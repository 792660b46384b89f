"""Synthetic furnished indoor scenes as instance maps.

Public API:
    SynthConfig                               dataclass, defaults matched to the ScanNet scans
    generate_scene(seed, cfg=SynthConfig()) -> InstanceMap     deterministic from the seed
    ROOM_TYPES                                room type -> furniture recipe

Defaults follow the real scans (../shared/data/scans): 450-1500 points per m^2 of surface
(mesh vertices), rooms of 3.5-7.5 m, 15-70 instances a room with many "otherprop"-like small
objects, walls split into several instances, a partial ceiling, about 5 % unlabelled points,
labels from the NYU40 names the scans carry mixed with open-set names.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..noise import NoiseConfig, apply_noise
from ...types import InstanceMap
from .layout import Placer, Room, Wall, add_openings, building, partition
from .objects import KINDS, Kind, build
from .shapes import Shapes, sample_shapes

# room type -> list of (kind or group, min count, max count), placed in this order
ROOM_TYPES: dict[str, list[tuple[str, int, int]]] = {
    "living room": [("sofa", 1, 1), ("armchair", 0, 2), ("tv stand", 0, 1), ("bookshelf", 0, 2), ("shelves", 0, 1),
                    ("cabinet", 0, 1), ("coffee table", 1, 1), ("side table", 0, 2), ("floor lamp", 0, 1), ("plant", 0, 3),
                    ("rug", 0, 1), ("ottoman", 0, 1), ("tv", 0, 1), ("lamp", 0, 1), ("books", 0, 2), ("pillow", 1, 4),
                    ("picture", 0, 2), ("radiator", 0, 1), ("box", 0, 2)],
    "bedroom": [("bed", 1, 1), ("night stand", 1, 2), ("wardrobe", 0, 1), ("dresser", 0, 1), ("desk set", 0, 1),
                ("bookshelf", 0, 1), ("plant", 0, 1), ("trash can", 0, 1), ("bag", 0, 2), ("box", 0, 3),
                ("lamp", 0, 2), ("pillow", 2, 4), ("books", 0, 2), ("mirror", 0, 1), ("picture", 0, 2), ("radiator", 0, 1)],
    "kitchen": [("counter", 1, 2), ("kitchen cabinet", 1, 4), ("refrigerator", 1, 1), ("oven", 0, 1), ("sink", 0, 1),
                ("dining set", 0, 1), ("washing machine", 0, 1), ("trash can", 1, 2), ("stool", 0, 2), ("microwave", 0, 1),
                ("wall cabinet", 0, 3), ("box", 0, 2), ("storage bin", 0, 1)],
    "bathroom": [("toilet", 1, 1), ("sink", 1, 1), ("bathtub", 0, 1), ("cabinet", 0, 1), ("trash can", 0, 1),
                 ("mirror", 1, 1), ("storage bin", 0, 1), ("washing machine", 0, 1)],
    "dining room": [("dining set", 1, 1), ("cabinet", 0, 2), ("shelves", 0, 1), ("plant", 0, 2), ("floor lamp", 0, 1),
                    ("picture", 0, 2), ("books", 0, 1), ("radiator", 0, 1)],
    "study": [("desk set", 1, 2), ("bookshelf", 1, 3), ("file cabinet", 0, 1), ("armchair", 0, 1), ("plant", 0, 1),
              ("trash can", 0, 1), ("box", 0, 3), ("bag", 0, 1), ("books", 0, 3), ("lamp", 0, 1), ("picture", 0, 1)],
    "open office": [("desk row", 1, 3), ("desk set", 1, 4), ("file cabinet", 0, 3), ("bookshelf", 0, 2), ("copier", 0, 1),
                    ("plant", 0, 3), ("trash can", 1, 3), ("coat rack", 0, 1), ("whiteboard", 0, 1), ("box", 0, 4),
                    ("printer", 0, 1), ("bag", 0, 2), ("books", 0, 3), ("fan", 0, 1), ("radiator", 0, 2)],
    "meeting room": [("meeting set", 1, 1), ("whiteboard", 0, 1), ("wall tv", 0, 1), ("cabinet", 0, 1), ("plant", 0, 2),
                     ("trash can", 0, 1), ("picture", 0, 1), ("chair", 0, 2)],
    "kitchenette": [("counter", 1, 1), ("refrigerator", 0, 1), ("sink", 0, 1), ("table", 0, 1), ("stool", 0, 3),
                    ("trash can", 1, 2), ("microwave", 0, 1), ("bench", 0, 1), ("wall cabinet", 0, 2)],
    "corridor": [("plant", 1, 4), ("trash can", 0, 2), ("bench", 0, 2), ("picture", 1, 4), ("radiator", 0, 2),
                 ("coat rack", 0, 1), ("file cabinet", 0, 1)],
}
APARTMENT = ["living room", "bedroom", "kitchen", "bathroom", "dining room", "study", "bedroom"]
OFFICE = ["open office", "meeting room", "kitchenette", "study", "meeting room", "open office"]
BUILDING = ["study", "bedroom", "meeting room", "open office", "kitchenette"]   # per run of rooms
# a building, not a city: ~70 000 points and 0.1 s a room; bench-scale's 2000-node graphs
# (AgentConfig.max_nodes) take ~215 rooms, and far more would only fill the memory for minutes
MAX_ROOMS = 500


@dataclass
class SynthConfig:
    kind: str = "apartment"            # "apartment", "office" or "building" (a corridor floor)
    rooms: int = 1                     # building: rooms besides the corridor
    run: int = 3                       # building: neighbouring rooms that are identical
    density: float = 650.0             # points per m^2 of surface (ScanNet vertices: 450-1500)
    density_jitter: float = 0.3        # per-scene density factor uniform in [1 - j, 1 + j]
    surface_noise: float = 0.005       # m, std of the noise on sampled points (mesh roughness)
    nyu40_prob: float = 0.6            # per kind and scene: label with the NYU40 class name
    repeat_prob: float = 0.8           # per kind and room: repeated objects are identical copies
    ceiling_prob: float = 0.75         # a room's ceiling is (partly) scanned
    ceiling_keep: tuple[float, float] = (0.2, 0.8)  # fraction of the ceiling that is scanned
    wall_split_prob: float = 0.4       # a long wall is segmented into two instances
    clutter: tuple[int, int] = (3, 12)  # small objects on floors and surfaces, per room
    unlabelled_prob: float = 0.3       # a clutter object stays unlabelled (instance 0)
    noise: NoiseConfig = field(default_factory=NoiseConfig)


SOFT_SEAT = {"bed": 0.52, "sofa": 0.42, "armchair": 0.42}   # seat heights of pillow hosts
CLUTTER = ["box", "books", "bag", "trash can", "storage bin", "laptop", "keyboard"]
FLOOR_COLORS = [(150, 110, 70), (128, 128, 128), (200, 200, 195), (110, 80, 60)]


class _Scene:
    """Collects instances (shapes in world frame) while a layout is furnished."""

    def __init__(self, cfg: SynthConfig, rng: np.random.Generator) -> None:
        self.cfg, self.rng = cfg, rng
        self.shapes = Shapes()
        self.labels: list[str | None] = []
        self.colors: list[np.ndarray] = []
        self.solids: list[tuple] = []      # (cx, cy, yaw, w, d, h) of footprints that hide surfaces
        self.label_of_kind: dict[str, str] = {}
        self.structural: list[bool] = []

    def label(self, kind: Kind) -> str:
        if kind.name not in self.label_of_kind:
            use_nyu = self.rng.random() < self.cfg.nyu40_prob
            self.label_of_kind[kind.name] = kind.nyu40 if use_nyu else kind.names[int(self.rng.integers(len(kind.names)))]
        return self.label_of_kind[kind.name]

    def add(self, shapes: Shapes, label: str | None, color, yaw=0.0, t=(0, 0, 0), structural=False) -> int:
        tag = len(self.labels)
        self.shapes.extend(shapes, yaw, t, tag)
        self.labels.append(label)
        jitter = self.rng.integers(-20, 21, 3)
        self.colors.append(np.clip(np.asarray(color) + jitter, 0, 255))
        self.structural.append(structural)
        return tag


class _RoomFurnisher:
    def __init__(self, scene: _Scene, room: Room, rng: np.random.Generator) -> None:
        self.scene, self.room, self.rng = scene, room, rng
        self.placer = Placer(room)
        self.cache: dict[str, tuple[tuple, Shapes]] = {}
        self.supports: list[tuple] = []    # (cx, cy, yaw, w, d, top_z, kind name, taken boxes)
        self.soft: list[tuple] = []        # the same for pillow hosts

    def shape(self, kind: Kind) -> tuple[tuple, Shapes]:
        """Size and surfaces; repeated kinds in a room are usually identical copies."""
        if kind.name in self.cache and self.rng.random() < self.scene.cfg.repeat_prob:
            return self.cache[kind.name]
        size = tuple(float(self.rng.uniform(*r)) for r in (kind.w, kind.d, kind.h))
        self.cache[kind.name] = (size, build(kind, size, self.rng))
        return self.cache[kind.name]

    def put(self, kind: Kind, size, shapes: Shapes, cx, cy, yaw, z=0.0, label: str | None = "") -> None:
        label = self.scene.label(kind) if label == "" else label
        self.scene.add(shapes, label, kind.color, yaw, (cx, cy, z))
        w, d, h = size
        if kind.solid:
            self.scene.solids.append((cx, cy, yaw, w, d, h + z))
        if kind.support:
            self.supports.append((cx, cy, yaw, w, d, z + h, kind.name, []))
        if kind.name in SOFT_SEAT:   # pillows lie on the seat, against the back
            self.soft.append((cx, cy, yaw, w * 0.85, d * 0.9, SOFT_SEAT[kind.name], kind.name, []))

    def place(self, name: str, label: str | None = "") -> bool:
        kind = KINDS[name]
        size, shapes = self.shape(kind)
        w, d, h = size
        if kind.placement == "top":
            return self.on_top(kind, size, shapes, label)
        if kind.placement == "mount":
            hit = self.placer.mount(w, kind.mount_z, h, self.rng)
            if hit is None:
                return False
            wall, s = hit
            p = wall.p0 + wall.u * s + wall.n * (d / 2 + 0.005)
            z = min(kind.mount_z + self.rng.normal(0, 0.05), self.room.height - h - 0.1)
            self.put(kind, size, shapes, p[0], p[1], float(np.arctan2(-wall.n[0], wall.n[1])), z, label)
            return True
        if kind.placement in ("wall", "corner"):
            pose = self.placer.wall(w, d, self.rng)
            if pose is None:
                return False
            cx, cy, yaw = pose[:3]
            if kind.placement == "corner":  # round things: any yaw, slightly off the wall
                yaw += self.rng.uniform(-np.pi, np.pi)
            self.put(kind, size, shapes, cx, cy, yaw, 0.0, label)
            return True
        pose = self.placer.free(w, d, self.rng, any_yaw=name in ("armchair", "ottoman", "stool"))
        if pose is None:
            return False
        self.put(kind, size, shapes, *pose, 0.0, label)
        return True

    def on_top(self, kind: Kind, size, shapes: Shapes, label) -> bool:
        w, d, _ = size
        if kind.name == "pillow":
            hosts = self.soft
        else:
            hosts = [s for s in self.supports if s[3] > w + 0.05 and s[4] > d + 0.05]
        for _ in range(10):
            if not hosts:
                return False
            cx, cy, yaw, sw, sd, top, _, taken = hosts[int(self.rng.integers(len(hosts)))]
            lx = self.rng.uniform(-(sw - w) / 2, (sw - w) / 2)
            ly = self.rng.uniform(-(sd - d) / 2, (sd - d) / 2)
            if kind.name == "pillow":
                ly = -(sd - d) / 2 + 0.05
            box = (lx - w / 2, ly - d / 2, lx + w / 2, ly + d / 2)
            if any(box[0] < b[2] and box[2] > b[0] and box[1] < b[3] and box[3] > b[1] for b in taken):
                continue
            taken.append(box)
            c, s = np.cos(yaw), np.sin(yaw)
            self.put(kind, size, shapes, cx + c * lx - s * ly, cy + s * lx + c * ly,
                     yaw + self.rng.normal(0, 0.1), top, label)
            return True
        return False

    def group(self, name: str) -> None:
        """Furniture sets: identical chairs around tables, desks with chair and screens."""
        rng = self.rng
        if name == "desk set":
            self.desk_set(self.placer.wall(*self.shape(KINDS["desk"])[0][:2], rng))
        elif name == "desk row":
            size, _ = self.shape(KINDS["desk"])
            n = int(rng.integers(2, 5))
            r = self.room
            cy = rng.uniform(r.y0 + 1.8, max(r.y1 - 1.8, r.y0 + 1.81))
            x = rng.uniform(r.x0 + 1.0, r.x0 + 1.5)
            for k in range(n):
                for side in (0.0, np.pi):   # two desks back to back
                    off = size[1] / 2 + 0.01
                    pose = self.placer.at(x + size[0] / 2, cy - np.cos(side) * off, side, size[0], size[1])
                    if pose is not None:
                        self.desk_set(pose, placed=True)
                x += size[0] + 0.02
        elif name in ("dining set", "meeting set"):
            tkind = KINDS["dining table"] if name == "dining set" else KINDS["table"]
            size, shapes = self.shape(tkind)
            if name == "meeting set":
                size = (rng.uniform(2.0, 3.2), rng.uniform(1.0, 1.3), size[2])
                shapes = build(tkind, size, rng)
            pose = self.placer.free(size[0] + 1.0, size[1] + 1.0, rng)
            if pose is None:
                return
            cx, cy, yaw = pose
            self.put(tkind, size, shapes, cx, cy, yaw)
            ckind = KINDS["chair"] if name == "dining set" else KINDS["office chair"]
            csize, cshapes = self.shape(ckind)
            per_side = max(1, int(size[0] / 0.65))
            c, s = np.cos(yaw), np.sin(yaw)
            for side in (-1, 1):
                for k in range(per_side):
                    if rng.random() < 0.1:
                        continue   # a missing chair
                    lx = (k + 0.5) * size[0] / per_side - size[0] / 2
                    ly = side * (size[1] / 2 + csize[1] / 2 - 0.05)
                    cyaw = yaw + (0.0 if side < 0 else np.pi) + rng.normal(0, 0.08)
                    self.scene.add(cshapes, self.scene.label(ckind), ckind.color, cyaw,
                                   (cx + c * lx - s * ly, cy + s * lx + c * ly, 0.0))

    def desk_set(self, pose, placed: bool = False) -> None:
        if pose is None:
            return
        cx, cy, yaw = pose[:3]
        dkind = KINDS["desk"]
        size, shapes = self.shape(dkind)
        self.put(dkind, size, shapes, cx, cy, yaw)
        c, s = np.cos(yaw), np.sin(yaw)
        chair = KINDS["office chair"]
        csize, cshapes = self.shape(chair)
        ly = size[1] / 2 + 0.1
        self.scene.add(cshapes, self.scene.label(chair), chair.color, yaw + np.pi + self.rng.normal(0, 0.3),
                       (cx - s * ly, cy + c * ly, 0.0))
        mon = KINDS["monitor"]
        msize, mshapes = self.shape(mon)
        n_mon = 1 + int(self.rng.random() < 0.4)
        for k in range(n_mon):
            lx = (k - (n_mon - 1) / 2) * (msize[0] + 0.05)
            ly = -size[1] / 2 + 0.15
            self.scene.add(mshapes, self.scene.label(mon), mon.color, yaw, (cx + c * lx - s * ly, cy + s * lx + c * ly, size[2]))
        if self.rng.random() < 0.7:
            kb = KINDS["keyboard"]
            _, kshapes = self.shape(kb)
            ly = 0.05
            self.scene.add(kshapes, self.scene.label(kb), kb.color, yaw, (cx - s * ly, cy + c * ly, size[2]))


def _wall_strips(wall: Wall, height: float, split: float | None):
    """(s0, s1, z0, z1, part) rectangles covering the wall around its openings."""
    cuts = sorted(wall.openings)
    strips, cursor = [], 0.0
    for s0, s1, z0, z1, _ in cuts:
        strips.append((cursor, s0, 0.0, height))
        if z0 > 0:
            strips.append((s0, s1, 0.0, z0))
        strips.append((s0, s1, z1, height))
        cursor = s1
    strips.append((cursor, wall.length, 0.0, height))
    out = []
    for s0, s1, z0, z1 in strips:
        if split is not None and s0 < split < s1:
            out += [(s0, split, z0, z1, 0), (split, s1, z0, z1, 1)]
        elif s1 - s0 > 1e-3 and z1 - z0 > 1e-3:
            out.append((s0, s1, z0, z1, int(split is not None and s0 >= split)))
    return out


def _build_structure(scene: _Scene, room: Room, rng: np.random.Generator) -> None:
    cfg = scene.cfg
    H = room.height
    floor = Shapes().rect((room.x0, room.y0, 0.0), (room.x1 - room.x0, 0, 0), (0, room.y1 - room.y0, 0))
    scene.add(floor, "floor", FLOOR_COLORS[int(rng.integers(len(FLOOR_COLORS)))], structural=True)
    if rng.random() < cfg.ceiling_prob:
        keep = rng.uniform(*cfg.ceiling_keep)   # scanners see only part of a ceiling
        w, d = room.x1 - room.x0, room.y1 - room.y0
        cw, cd = w * np.sqrt(keep), d * np.sqrt(keep)
        x0, y0 = rng.uniform(room.x0, room.x1 - cw), rng.uniform(room.y0, room.y1 - cd)
        scene.add(Shapes().rect((x0, y0, H), (cw, 0, 0), (0, cd, 0)), "ceiling", (235, 235, 232), structural=True)
    wall_color = np.array([225, 220, 210]) - rng.integers(0, 40)
    for wall in room.walls:
        split = None
        if wall.length > 3.5 and rng.random() < cfg.wall_split_prob:
            split = rng.uniform(0.3, 0.7) * wall.length
        parts = [Shapes(), Shapes()]
        for s0, s1, z0, z1, part in _wall_strips(wall, H, split):
            o = np.r_[wall.p0 + wall.u * s0, z0]
            parts[part].rect(o, np.r_[wall.u * (s1 - s0), 0], (0, 0, z1 - z0))
        for p in parts:
            if p.rects:
                scene.add(p, "wall", wall_color, structural=True)
        for s0, s1, z0, z1, kind in wall.openings:
            yaw = float(np.arctan2(-wall.n[0], wall.n[1]))
            c = wall.p0 + wall.u * (s0 + s1) / 2
            w = s1 - s0
            if kind == "door":
                door = Shapes()
                if rng.random() < 0.5:   # closed, slightly recessed
                    door.box((0, -0.05, 0), (w - 0.02, 0.04, z1 - 0.01))
                    scene.add(door, scene.label(_DOOR), _DOOR.color, yaw, (c[0] - wall.n[0] * 0.02, c[1] - wall.n[1] * 0.02, 0))
                else:                    # open into the room, hinged at one jamb
                    door.box((0, 0, 0), (0.04, w - 0.02, z1 - 0.01))
                    hinge = wall.p0 + wall.u * (s0 + 0.03) + wall.n * (w / 2)
                    scene.add(door, scene.label(_DOOR), _DOOR.color, yaw, (hinge[0], hinge[1], 0))
            elif kind == "window":
                win = Shapes()
                fh = z1 - z0
                win.box((-w / 2 + 0.03, 0, 0), (0.06, 0.1, fh)).box((w / 2 - 0.03, 0, 0), (0.06, 0.1, fh))
                win.box((0, 0, 0), (w, 0.1, 0.06)).box((0, 0, fh - 0.06), (w, 0.1, 0.06))
                win.box((0, 0.06, -0.03), (w + 0.1, 0.12, 0.03))                    # sill
                if rng.random() < 0.5:
                    win.box((0, 0, 0), (0.04, 0.06, fh))                             # mullion
                scene.add(win, scene.label(_WINDOW), _WINDOW.color, yaw, (c[0], c[1], z0))
                if rng.random() < 0.4:
                    ck = KINDS["curtain"]
                    cw = w + 0.4
                    ch = min(z1 + 0.2, H - 0.05)
                    cshape = build(ck, (cw, 0.12, ch), rng)
                    p = c + wall.n * 0.15
                    scene.add(cshape, scene.label(ck), ck.color, yaw, (p[0], p[1], 0.0))


_DOOR = Kind("door", lambda *a: Shapes(), (0, 0), (0, 0), (0, 0), "wall", "door", ("door",), (170, 130, 90))
_WINDOW = Kind("window", lambda *a: Shapes(), (0, 0), (0, 0), (0, 0), "wall", "window", ("window",), (180, 200, 220))


def _furnish(scene: _Scene, room: Room, rng: np.random.Generator) -> None:
    f = _RoomFurnisher(scene, room, rng)
    recipe = ROOM_TYPES[room.rtype]
    floor_first = sorted(recipe, key=lambda r: KINDS[r[0]].placement in ("top", "mount") if r[0] in KINDS else False)
    for name, lo, hi in floor_first:
        for _ in range(int(rng.integers(lo, hi + 1))):
            if name not in KINDS:
                f.group(name)
                continue
            f.place(name)
    for _ in range(int(rng.integers(*scene.cfg.clutter))):
        name = CLUTTER[int(rng.integers(len(CLUTTER)))]
        unlabelled = rng.random() < scene.cfg.unlabelled_prob
        f.place(name, label=None if unlabelled else "")


def _hide_occluded(points: np.ndarray, tags: np.ndarray, structural: np.ndarray, solids: list[tuple]) -> np.ndarray:
    """Mask of points to keep: floor and wall samples under or behind solid furniture go."""
    keep = np.ones(len(points), dtype=bool)
    cand = np.flatnonzero(structural[tags])
    p = points[cand]
    for cx, cy, yaw, w, d, h in solids:
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = p[:, 0] - cx, p[:, 1] - cy
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        inside = (np.abs(lx) < w / 2 + 0.02) & (np.abs(ly) < d / 2 + 0.03) & (p[:, 2] < h + 0.02)
        keep[cand[inside]] = False
    return keep


def generate_scene(seed: int, cfg: SynthConfig | None = None) -> InstanceMap:
    """A furnished apartment, office or building floor as an InstanceMap with colours (see
    SynthConfig)."""
    cfg = cfg or SynthConfig()
    if cfg.kind not in ("apartment", "office", "building"):
        raise ValueError(f"kind must be 'apartment', 'office' or 'building', got {cfg.kind!r}")
    if not 1 <= cfg.rooms <= MAX_ROOMS or cfg.run < 1:
        raise ValueError(f"rooms must lie in [1, {MAX_ROOMS}] and run be >= 1, got {cfg.rooms}, {cfg.run}")
    rng = np.random.default_rng(seed)
    templates: list[int] = []
    if cfg.kind == "building":
        rooms, templates = building(cfg.rooms, rng, cfg.run)
        order = rng.permutation(len(BUILDING))
        for room, t in zip(rooms[1:], templates[1:]):
            room.rtype = BUILDING[order[t % len(BUILDING)]]
    else:
        rooms = partition(cfg.rooms, cfg.kind, rng)
        add_openings(rooms, rng)
        types = APARTMENT if cfg.kind == "apartment" else OFFICE
        order = rng.permutation(len(types))
        rooms_by_size = sorted(range(len(rooms)), key=lambda k: -rooms[k].area)
        for rank, k in enumerate(rooms_by_size):
            # offices: by size, from the open office down, starting over past the sixth room
            rooms[k].rtype = types[rank % len(types)] if cfg.kind == "office" or rank == 0 \
                else types[order[rank % len(types)]]
            if cfg.kind == "apartment" and rank == 0 and cfg.rooms == 1:
                rooms[k].rtype = ["living room", "bedroom", "study", "kitchen"][int(rng.integers(4))]
    scene = _Scene(cfg, rng)
    for k, room in enumerate(rooms):
        # the rooms of one template are built and furnished from one seed: identical rooms
        t = templates[k] if templates else -1
        room_rng = rng if t < 0 else np.random.default_rng([seed, 1 + t])
        _build_structure(scene, room, room_rng)
        _furnish(scene, room, room_rng)

    density = cfg.density * rng.uniform(1 - cfg.density_jitter, 1 + cfg.density_jitter)
    points, tags = sample_shapes(scene.shapes, density, rng)
    ceiling = np.array([l == "ceiling" for l in scene.labels])
    # ceilings are scanned sparsely from below
    keep = ~ceiling[tags] | (rng.random(len(tags)) < 0.4)
    keep &= _hide_occluded(points, tags, np.array(scene.structural), scene.solids)
    points, tags = points[keep], tags[keep]
    points = points + rng.normal(0, cfg.surface_noise, points.shape).astype(np.float32)

    labelled = np.array([l is not None for l in scene.labels])
    ids = np.where(labelled, np.cumsum(labelled), 0)
    present = np.zeros(len(scene.labels), dtype=bool)
    present[tags] = True
    colors = np.array(scene.colors)[tags] + rng.normal(0, 6, (len(tags), 3))
    imap = InstanceMap(
        points=points.astype(np.float32),
        instance=ids[tags].astype(np.int32),
        labels={int(ids[k]): scene.labels[k] for k in np.flatnonzero(labelled & present)},
        scores={int(ids[k]): 1.0 for k in np.flatnonzero(labelled & present)},
        colors=np.clip(colors, 0, 255).astype(np.uint8),
    )
    if replace(cfg.noise, tilt=0.0) != NoiseConfig():   # tilt moves points: pairs apply it
        imap = apply_noise(imap, cfg.noise, rng)
    return imap
