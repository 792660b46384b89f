"""Object kinds as parametric surface models (legs, seats, backs, shelves, not just boxes).

Public API:
    Kind                     dataclass: name, builder, size ranges, placement, labels, colour
    KINDS: dict[str, Kind]   the catalogue (>= 40 kinds)
    build(kind, size, rng) -> Shapes    the object's surfaces in its local frame

Local frame: origin at the centre of the footprint on the floor, x along the width w, y along
the depth d with the front facing +y (a wall object's back lies at y = -d/2), z up to h.
Placement: "wall" (back against a wall), "free" (anywhere on the floor), "top" (on a support
surface), "mount" (hung on a wall at `mount_z`), "corner" (floor, near a wall, any side).
Labels: `nyu40` is the ScanNet/NYU40 class name that real scans carry (instances.json of the
ScanNet scans); `names` are open-set names a detector might give.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .shapes import Shapes


@dataclass(frozen=True)
class Kind:
    name: str
    builder: Callable[[float, float, float, np.random.Generator], Shapes]
    w: tuple[float, float]
    d: tuple[float, float]
    h: tuple[float, float]
    placement: str
    nyu40: str
    names: tuple[str, ...]
    color: tuple[int, int, int]
    solid: bool = False              # hides the floor / wall behind its footprint
    support: bool = False            # other objects may stand on its top
    mount_z: float = 1.2             # m, bottom height of a "mount" object


def _legs(S: Shapes, w, d, h, t=0.04, inset=0.03):
    for sx in (-1, 1):
        for sy in (-1, 1):
            S.box((sx * (w / 2 - inset - t / 2), sy * (d / 2 - inset - t / 2), 0), (t, t, h))


def table(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, h - 0.04), (w, d, 0.04), bottom=True)
    if rng.random() < 0.3 and min(w, d) < 1.0:   # pedestal table
        S.cyl((0, 0, 0), 0.05, h - 0.04, top=False).cyl((0, 0, 0), 0.25, 0.03)
    else:
        _legs(S, w, d, h - 0.04)
    return S


def desk(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, h - 0.03), (w, d, 0.03), bottom=True)
    S.box((-w / 2 + 0.02, 0, 0), (0.03, d, h - 0.03), top=False)
    if rng.random() < 0.5:
        S.box((w / 2 - 0.22, 0, 0), (0.42, d - 0.05, h - 0.03), top=False)  # drawer unit
    else:
        S.box((w / 2 - 0.02, 0, 0), (0.03, d, h - 0.03), top=False)
    S.rect((-w / 2, -d / 2 + 0.03, 0.35), (w, 0, 0), (0, 0, h - 0.4))    # modesty panel
    return S


def chair(w, d, h, rng):
    S = Shapes()
    seat = 0.45
    _legs(S, w, d, seat - 0.05, t=0.03, inset=0.02)
    S.box((0, 0, seat - 0.05), (w, d, 0.05), bottom=True)
    S.box((0, -d / 2 + 0.025, seat), (w, 0.05, h - seat))
    return S


def office_chair(w, d, h, rng):
    S = Shapes()
    for a in np.arange(5) * 2 * np.pi / 5:   # five-star base
        S.box((0.18 * np.cos(a), 0.18 * np.sin(a), 0.05), (0.06, 0.06, 0.04))
    S.cyl((0, 0, 0.05), 0.03, 0.37, top=False)
    S.box((0, 0, 0.42), (w, d, 0.08), bottom=True)
    S.box((0, -d / 2 + 0.04, 0.55), (w * 0.9, 0.06, h - 0.55), bottom=True)
    for sx in (-1, 1):
        S.box((sx * w / 2, 0, 0.6), (0.05, d * 0.6, 0.04))
    return S


def stool(w, d, h, rng):
    S = Shapes()
    S.cyl((0, 0, h - 0.04), w / 2, 0.04)
    for a in np.arange(4) * np.pi / 2 + np.pi / 4:
        S.cyl((0.3 * w * np.cos(a), 0.3 * w * np.sin(a), 0), 0.015, h - 0.04, top=False)
    return S


def sofa(w, d, h, rng):
    S = Shapes()
    arm = 0.18
    S.box((0, 0.05, 0.1), (w - 2 * arm, d - 0.1, 0.32))                    # seat cushions
    S.box((0, 0, 0), (w, d, 0.1), top=False)                              # base
    S.box((0, -d / 2 + 0.1, 0.1), (w - 2 * arm, 0.2, h - 0.1))             # back
    for sx in (-1, 1):
        S.box((sx * (w / 2 - arm / 2), 0, 0.1), (arm, d, 0.52))            # arms
    return S


def bed(w, d, h, rng):
    S = Shapes()
    S.box((0, 0.04, 0), (w, d - 0.08, 0.3), top=False)
    S.box((0, 0.04, 0.3), (w - 0.04, d - 0.12, 0.22))                      # mattress
    S.box((0, -d / 2 + 0.04, 0), (w, 0.08, h))                             # headboard
    return S


def cabinet(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0.08), (w, d, h - 0.08))
    S.rect((-w / 2 + 0.02, d / 2, 0), (w - 0.04, 0, 0), (0, 0, 0.08))       # recessed plinth
    for k in range(int(rng.integers(1, 3)) + int(w > 0.9)):                 # door handles
        S.box((-w / 2 + (k + 0.5) * w / (int(w > 0.9) + 2), d / 2 + 0.015, h * 0.6), (0.02, 0.03, 0.12))
    return S


def wall_cabinet(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0), (w, d, h), bottom=True)
    return S


def shelves(w, d, h, rng):
    S = Shapes()
    t = 0.02
    for sx in (-1, 1):
        S.box((sx * (w / 2 - t / 2), 0, 0), (t, d, h))
    S.rect((-w / 2, -d / 2, 0), (w, 0, 0), (0, 0, h))                       # back panel
    n = max(2, int(h / 0.35))
    for z in np.linspace(0.05, h - t, n):
        S.box((0, 0, z), (w - 2 * t, d, t), bottom=True)
    # books and things on the shelves
    for z in np.linspace(0.05, h - t, n)[:-1]:
        x = -w / 2 + t
        while x < w / 2 - 0.15:
            bw = rng.uniform(0.1, 0.4)
            if rng.random() < 0.6:
                S.box((x + bw / 2, -0.02, z + t), (bw * 0.9, d * 0.7, rng.uniform(0.15, 0.28)))
            x += bw
    return S


def dresser(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0.05), (w, d, h - 0.05))
    n = int(rng.integers(3, 5))
    for z in np.linspace(0.1, h - 0.1, n):
        for sx in (-1, 1):
            S.box((sx * w / 4, d / 2 + 0.01, z), (0.12, 0.02, 0.02))
    return S


def slab(w, d, h, rng):   # a closed box: fridge, oven, washing machine, printer, box ...
    S = Shapes()
    S.box((0, 0, 0), (w, d, h))
    return S


def panel(w, d, h, rng):  # thin wall-mounted things: picture, whiteboard, mirror, tv
    S = Shapes()
    S.box((0, 0, 0), (w, d, h), bottom=True)
    return S


def monitor(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0), (0.22, 0.18, 0.02))
    S.box((0, -0.05, 0.02), (0.05, 0.03, 0.1))
    S.box((0, -0.02, 0.1), (w, 0.03, h - 0.1), bottom=True)
    return S


def tv_on_stand(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0), (w * 0.4, 0.2, 0.02))
    S.box((0, -0.03, 0.02), (0.08, 0.04, 0.1))
    S.box((0, 0, 0.08), (w, 0.05, h - 0.08), bottom=True)
    return S


def keyboard(w, d, h, rng):
    return Shapes().box((0, 0, 0), (w, d, h))


def laptop(w, d, h, rng):
    S = Shapes().box((0, 0, 0), (w, d, 0.02))
    S.rect((-w / 2, -d / 2, 0.02), (w, 0, 0), (0, -0.08, h - 0.02))
    return S


def lamp(w, d, h, rng):
    S = Shapes()
    S.cyl((0, 0, 0), w * 0.35, 0.03)
    S.cyl((0, 0, 0.03), 0.015, h * 0.7, top=False)
    S.cyl((0, 0, h * 0.68), w / 2, h * 0.32, top=False)
    return S


def plant(w, d, h, rng):
    S = Shapes()
    pot = min(0.35 * h, 0.45)
    S.cyl((0, 0, 0), w * 0.3, pot, top=False)
    S.ell((0, 0, pot + (h - pot) * 0.5), (w / 2, d / 2, (h - pot) / 2))
    if rng.random() < 0.5:
        S.ell((w * 0.15, 0, pot + (h - pot) * 0.7), (w / 3, d / 3, (h - pot) / 3))
    return S


def toilet(w, d, h, rng):
    S = Shapes()
    S.cyl((0, 0.1, 0), 0.14, 0.3, top=False)
    S.ell((0, 0.1, 0.3), (w / 2, d * 0.4, 0.1), zmin=-0.2)
    S.box((0, -d / 2 + 0.09, 0.3), (w * 0.9, 0.18, h - 0.3))
    return S


def sink(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0), (w, d, h - 0.15), top=False)
    S.box((0, 0, h - 0.15), (w, d, 0.02))
    S.ell((0, 0.03, h - 0.02), (w * 0.35, d * 0.3, 0.13), zmin=-1.0, )
    S.cyl((0, -d / 2 + 0.06, h), 0.015, 0.2)
    return S


def bathtub(w, d, h, rng):
    S = Shapes()
    S.box((0, 0, 0), (w, d, h), top=False)
    S.box((0, 0, 0.1), (w - 0.16, d - 0.16, h - 0.1), top=False)  # inner tub walls
    for o, u, v in (((-w / 2, -d / 2, h), (w, 0, 0), (0, 0.08, 0)), ((-w / 2, d / 2 - 0.08, h), (w, 0, 0), (0, 0.08, 0)),
                    ((-w / 2, -d / 2, h), (0.08, 0, 0), (0, d, 0)), ((w / 2 - 0.08, -d / 2, h), (0.08, 0, 0), (0, d, 0))):
        S.rect(o, u, v)                                             # rim
    return S


def trash_can(w, d, h, rng):
    return Shapes().cyl((0, 0, 0), w / 2, h, top=False)


def pillow(w, d, h, rng):
    return Shapes().ell((0, 0, h / 2), (w / 2, d / 2, h / 2))


def bag(w, d, h, rng):
    return Shapes().ell((0, 0, h / 2), (w / 2, d / 2, h / 2), zmin=-0.6)


def books(w, d, h, rng):
    S = Shapes()
    z = 0.0
    for _ in range(int(rng.integers(2, 6))):
        t = rng.uniform(0.02, 0.05)
        S.box((rng.normal(0, 0.01), rng.normal(0, 0.01), z), (w, d, t))
        z += t
    return S


def rug(w, d, h, rng):
    return Shapes().rect((-w / 2, -d / 2, 0.01), (w, 0, 0), (0, d, 0))


def curtain(w, d, h, rng):
    S = Shapes()
    folds = max(4, int(w / 0.15))
    xs = np.linspace(-w / 2, w / 2, folds + 1)
    for k in range(folds):
        y0, y1 = (-d / 2, d / 2) if k % 2 == 0 else (d / 2, -d / 2)
        S.rect((xs[k], y0, 0.02), (xs[k + 1] - xs[k], y1 - y0, 0), (0, 0, h - 0.02))
    return S


def radiator(w, d, h, rng):
    S = Shapes()
    for x in np.arange(-w / 2 + 0.03, w / 2, 0.08):
        S.box((x, 0, 0), (0.03, d, h))
    return S


def coat_rack(w, d, h, rng):
    S = Shapes().cyl((0, 0, 0), w / 2, 0.03).cyl((0, 0, 0.03), 0.02, h - 0.03)
    for a in np.arange(4) * np.pi / 2:
        S.box((0.12 * np.cos(a), 0.12 * np.sin(a), h - 0.2), (0.03, 0.03, 0.15))
    return S


def fan(w, d, h, rng):
    S = Shapes().cyl((0, 0, 0), w * 0.4, 0.04).cyl((0, 0, 0.04), 0.02, h - 0.3, top=False)
    S.ell((0, 0, h - 0.2), (w / 2, 0.1, w / 2))
    return S


def bench(w, d, h, rng):
    S = Shapes().box((0, 0, h - 0.05), (w, d, 0.05), bottom=True)
    for sx in (-1, 1):
        S.box((sx * (w / 2 - 0.05), 0, 0), (0.04, d * 0.9, h - 0.05), top=False)
    return S


def counter(w, d, h, rng):
    S = Shapes()
    S.box((0, -0.02, 0.1), (w, d - 0.04, h - 0.14))
    S.box((0, 0, h - 0.04), (w, d, 0.04), bottom=True)
    n = max(1, int(round(w / 0.6)))
    for k in range(n):
        S.box((-w / 2 + (k + 0.5) * w / n, d / 2 - 0.02, h - 0.25), (0.12, 0.02, 0.02))
    return S


def _k(name, builder, w, d, h, placement, nyu40, names, color, **kw) -> Kind:
    return Kind(name, builder, w, d, h, placement, nyu40, tuple(names), color, **kw)


KINDS: dict[str, Kind] = {k.name: k for k in [
    _k("table", table, (0.8, 1.6), (0.6, 0.9), (0.72, 0.78), "free", "table", ["table"], (150, 110, 70), support=True),
    _k("dining table", table, (1.2, 2.0), (0.8, 1.0), (0.72, 0.78), "free", "table", ["dining table", "table"], (140, 100, 60), support=True),
    _k("coffee table", table, (0.8, 1.3), (0.45, 0.7), (0.35, 0.48), "free", "table", ["coffee table", "low table"], (120, 80, 50), support=True),
    _k("side table", table, (0.4, 0.6), (0.4, 0.6), (0.45, 0.65), "corner", "table", ["side table", "end table"], (130, 90, 60), support=True),
    _k("desk", desk, (1.1, 1.8), (0.6, 0.8), (0.72, 0.76), "wall", "desk", ["desk", "work desk"], (180, 160, 130), support=True),
    _k("chair", chair, (0.42, 0.5), (0.45, 0.52), (0.8, 0.95), "free", "chair", ["chair", "dining chair"], (110, 70, 40)),
    _k("office chair", office_chair, (0.55, 0.65), (0.55, 0.62), (0.9, 1.15), "free", "chair", ["office chair", "desk chair"], (40, 40, 45)),
    _k("stool", stool, (0.32, 0.4), (0.32, 0.4), (0.45, 0.75), "free", "otherfurniture", ["stool", "bar stool"], (90, 90, 90)),
    _k("sofa", sofa, (1.6, 2.6), (0.8, 1.0), (0.75, 0.95), "wall", "sofa", ["sofa", "couch"], (90, 100, 130), solid=True),
    _k("armchair", sofa, (0.75, 0.95), (0.75, 0.9), (0.75, 0.95), "free", "chair", ["armchair", "lounge chair"], (120, 90, 90), solid=True),
    _k("bed", bed, (1.4, 1.9), (1.95, 2.15), (0.8, 1.1), "wall", "bed", ["bed", "double bed"], (200, 200, 210), solid=True),
    _k("night stand", cabinet, (0.4, 0.55), (0.35, 0.45), (0.45, 0.6), "wall", "night stand", ["nightstand", "bedside table"], (150, 120, 90), solid=True, support=True),
    _k("cabinet", cabinet, (0.6, 1.2), (0.4, 0.6), (0.8, 2.0), "wall", "cabinet", ["cabinet", "cupboard"], (170, 150, 120), solid=True, support=True),
    _k("kitchen cabinet", cabinet, (0.5, 1.0), (0.55, 0.62), (0.85, 0.9), "wall", "cabinet", ["kitchen cabinet", "cabinet"], (220, 220, 215), solid=True, support=True),
    _k("wall cabinet", wall_cabinet, (0.6, 1.2), (0.3, 0.38), (0.6, 0.8), "mount", "cabinet", ["wall cabinet", "cupboard"], (220, 220, 215), mount_z=1.45),
    _k("counter", counter, (1.2, 2.6), (0.58, 0.65), (0.88, 0.93), "wall", "counter", ["counter", "countertop"], (200, 195, 185), solid=True, support=True),
    _k("dresser", dresser, (0.8, 1.4), (0.45, 0.55), (0.75, 1.1), "wall", "dresser", ["dresser", "chest of drawers"], (160, 120, 80), solid=True, support=True),
    _k("wardrobe", cabinet, (0.9, 1.8), (0.55, 0.65), (1.9, 2.2), "wall", "cabinet", ["wardrobe", "closet"], (200, 190, 170), solid=True),
    _k("bookshelf", shelves, (0.7, 1.2), (0.28, 0.38), (1.6, 2.1), "wall", "bookshelf", ["bookshelf", "bookcase"], (150, 110, 70), solid=True),
    _k("shelves", shelves, (0.8, 1.6), (0.3, 0.45), (0.8, 1.9), "wall", "shelves", ["shelves", "shelf", "rack"], (170, 170, 170), solid=True),
    _k("file cabinet", cabinet, (0.4, 0.5), (0.5, 0.65), (0.7, 1.3), "wall", "cabinet", ["file cabinet", "filing cabinet"], (150, 150, 155), solid=True, support=True),
    _k("tv stand", cabinet, (1.0, 1.8), (0.4, 0.5), (0.4, 0.6), "wall", "otherfurniture", ["tv stand", "media console"], (60, 50, 45), solid=True, support=True),
    _k("tv", tv_on_stand, (0.9, 1.4), (0.2, 0.25), (0.55, 0.85), "top", "television", ["tv", "television"], (20, 20, 25)),
    _k("wall tv", panel, (1.0, 1.6), (0.05, 0.08), (0.6, 0.9), "mount", "television", ["tv", "television", "screen"], (20, 20, 25), mount_z=1.1),
    _k("monitor", monitor, (0.5, 0.7), (0.2, 0.22), (0.4, 0.5), "top", "otherprop", ["monitor", "computer monitor"], (30, 30, 35)),
    _k("keyboard", keyboard, (0.4, 0.48), (0.13, 0.17), (0.02, 0.04), "top", "otherprop", ["keyboard"], (50, 50, 50)),
    _k("laptop", laptop, (0.3, 0.38), (0.22, 0.26), (0.22, 0.26), "top", "otherprop", ["laptop", "computer"], (150, 150, 160)),
    _k("lamp", lamp, (0.25, 0.4), (0.25, 0.4), (0.35, 0.6), "top", "lamp", ["lamp", "table lamp"], (230, 220, 190)),
    _k("floor lamp", lamp, (0.35, 0.5), (0.35, 0.5), (1.4, 1.8), "corner", "lamp", ["floor lamp", "lamp"], (230, 220, 190)),
    _k("plant", plant, (0.35, 0.7), (0.35, 0.7), (0.5, 1.5), "corner", "otherprop", ["plant", "potted plant"], (60, 130, 60)),
    _k("toilet", toilet, (0.38, 0.45), (0.65, 0.75), (0.75, 0.85), "wall", "toilet", ["toilet"], (240, 240, 240)),
    _k("sink", sink, (0.5, 0.8), (0.45, 0.55), (0.85, 0.9), "wall", "sink", ["sink", "washbasin"], (235, 235, 235), solid=True),
    _k("bathtub", bathtub, (1.5, 1.8), (0.7, 0.8), (0.5, 0.6), "wall", "bathtub", ["bathtub", "tub"], (245, 245, 245), solid=True),
    _k("refrigerator", slab, (0.6, 0.9), (0.6, 0.75), (1.5, 1.9), "wall", "refridgerator", ["refrigerator", "fridge"], (225, 225, 230), solid=True),
    _k("oven", slab, (0.55, 0.65), (0.55, 0.65), (0.85, 0.9), "wall", "otherfurniture", ["oven", "stove"], (70, 70, 75), solid=True),
    _k("microwave", slab, (0.45, 0.55), (0.32, 0.4), (0.26, 0.32), "top", "otherprop", ["microwave"], (200, 200, 200)),
    _k("washing machine", slab, (0.58, 0.62), (0.55, 0.62), (0.82, 0.88), "wall", "otherfurniture", ["washing machine", "washer"], (240, 240, 240), solid=True),
    _k("printer", slab, (0.45, 0.6), (0.4, 0.55), (0.3, 0.45), "top", "otherprop", ["printer"], (210, 210, 210)),
    _k("copier", slab, (0.6, 0.7), (0.6, 0.7), (1.0, 1.2), "wall", "otherfurniture", ["copier", "printer"], (210, 210, 215), solid=True),
    _k("trash can", trash_can, (0.25, 0.4), (0.25, 0.4), (0.3, 0.65), "corner", "otherprop", ["trash can", "bin"], (80, 80, 80)),
    _k("pillow", pillow, (0.4, 0.65), (0.3, 0.45), (0.12, 0.2), "top", "pillow", ["pillow", "cushion"], (220, 200, 180)),
    _k("bag", bag, (0.3, 0.45), (0.2, 0.3), (0.3, 0.45), "corner", "bag", ["bag", "backpack"], (60, 60, 90)),
    _k("box", slab, (0.25, 0.6), (0.25, 0.5), (0.2, 0.5), "corner", "box", ["box", "cardboard box"], (180, 140, 90)),
    _k("books", books, (0.18, 0.28), (0.14, 0.22), (0.1, 0.2), "top", "books", ["books", "book"], (140, 60, 60)),
    _k("rug", rug, (1.2, 2.4), (0.8, 1.7), (0.01, 0.02), "free", "floor mat", ["rug", "carpet"], (150, 60, 60)),
    _k("curtain", curtain, (1.0, 2.0), (0.1, 0.16), (1.8, 2.3), "wall", "curtain", ["curtain", "drape"], (200, 180, 150)),
    _k("radiator", radiator, (0.6, 1.2), (0.08, 0.12), (0.5, 0.7), "mount", "otherprop", ["radiator", "heater"], (235, 235, 235), mount_z=0.12),
    _k("picture", panel, (0.4, 1.0), (0.02, 0.04), (0.3, 0.8), "mount", "picture", ["picture", "painting"], (120, 100, 140), mount_z=1.3),
    _k("whiteboard", panel, (1.2, 2.0), (0.03, 0.05), (0.9, 1.2), "mount", "whiteboard", ["whiteboard"], (245, 245, 245), mount_z=0.9),
    _k("mirror", panel, (0.4, 0.8), (0.02, 0.03), (0.5, 0.9), "mount", "mirror", ["mirror"], (190, 200, 210), mount_z=1.15),
    _k("coat rack", coat_rack, (0.4, 0.5), (0.4, 0.5), (1.6, 1.8), "corner", "otherfurniture", ["coat rack", "coat stand"], (90, 60, 40)),
    _k("fan", fan, (0.35, 0.45), (0.35, 0.45), (1.0, 1.3), "corner", "otherprop", ["fan"], (220, 220, 220)),
    _k("bench", bench, (1.0, 1.6), (0.35, 0.45), (0.42, 0.48), "wall", "otherfurniture", ["bench"], (130, 100, 70)),
    _k("ottoman", slab, (0.45, 0.7), (0.45, 0.7), (0.38, 0.45), "free", "otherfurniture", ["ottoman", "footstool"], (130, 110, 100)),
    _k("storage bin", trash_can, (0.35, 0.5), (0.35, 0.5), (0.3, 0.5), "corner", "otherprop", ["basket", "storage bin"], (160, 130, 90)),
]}


def build(kind: Kind, size: tuple[float, float, float], rng: np.random.Generator) -> Shapes:
    return kind.builder(*size, rng)
