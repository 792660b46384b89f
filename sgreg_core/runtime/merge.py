"""N agents, one frame: the verified pairwise links of every agent turned into one pose per map.

Every agent publishes its verified links (T_a^b on /a/sgreg/registration). Pairwise links
alone never bend a map into another: one wrong link would, so before any pose is computed the
links are checked against each other around cycles. Each agent runs the same deterministic
steps on the same links, so all of them publish the same tree:

1. One measurement per directed link: the latest verified T_a^b of agent a for peer b, taken
   between the two agents' levelled frames (each map levelled on its own floor and walls,
   maps/level.py; Merger.update converts with the latest levellings it was given), so that it
   is a 4-DoF transform (yaw and translation). A link whose owner says it is no longer confirmed
   (withdrawn, contradicted) is dropped.
2. Consistency: a measurement's support counts the short cycles it closes within cycle_m /
   cycle_deg: 1 when the same pair measured the other way agrees (checked in both agents'
   frames), and one per consistent triangle a -> c -> b through a third agent and per pair of
   measurements of its two other sides (up to 4 per third agent). When the two agents of a
   pair disagree and no third agent's links decide, neither link is kept (two maps cannot tell
   which of their two estimates is wrong). The others are taken in order of support, then
   confidence, then published before withheld (a link its agent withholds as
   disputed_by_cycles, kept so the cycles can re-judge it); one joins the accepted set when it
   connects two groups of agents, or when it agrees with the path the accepted set already
   gives between its ends. Otherwise it breaks the cycles it is in and is rejected, with the
   reason. A wrong link in a cycle of right ones closes no consistent cycle, so it comes after
   them and is refused (in a ring measured one way each no link closes one, and confidence
   orders them); a link in no cycle (a bridge) cannot be checked and is kept, as the
   pair's own verdict and confirmation already are. When a rejected link is as well backed as
   the one accepted link on the path it contradicts that is no better backed than it (the rest
   of the path being better backed), or as the other link of its own pair, only the order
   decided between those two: both are set aside as contested (and disputed, so their agents
   withhold them) and the rest is merged again, so an agent that two equally trusted links
   place differently waits unattached until a further link settles it. In a longer cycle of
   equally weak links (a ring measured one way, three pairs each agreeing with itself) no
   single link is singled out, and the order stands.
3. Poses: the merged frame is the levelled frame of the anchor, the lowest agent id of the
   largest group (so a lone agent with a low id cannot hide the fleet); every other agent's
   pose is the confidence-weighted average over all its accepted measurements of (neighbour
   pose o measurement), iterated to a fixed point (circular mean for yaw), so a map reached by
   several paths sits where they agree best. Published poses compose the agent's levelling:
   T_merged<-map = T_merged<-levelled R.

Agents that no accepted path joins to the anchor are not attached; they form groups of their
own, reported but not placed in the merged frame.

Public API:
    MergeConfig
    Link                      one verified T_src^dst with its confidence and stamp
    MergeResult               poses (agent -> 4x4 T_merged<-levelled agent), attached, groups,
                              accepted / rejected links (rejected: link, reason), disputed
                              (links the cycles through a third agent reject)
    merge(links, agents, cfg) -> MergeResult
    Links                     the latest link state per directed pair, fed with results
    Merger                    one agent's merger: levellings + Links + merge + what changed +
                              which peers need no more dense data (settled, placed by others),
                              which links are disputed
    to_4dof(T) -> (yaw, t)    (geometry.yaw_transform(yaw, t) is its inverse)
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import param
from ..geometry import MAX_COORD_M, invert_transform, is_rigid, is_rotation, yaw_transform
from ..maps.level import MAX_TILT_DEG, tilt_deg
from .clock import stamp_ns as _stamp_ns


@dataclass
class MergeConfig:
    """merged_frame: the name of the shared frame (the parent of every attached <id>/map).
    cycle_m / cycle_deg: measurements that close a cycle (or agree with the accepted path)
        within this translation / rotation are consistent. A cycle composes several links, so
        this is wider than one link's agreement.
    max_link_age_s: a link made from maps this much older than the newest maps its own pair's
        last results (either way, verified or not) were made from is left out (0: links never
        age): the pair has moved on and no longer verifies it. Measured on the maps' stamps, not
        a node's clock: every agent's merger hears the same results and keeps the same links,
        and a replayed bag ages its links as it did live. Per pair, so that one agent whose
        clock runs ahead (or that fell silent after it) ages no other pair's links.
    average_iters: fixed-point iterations of the pose averaging."""

    merged_frame: str = param("sgreg_merged", "the shared frame every attached agent map is placed in")
    cycle_m: float = param(0.5, "links closing a cycle within this translation (m) are consistent",
                           0.01, 10.0)
    cycle_deg: float = param(5.0, "links closing a cycle within this rotation (deg) are consistent",
                             0.1, 90.0)
    max_link_age_s: float = param(0.0, "leave out links from maps this much older than their pair's "
                                  "newest results' (s; 0: never)", 0.0, 86400.0)
    average_iters: int = 30


def to_4dof(T: np.ndarray) -> tuple[float, np.ndarray]:
    """Yaw (rad) and translation of a transform; roll and pitch are dropped."""
    T = np.asarray(T, np.float64)
    return float(np.arctan2(T[1, 0], T[0, 0])), T[:3, 3].copy()


def _deviation(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Translation (m) and yaw (deg) between two 4-DoF transforms."""
    D = invert_transform(A) @ B
    yaw, t = to_4dof(D)
    return float(np.linalg.norm(t)), float(abs(np.degrees(yaw)))


@dataclass(frozen=True)
class Link:
    """T maps src's map into dst's (T_src^dst, as agent src publishes it for peer dst)."""

    src: str
    dst: str
    T: np.ndarray = field(compare=False, hash=False)
    confidence: float = 1.0
    stamp_ns: int = 0        # of the newer map it was estimated from
    # kept only for the cycles to re-judge: its agent withholds it (disputed_by_cycles)
    withheld: bool = False

    @property
    def key(self) -> tuple[str, str]:
        return self.src, self.dst

    def towards(self, a: str) -> np.ndarray:
        """The transform that maps the other end's map into a's."""
        return self.T if self.dst == a else invert_transform(self.T)


@dataclass
class MergeResult:
    poses: dict[str, np.ndarray]          # attached agent -> T_merged<-agent's levelled frame (4-DoF)
    anchor: str | None
    attached: list[str]
    groups: list[list[str]]               # every agent, by connected group (anchor's first)
    accepted: list[Link]
    rejected: list[tuple[Link, str]]      # (link, one-line reason)
    disputed: set = field(default_factory=set)   # keys of rejected links a third agent's links contradict
    checked: set = field(default_factory=set)    # attached agents an accepted link that closes a
                                                 # consistent triangle places (not a bridge)

    def to_json(self) -> dict:
        return {"anchor": self.anchor, "attached": self.attached, "groups": self.groups,
                "accepted": [f"{l.src}->{l.dst}" for l in self.accepted],
                "rejected": {f"{l.src}->{l.dst}": why for l, why in self.rejected},
                "poses": {a: np.round(T, 6).tolist() for a, T in self.poses.items()}}


_BLOCK = 256   # links per block of the triangle check


def _support(links: list[Link], cfg: MergeConfig) -> tuple[dict, dict]:
    """Per link, the consistent short cycles it closes: ({key: 1 when the pair's other
    measurement agrees}, {key: consistent triangles through a third agent}). Vectorised over
    links and third agents: a fleet of 17 agents has 272 links and 16,000 triangle checks
    every merge period."""
    pair, triangles = dict.fromkeys((l.key for l in links), 0), dict.fromkeys((l.key for l in links), 0)
    if not links:
        return pair, triangles
    agents = sorted({a for l in links for a in l.key})
    idx = {a: i for i, a in enumerate(agents)}
    n = len(agents)
    # M[a, b, k]: T_a^b measured by a's link (k = 0) and by b's link, inverted (k = 1)
    src = np.array([idx[l.src] for l in links])
    dst = np.array([idx[l.dst] for l in links])
    T = np.stack([l.T for l in links])                                          # (L, 4, 4)
    inv_T = np.stack([invert_transform(l.T) for l in links])
    M = np.tile(np.eye(4), (n, n, 2, 1, 1))
    have = np.zeros((n, n, 2), bool)
    M[src, dst, 0], have[src, dst, 0] = T, True
    M[dst, src, 1], have[dst, src, 1] = inv_T, True
    # the pair's other measurement: the link dst -> src, inverted; compared in both agents'
    # frames (the lever arm differs), so that both links of a pair get the same answer
    pair_ok = have[src, dst, 1] & _consistent_many(inv_T, M[src, dst, 1], cfg) \
        & _consistent_many(T, M[dst, src, 0], cfg)     # A^-1 B in a's frame, A B^-1 in b's
    # triangles: T_c^b @ T_a^c for every third agent c and every pair of measurements (k1, k2),
    # in blocks of links so that memory stays bounded (L x n stacks of 4x4 grow as n^3)
    counts = np.zeros(len(links), int)
    for lo in range(0, len(links), _BLOCK):
        s_, d_ = src[lo:lo + _BLOCK], dst[lo:lo + _BLOCK]
        T_ac = M[s_][:, :, :, None]                                             # (B, n, 2, 1, 4, 4)
        T_cb = M[:, d_].transpose(1, 0, 2, 3, 4)[:, :, None]                   # (B, n, 1, 2, 4, 4)
        valid = have[s_][:, :, :, None] & have[:, d_].transpose(1, 0, 2)[:, :, None, :]
        valid[np.arange(len(s_)), s_] = valid[np.arange(len(s_)), d_] = False  # c is a third agent
        ok = _consistent_many(inv_T[lo:lo + _BLOCK, None, None, None], T_cb @ T_ac, cfg) & valid
        counts[lo:lo + _BLOCK] = ok.reshape(len(s_), -1).sum(axis=1)
    for l, p_, c in zip(links, pair_ok, counts):
        pair[l.key], triangles[l.key] = int(p_), int(c)
    return pair, triangles


def _consistent_many(inv_A: np.ndarray, B: np.ndarray, cfg: MergeConfig) -> np.ndarray:
    """_consistent(A, B) over broadcast stacks, given inv(A)."""
    D = inv_A @ B
    dt = np.linalg.norm(D[..., :3, 3], axis=-1)
    dyaw = np.abs(np.degrees(np.arctan2(D[..., 1, 0], D[..., 0, 0])))
    return (dt < cfg.cycle_m) & (dyaw < cfg.cycle_deg)


def _consistent(A: np.ndarray, B: np.ndarray, cfg: MergeConfig) -> bool:
    return bool(_consistent_many(invert_transform(A), B, cfg))


class _Forest:
    """The accepted links: one edge per pair (its first accepted measurement), and a spanning
    forest of them in which each agent keeps its pose in its tree's root (T_agent^root). The
    path transform between two joined agents is then one product, and joining two trees
    re-poses the smaller one, so a fleet of n agents checks its n^2 links at O(1) each. The
    forest's links are walked only for a rejected link, to name those on the path it broke."""

    def __init__(self, names: list[str]):
        self.graph: dict[str, dict[str, Link]] = {a: {} for a in names}    # every pair's edge
        self.tree: dict[str, dict[str, Link]] = {a: {} for a in names}     # the spanning edges
        self.root = {a: a for a in names}
        self.members = {a: [a] for a in names}
        self.P = {a: np.eye(4) for a in names}       # T_agent^root

    def path_T(self, a: str, b: str) -> np.ndarray | None:
        """T_a^b by the pair's own accepted link where there is one, else along the forest
        (None when a and b are not joined). A pair's second measurement is checked against its
        first alone, which the tree path was checked against: the two may lie up to twice the
        cycle tolerance from that path."""
        if a == b:
            return np.eye(4)
        if b in self.graph[a]:
            return self.graph[a][b].towards(b)
        if self.root[a] != self.root[b]:
            return None
        return invert_transform(self.P[b]) @ self.P[a]

    def path_links(self, a: str, b: str) -> list[Link]:
        """The links on the forest's path from a to b (a and b joined): the path path_T composes
        when the pair has no edge of its own."""
        seen, stack = {a: []}, [a]
        while stack:
            x = stack.pop()
            for y, l in self.tree[x].items():
                if y not in seen:
                    seen[y] = seen[x] + [l]
                    stack.append(y)
        return seen[b]

    def add(self, l: Link) -> None:
        """An accepted link: the first of its pair is the pair's edge; one that joins two trees
        re-poses the smaller into the larger's root."""
        if l.dst in self.graph[l.src]:
            return
        self.graph[l.src][l.dst] = self.graph[l.dst][l.src] = l
        keep, move = self.root[l.src], self.root[l.dst]
        if keep == move:
            return
        self.tree[l.src][l.dst] = self.tree[l.dst][l.src] = l
        # G maps the moved root into the kept one: T_src^keep T_dst^src T_move^dst
        G = self.P[l.src] @ invert_transform(l.T) @ invert_transform(self.P[l.dst])
        if len(self.members[keep]) < len(self.members[move]):
            keep, move, G = move, keep, invert_transform(G)
        moved = self.members.pop(move)
        for c, P in zip(moved, G @ np.stack([self.P[c] for c in moved])):
            self.root[c], self.P[c] = keep, P
        self.members[keep] += moved


def _greedy(order: list[Link], names: list[str], support: dict, triangles: dict,
            cfg: MergeConfig) -> tuple[list[Link], list[tuple[Link, str]], set, set]:
    """Step 2 on links in order: (accepted, rejected with reasons, keys of disputed links,
    contested pairs: a rejected link broke a cycle whose accepted links are no better backed
    than it, so that only the order decided between them)."""
    forest = _Forest(names)
    accepted, rejected, disputed, contested = [], [], set(), set()
    for l in order:
        found = forest.path_T(l.src, l.dst)
        if found is not None and not _consistent(l.T, found, cfg):
            dt, dyaw = _deviation(l.T, found)
            rejected.append((l, f"breaks the cycles it is in: {dt:.2f} m / {dyaw:.1f} deg from the "
                                f"path of the accepted links (closes {triangles[l.key]} consistent "
                                "cycles through other agents)"))
            # disputed by other agents' links when the path runs through them, or when the link
            # of the same pair it contradicts is backed by a triangle
            # (the pair's accepted link is its edge: the other one, as this one is rejected)
            edge = forest.graph[l.src].get(l.dst)
            if edge is None or triangles[edge.key]:
                disputed.add(l.key)
            if edge is not None:
                # a pair at odds with itself, each side as well backed by other agents' links
                # (one agent misplaced against two that agree, or the reverse): only the order
                # chose, so the pair waits
                if support[edge.key] == support[l.key]:
                    contested.add(frozenset(l.key))
            else:
                # one link against one: the rest of the path backs the accepted link's side, and
                # the two are equally backed (in a longer cycle of weak links, no single link is
                # singled out by the cycle, and the order of support and confidence stands)
                weak = [m for m in forest.path_links(l.src, l.dst) if support[m.key] <= support[l.key]]
                if len(weak) == 1:
                    contested |= {frozenset(l.key), frozenset(weak[0].key)}
            continue
        accepted.append(l)
        forest.add(l)
    return accepted, rejected, disputed, contested


def merge(links: list[Link], agents: list[str] | None = None,
          cfg: MergeConfig | None = None) -> MergeResult:
    """The consistent links and one pose per attached agent (see the module docstring)."""
    cfg = cfg or MergeConfig()
    links = sorted(links, key=lambda l: l.key)           # deterministic, whatever the arrival order
    keys = [l.key for l in links]
    if len(set(keys)) < len(keys) or any(a == b for a, b in keys):
        raise ValueError("merge: one measurement per directed link between two agents (Links keeps "
                         "the latest), and none of an agent to itself")
    names = sorted(set(agents or []) | {a for l in links for a in l.key})
    pair, triangles = _support(links, cfg)
    rejected, disputed = [], set()
    # a pair whose two measurements disagree, with no third agent's word for either: neither
    both = defaultdict(list)
    for l in links:
        both[frozenset(l.key)].append(l)
    undecided = {l.key for ls in both.values() if len(ls) == 2 and not pair[ls[0].key]
                 and not triangles[ls[0].key] and not triangles[ls[1].key] for l in ls}
    for l in links:
        if l.key in undecided:
            rejected.append((l, f"{l.src} and {l.dst} disagree about their pair and no third agent's "
                                "links decide"))
    support = {k: pair[k] + triangles[k] for k in pair}
    # at equal support and confidence (1.0 is common: float32 saturates), a withheld link comes
    # after the published ones: its own agent says the merged frame disagrees with it, and the
    # agents' names must not let it push out the links that placed that frame (and with them
    # the guard that withholds it)
    order = sorted((l for l in links if l.key not in undecided),
                   key=lambda l: (-support[l.key], -l.confidence, l.withheld, l.key))
    # a cycle that only the order of equally backed links decided keeps none of them (their
    # agents wait for a link that settles it); the rest is merged again without them
    contested: set = set()
    while True:
        keep = [l for l in order if frozenset(l.key) not in contested]
        accepted, broken, disputed, more = _greedy(keep, names, support, triangles, cfg)
        if not more:
            break
        contested |= more
    for l in order:
        if frozenset(l.key) in contested:
            rejected.append((l, "contested: it and the links it disagrees with close no more "
                                "consistent cycles than each other, so no majority decides"))
            disputed.add(l.key)
    rejected += broken
    groups = _groups(names, accepted)
    attached = max(groups, key=len) if groups else []     # the largest group, the lowest id on ties
    anchor = attached[0] if attached else None
    poses = _average(attached, anchor, [l for l in accepted if l.src in attached], cfg)
    checked = {a for l in accepted if triangles[l.key] for a in l.key} & set(attached)
    return MergeResult(poses=poses, anchor=anchor, attached=attached, groups=groups,
                       accepted=accepted, rejected=rejected, disputed=disputed, checked=checked)


def _groups(names: list[str], accepted: list[Link]) -> list[list[str]]:
    """Connected groups of agents under the accepted links, ordered by their lowest id."""
    parent = {a: a for a in names}

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for l in accepted:
        parent[root(l.src)] = root(l.dst)
    groups = defaultdict(list)
    for a in names:
        groups[root(a)].append(a)
    return sorted((sorted(g) for g in groups.values()), key=lambda g: g[0])


def _average(group: list[str], anchor: str | None, links: list[Link],
             cfg: MergeConfig) -> dict[str, np.ndarray]:
    """4-DoF poses T_merged<-agent of one group: the anchor at the identity, the others at the
    weighted average of what their accepted measurements say, iterated to a fixed point."""
    if anchor is None or anchor not in group:
        return {}
    forest = _Forest(group)
    for l in links:
        forest.add(l)
    # start from the spanning paths: T_merged<-a = T_a^anchor
    index = {a: i for i, a in enumerate(group)}
    P = np.stack([yaw_transform(*to_4dof(forest.path_T(a, anchor))) for a in group])
    # per agent, its measurements: (the other ends, T_a^other, weights)
    around = {a: ([], [], []) for a in group}
    for l in links:
        for a, other in ((l.src, l.dst), (l.dst, l.src)):
            around[a][0].append(index[other])
            around[a][1].append(l.towards(other))
            around[a][2].append(max(l.confidence, 1e-3))
    around = {a: (np.array(o), np.stack(T), np.asarray(w) / np.sum(w)) for a, (o, T, w) in around.items() if o}
    for _ in range(cfg.average_iters):
        moved = 0.0
        for a in group:
            if a == anchor or a not in around:
                continue
            others, Ts, w = around[a]
            Q = P[others] @ Ts          # the pose of a through each measurement: T_merged<-other @ T_a^other
            yaws = np.arctan2(Q[:, 1, 0], Q[:, 0, 0])
            yaw = float(np.arctan2(w @ np.sin(yaws), w @ np.cos(yaws)))
            t = w @ Q[:, :3, 3]
            old_yaw, old_t = to_4dof(P[index[a]])
            moved = max(moved, float(np.linalg.norm(t - old_t)),
                        abs(float(np.angle(np.exp(1j * (yaw - old_yaw))))))
            P[index[a]] = yaw_transform(yaw, t)
        if moved < 1e-6:
            break
    return {a: P[index[a]] for a in group}


class Links:
    """The latest state of every directed link, fed with every registration result of every
    agent (verified or not). A verified result sets the link, and so does one withheld only
    because the cycles dispute the link (reason "disputed_by_cycles": the cycles must keep
    seeing the link's pose to re-judge it); a result that says the link is no longer confirmed
    (withdrawn, contradicted, restarted) drops it; other failed estimates of a confirmed link
    leave it."""

    def __init__(self):
        self._links: dict[tuple[str, str], Link] = {}
        self.agents: set[str] = set()
        # the map stamp of each directed pair's last result, verified or not: what the pair's
        # links age against (the last, not the largest ever, so that one stamp far ahead or a
        # bag played again ages them only until that pair's next result)
        self._heard_ns: dict[tuple[str, str], int] = {}

    def take(self, agent: str, peer: str, T: np.ndarray, verified: bool, reason: str,
             link_state: str, confidence: float, stamp_ns: int) -> bool:
        """False (nothing taken) for a result of an agent about itself, and for a link to keep
        whose transform is not rigid, lies beyond MAX_COORD_M or whose confidence is not a
        number: a NaN or an overflow would spread through every pose averaged with it."""
        keep = verified or reason == "disputed_by_cycles"
        if agent == peer or (keep and not (is_rigid(T) and np.isfinite(confidence)
                                           and np.abs(np.asarray(T)[:3, 3]).max() <= MAX_COORD_M)):
            return False
        self.agents |= {agent, peer}
        stamp_ns = _stamp_ns(stamp_ns)
        self._heard_ns[(agent, peer)] = stamp_ns
        if keep:
            self._links[(agent, peer)] = Link(agent, peer, np.asarray(T, np.float64), float(confidence),
                                              stamp_ns, withheld=not verified)
        elif link_state != "confirmed":
            self._links.pop((agent, peer), None)
        return True

    def drop(self, agent: str, peer: str) -> None:
        """agent's link to peer is taken back outside any result (Peers.on_peer_result)."""
        self._links.pop((agent, peer), None)

    def forget(self, agent: str) -> None:
        """Every link to or from agent, and what was heard of its pairs: it went silent."""
        self.agents.discard(agent)
        for d in (self._links, self._heard_ns):
            for key in [k for k in d if agent in k]:
                del d[key]

    def current(self, max_age_s: float = 0.0) -> list[Link]:
        """The links, without those made from maps more than max_age_s older than the newest
        maps of their pair's last results (0: all)."""
        links = list(self._links.values())
        if max_age_s > 0:
            def newest(l: Link) -> int:
                return max(self._heard_ns.get(l.key, 0), self._heard_ns.get(l.key[::-1], 0))
            links = [l for l in links if (newest(l) - l.stamp_ns) * 1e-9 <= max_age_s]
        return links


class Merger:
    """What an agent's merger keeps: every agent's levelling and links, the last merge, and the
    one-line news of what changed (a link rejected, an agent attached) for the log.

    set_level(agent, R): the rotation that levels agent's map (from its graph messages; the
    identity until known). take(...): a result T_agent^peer between the maps as published,
    kept as it is; each merge takes it between the levelled frames, T = R_peer T R_agent^T,
    with the levellings of that moment, the same ones raw_poses() composes: the merged poses
    of the maps as they are, T_merged<-map = T_merged<-levelled R (what /tf carries). (Kept
    levelled with the levellings of when it came, a link would place a map wrong once the
    peer levelled it anew.)"""

    def __init__(self, cfg: MergeConfig, agent: str):
        self.cfg, self.agent = cfg, agent
        self.links = Links()
        self.levels: dict[str, np.ndarray] = {}
        self.result = merge([], [agent], cfg)

    def set_level(self, agent: str, R: np.ndarray) -> bool:
        """False (the agent's levelling unchanged) for R that is not a rotation tilting by at
        most MAX_TILT_DEG (as a peer's levelling is checked where it arrives)."""
        if not (is_rotation(R) and tilt_deg(R) <= MAX_TILT_DEG):
            return False
        self.levels[agent] = np.asarray(R, np.float64)
        return True

    def _level_T(self, agent: str) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.levels.get(agent, np.eye(3))
        return T

    def take(self, agent: str, peer: str, T: np.ndarray, verified: bool, reason: str,
             link_state: str, confidence: float, stamp_ns: int) -> bool:
        """Links.take: False when refused."""
        # as float32 in [0, 1], what the other agents' mergers get over the wire (convert clips
        # it): the same order for all, and no result wins every tie by a confidence above 1
        confidence = float(np.float32(np.clip(confidence, 0.0, 1.0)))
        return self.links.take(agent, peer, T, verified, reason, link_state, confidence, stamp_ns)

    def drop(self, agent: str, peer: str) -> None:
        """Links.drop."""
        self.links.drop(agent, peer)

    def forget(self, agent: str) -> None:
        """Links.forget, and agent's levelling: a peer this agent no longer listens to (gone
        silent) is not kept on /tf by its last links."""
        self.links.forget(agent)
        self.levels.pop(agent, None)

    def _levelled(self, link: Link) -> Link:
        """The link between the two agents' levelled frames, with the current levellings."""
        return replace(link, T=self._level_T(link.dst) @ link.T @ invert_transform(self._level_T(link.src)))

    def raw_poses(self) -> dict[str, np.ndarray]:
        return {a: T @ self._level_T(a) for a, T in self.result.poses.items()}

    def expected(self, peer: str) -> np.ndarray | None:
        """T_agent^peer between the maps as the merged frame places them, when accepted links
        other than the pair's own join the two (so that other agents' links take part), else
        None: in a chain a - b - c, a's own link is all that places b for a."""
        poses = self.raw_poses()
        pair = {self.agent, peer}
        if not pair <= set(poses):
            return None
        others = [l for l in self.result.accepted if set(l.key) != pair]
        names = sorted(set(poses) | {a for l in others for a in l.key})   # groups not attached too
        if not any(pair <= set(g) for g in _groups(names, others)):
            return None
        return invert_transform(poses[peer]) @ poses[self.agent]

    def update(self) -> list[str]:
        """Merge the current links; returns what changed since the last merge, one line each."""
        old = self.result
        links = [self._levelled(l) for l in self.links.current(self.cfg.max_link_age_s)]
        self.result = merge(links, sorted({a for l in links for a in l.key} | {self.agent}), self.cfg)
        news = []
        for a in sorted(set(self.result.attached) - set(old.attached)):
            news.append(f"{a}/map attached to {self.cfg.merged_frame} (anchor {self.result.anchor})")
        for a in sorted(set(old.attached) - set(self.result.attached)):
            news.append(f"{a}/map no longer attached to {self.cfg.merged_frame}")
        before = {l.key for l, _ in old.rejected}
        for l, why in self.result.rejected:
            if l.key not in before:
                news.append(f"link {l.src} -> {l.dst} rejected: {why}")
        return news

    def disputed_peers(self) -> set[str]:
        """Peers this agent's own link to is rejected by cycles through other agents (a
        disagreement within a pair alone disputes neither side: each link's own rules judge it)."""
        return {l.dst for l, _ in self.result.rejected if l.src == self.agent and l.key in self.result.disputed}

    def placed_by_others(self) -> set[str]:
        """Settled peers that a link closing a consistent triangle places in the merged frame:
        other agents' links already place them, and not through a bridge no cycle checks."""
        return self.settled_peers() & self.result.checked

    def settled_peers(self) -> set[str]:
        """Peers placed in this agent's merged frame whose links with it no cycle disputes:
        more dense data from them would not place them better."""
        if self.agent not in self.result.attached:
            return set()
        rejected_own = {l.dst for l, _ in self.result.rejected if l.src == self.agent}
        return set(self.result.attached) - rejected_own - {self.agent}
