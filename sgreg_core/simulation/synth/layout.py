"""Room layout: footprint partition, walls with door and window openings, furniture placement.

Public API:
    Wall, Room                  geometry of one room (interior rectangle, four walls)
    partition(n_rooms, kind, rng) -> list[Room]      BSP split of an apartment / office footprint
    add_openings(rooms, rng)    doors between adjacent rooms (a spanning tree: every room has
                                a way in, though scene.py leaves half the doors closed, and a
                                walking agent passes no closed door), one entrance door,
                                windows on exterior walls
    building(n_rooms, rng) -> (rooms, templates)   a floor: rooms on both sides of a corridor
                                (rooms[0]), each with its door on the corridor and windows
                                outside; rooms of one run share a template (same size, same
                                openings: furnished alike, they are identical rooms)
    Placer                      non-overlapping placement of footprints in one room:
        .wall(w, d, rng) / .free(w, d, rng) / .at(cx, cy, yaw, w, d) -> pose or None
        .mount(w, z0, h, rng) -> (wall, s) or None
Rooms are axis-aligned; walls run anticlockwise (south, east, north, west) with the inward
normal on their left.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WALL_HALF = 0.06  # m, half the wall thickness: interiors are shrunk by it


@dataclass
class Wall:
    p0: np.ndarray                # start (x, y)
    u: np.ndarray                 # unit direction along the wall
    n: np.ndarray                 # unit inward normal
    length: float
    exterior: bool
    openings: list = field(default_factory=list)   # (s0, s1, z0, z1, kind)
    mounted: list = field(default_factory=list)    # (s0, s1) of wall-mounted objects

    def free_interval(self, s0: float, s1: float, margin: float = 0.1) -> bool:
        if s0 < 0.05 or s1 > self.length - 0.05:
            return False
        taken = [(a, b) for a, b, *_ in self.openings] + self.mounted
        return all(s1 + margin <= a or s0 - margin >= b for a, b in taken)


@dataclass
class Room:
    x0: float
    y0: float
    x1: float
    y1: float
    height: float
    rtype: str = ""
    walls: list[Wall] = field(default_factory=list)

    def make_walls(self, outer: tuple[float, float, float, float]) -> None:
        X0, Y0, X1, Y1 = outer
        c = [(self.x0, self.y0), (self.x1, self.y0), (self.x1, self.y1), (self.x0, self.y1)]
        ext = [abs(self.y0 - Y0 - WALL_HALF) < 1e-6, abs(self.x1 - X1 + WALL_HALF) < 1e-6,
               abs(self.y1 - Y1 + WALL_HALF) < 1e-6, abs(self.x0 - X0 - WALL_HALF) < 1e-6]
        self.walls = []
        for k in range(4):
            p0, p1 = np.array(c[k]), np.array(c[(k + 1) % 4])
            L = float(np.linalg.norm(p1 - p0))
            u = (p1 - p0) / L
            self.walls.append(Wall(p0, u, np.array([-u[1], u[0]]), L, ext[k]))

    @property
    def area(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)


def partition(n_rooms: int, kind: str, rng: np.random.Generator) -> list[Room]:
    """Split a rectangular footprint into n_rooms rooms (largest room split first)."""
    areas = rng.uniform(30, 60, 1) if kind == "office" else rng.uniform(14, 28, 1)
    total = float(areas[0] + rng.uniform(10, 26, max(n_rooms - 1, 0)).sum())
    aspect = rng.uniform(1.0, 1.5)
    W = np.sqrt(total * aspect)
    D = total / W
    rects = [(0.0, 0.0, W, D)]
    for _ in range(n_rooms - 1):
        rects.sort(key=lambda r: (r[2] - r[0]) * (r[3] - r[1]))
        x0, y0, x1, y1 = rects.pop()
        f = rng.uniform(0.35, 0.65)
        if x1 - x0 >= y1 - y0:
            xm = x0 + f * (x1 - x0)
            rects += [(x0, y0, xm, y1), (xm, y0, x1, y1)]
        else:
            ym = y0 + f * (y1 - y0)
            rects += [(x0, y0, x1, ym), (x0, ym, x1, y1)]
    height = rng.uniform(2.5, 3.0)
    rooms = [Room(x0 + WALL_HALF, y0 + WALL_HALF, x1 - WALL_HALF, y1 - WALL_HALF, height) for x0, y0, x1, y1 in rects]
    for r in rooms:
        r.make_walls((0.0, 0.0, W, D))
    return rooms


def _shared(a: Room, b: Room):
    """(wall index in a, wall index in b, lo, hi, axis) of a shared boundary, or None."""
    gap = 2 * WALL_HALF + 1e-6
    if abs(b.x0 - a.x1) < gap:
        lo, hi = max(a.y0, b.y0), min(a.y1, b.y1)
        return (1, 3, lo, hi, "y") if hi - lo > 1.2 else None
    if abs(a.x0 - b.x1) < gap:
        lo, hi = max(a.y0, b.y0), min(a.y1, b.y1)
        return (3, 1, lo, hi, "y") if hi - lo > 1.2 else None
    if abs(b.y0 - a.y1) < gap:
        lo, hi = max(a.x0, b.x0), min(a.x1, b.x1)
        return (2, 0, lo, hi, "x") if hi - lo > 1.2 else None
    if abs(a.y0 - b.y1) < gap:
        lo, hi = max(a.x0, b.x0), min(a.x1, b.x1)
        return (0, 2, lo, hi, "x") if hi - lo > 1.2 else None
    return None


def _to_s(wall: Wall, coord_lo: float, coord_hi: float, axis: str) -> tuple[float, float]:
    k = 0 if axis == "x" else 1
    s = sorted(((coord_lo - wall.p0[k]) * wall.u[k], (coord_hi - wall.p0[k]) * wall.u[k]))
    return s[0], s[1]


def add_openings(rooms: list[Room], rng: np.random.Generator) -> None:
    """Doors on a spanning tree of the room adjacency, one entrance, windows outside."""
    seen, frontier = {0}, [0]
    while frontier:
        a = frontier.pop()
        for b in rng.permutation(len(rooms)):
            if b in seen:
                continue
            sh = _shared(rooms[a], rooms[b])
            if sh is None:
                continue
            wa, wb, lo, hi, axis = sh
            width = rng.uniform(0.8, 0.95)
            c0 = rng.uniform(lo + 0.15, hi - 0.15 - width)
            top = rng.uniform(2.0, 2.1)
            for room, w in ((rooms[a], wa), (rooms[b], wb)):
                s0, s1 = _to_s(room.walls[w], c0, c0 + width, axis)
                room.walls[w].openings.append((s0, s1, 0.0, top, "door" if room is rooms[a] else "opening"))
            seen.add(int(b))
            frontier.append(int(b))
    entrance = rooms[int(rng.integers(len(rooms)))]
    ext = [w for w in entrance.walls if w.exterior and w.length > 1.6]
    if ext:
        w = ext[int(rng.integers(len(ext)))]
        width = rng.uniform(0.85, 1.0)
        _try_opening(w, width, 0.0, rng.uniform(2.0, 2.1), "door", rng)
    for room in rooms:
        n_win = 0
        for w in rng.permutation(len(room.walls)):
            wall = room.walls[w]
            if wall.exterior and wall.length > 1.8 and n_win < 2 and rng.random() < 0.7:
                width = rng.uniform(0.8, min(2.0, wall.length - 0.6))
                z0 = rng.uniform(0.75, 1.0)
                n_win += _try_opening(wall, width, z0, min(z0 + rng.uniform(1.0, 1.4), room.height - 0.25), "window", rng)


def _try_opening(wall: Wall, width: float, z0: float, z1: float, kind: str, rng) -> bool:
    for _ in range(10):
        s0 = rng.uniform(0.2, wall.length - 0.2 - width)
        if wall.free_interval(s0, s0 + width, margin=0.3):
            wall.openings.append((s0, s0 + width, z0, z1, kind))
            return True
    return False


class Placer:
    """Non-overlapping footprints (axis-aligned boxes of the rotated footprints) in one room."""

    def __init__(self, room: Room, margin: float = 0.05) -> None:
        self.room, self.margin = room, margin
        self.boxes: list[tuple[float, float, float, float]] = []
        for wall in room.walls:   # keep door swings and passages clear
            for s0, s1, z0, _, kind in wall.openings:
                if kind in ("door", "opening"):
                    a = wall.p0 + wall.u * s0
                    b = wall.p0 + wall.u * s1 + wall.n * 0.9
                    self.boxes.append((min(a[0], b[0]), min(a[1], b[1]), max(a[0], b[0]), max(a[1], b[1])))

    def at(self, cx: float, cy: float, yaw: float, w: float, d: float, check_room: bool = True):
        c, s = abs(np.cos(yaw)), abs(np.sin(yaw))
        hx, hy = (w * c + d * s) / 2, (w * s + d * c) / 2
        box = (cx - hx, cy - hy, cx + hx, cy + hy)
        r = self.room
        if check_room and (box[0] < r.x0 - 1e-6 or box[1] < r.y0 - 1e-6 or box[2] > r.x1 + 1e-6 or box[3] > r.y1 + 1e-6):
            return None
        m = self.margin
        for b in self.boxes:
            if box[0] < b[2] + m and box[2] > b[0] - m and box[1] < b[3] + m and box[3] > b[1] - m:
                return None
        self.boxes.append(box)
        return (cx, cy, yaw)

    def wall(self, w: float, d: float, rng: np.random.Generator, tries: int = 30, wall_index: int | None = None):
        """Back against a wall, front towards the room: (cx, cy, yaw, wall, s) or None."""
        for _ in range(tries):
            k = int(rng.integers(4)) if wall_index is None else wall_index
            wall = self.room.walls[k]
            if wall.length < w + 0.1:
                continue
            s = rng.uniform(w / 2 + 0.02, wall.length - w / 2 - 0.02)
            if any(s + w / 2 > a and s - w / 2 < b and z0 < 1.0 for a, b, z0, *_ in wall.openings):
                continue  # not in front of a door or a low window
            p = wall.p0 + wall.u * s + wall.n * (d / 2 + 0.01)
            yaw = float(np.arctan2(-wall.n[0], wall.n[1]))
            if self.at(p[0], p[1], yaw, w, d) is not None:
                return p[0], p[1], yaw, wall, s
        return None

    def free(self, w: float, d: float, rng: np.random.Generator, tries: int = 30, any_yaw: bool = False):
        r = self.room
        for _ in range(tries):
            yaw = rng.uniform(-np.pi, np.pi) if any_yaw else rng.integers(4) * np.pi / 2 + rng.normal(0, 0.05)
            cx, cy = rng.uniform(r.x0 + 0.3, r.x1 - 0.3), rng.uniform(r.y0 + 0.3, r.y1 - 0.3)
            if self.at(cx, cy, yaw, w, d) is not None:
                return cx, cy, yaw
        return None

    def mount(self, w: float, z0: float, h: float, rng: np.random.Generator, tries: int = 20):
        """A free interval on a wall for a hung object: (wall, s_center) or None."""
        for _ in range(tries):
            wall = self.room.walls[int(rng.integers(4))]
            if wall.length < w + 0.3:
                continue
            s = rng.uniform(w / 2 + 0.1, wall.length - w / 2 - 0.1)
            if wall.free_interval(s - w / 2, s + w / 2) and not self._blocked(wall, s, w, z0):
                wall.mounted.append((s - w / 2, s + w / 2))
                return wall, s
        return None

    def _blocked(self, wall: Wall, s: float, w: float, z0: float) -> bool:
        # a hung object needs the wall in front of it free of tall furniture
        a = wall.p0 + wall.u * (s - w / 2)
        b = wall.p0 + wall.u * (s + w / 2) + wall.n * 0.3
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return z0 < 1.5 and any(bx[0] < hi[0] and bx[2] > lo[0] and bx[1] < hi[1] and bx[3] > lo[1] for bx in self.boxes)


def building(n_rooms: int, rng: np.random.Generator, run: int = 3) -> tuple[list[Room], list[int]]:
    """A floor of an office building or hotel: a corridor (rooms[0]) with n_rooms rooms of one
    width on its two sides. Runs of `run` neighbouring rooms on one side share a template: the
    same door and window positions (templates[k] for rooms[k]; the corridor's is -1), so that
    furnished from the same seed they are identical rooms, the hardest case for false links."""
    per_side = [(n_rooms + 1) // 2, n_rooms // 2]
    width = rng.uniform(3.4, 4.2)
    depth = rng.uniform(4.0, 5.5, 2)                   # south, north rooms
    corridor = rng.uniform(1.8, 2.4)
    length = max(per_side) * width
    total = depth[0] + corridor + depth[1]
    height = rng.uniform(2.6, 3.0)
    outer = (0.0, 0.0, length, total)

    def room(x0, y0, x1, y1, rtype=""):
        r = Room(x0 + WALL_HALF, y0 + WALL_HALF, x1 - WALL_HALF, y1 - WALL_HALF, height, rtype)
        r.make_walls(outer)
        return r

    rooms = [room(0.0, depth[0], length, depth[0] + corridor, "corridor")]
    templates = [-1]
    n_templates = 0
    for side, (y0, y1) in enumerate(((0.0, depth[0]), (depth[0] + corridor, total))):
        door_wall, corridor_wall = (2, 0) if side == 0 else (0, 2)
        for k in range(per_side[side]):
            if k % run == 0:
                n_templates += 1
                door = rng.uniform(0.3, width - 1.3)                 # from the room's west end
                window = (rng.uniform(0.4, 0.6), rng.uniform(1.0, 1.8), rng.uniform(0.8, 1.0))
            r = room(k * width, y0, (k + 1) * width, y1)
            x_door = r.x0 + door
            s0, s1 = _to_s(r.walls[door_wall], x_door, x_door + 0.9, "x")
            r.walls[door_wall].openings.append((s0, s1, 0.0, 2.05, "door"))
            s0, s1 = _to_s(rooms[0].walls[corridor_wall], x_door, x_door + 0.9, "x")
            rooms[0].walls[corridor_wall].openings.append((s0, s1, 0.0, 2.05, "opening"))
            outside = r.walls[0 if side == 0 else 2]
            centre, w, z0 = window
            s = centre * outside.length
            outside.openings.append((s - w / 2, s + w / 2, z0, min(z0 + 1.3, height - 0.25), "window"))
            rooms.append(r)
            templates.append(n_templates - 1)
    # an entrance at one end of the corridor
    end = rooms[0].walls[3]
    end.openings.append((end.length / 2 - 0.5, end.length / 2 + 0.5, 0.0, 2.1, "door"))
    return rooms, templates
