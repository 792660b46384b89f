"""Offline replay: every agent's core and peers in one process, on a virtual clock, over an
ideal link. The same AgentCore and Peers the nodes run, fed the same maps and messages
(features through the same wire encoding), without DDS, processes or wall time: deterministic
and several times faster than real time, for choosing thresholds over many bags and for tests
of the protocol's logic. `sgreg replay` (real nodes) remains the measurement that is reported.

What the ideal link leaves out: message latency and loss, CPU contention between nodes (a
busy registration node skips coarse graphs that arrive while it computes), DDS discovery.

Every agent also runs its merger (runtime/merge.py) on every agent's results, as the nodes do
(each registration node hears every agent's sgreg/registration), which tells its Peers which
peers need no more dense data.

Public API:
    OfflineReplayConfig
    offline_replay(maps, model, cfg, log, merges=None, counters=None) -> list[ResultRecord]
        maps: (t, agent, InstanceMap) map snapshots in time order (t in bag seconds);
        merges: a dict, filled with each agent's last MergeResult;
        counters: a dict, filled with each agent's counters (one table for its AgentCore and
            Peers: the requests it sent, retried and gave up beside those it refused to
            answer), what the two nodes of an agent report between them
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field, replace

import numpy as np

from ..net.model import SGRegModel
from ..runtime.agent import AgentConfig, AgentCore
from ..runtime.clock import seconds_to_ns
from ..runtime.messages import GraphMessage
from ..runtime.merge import MergeConfig, Merger
from ..runtime.peers import Peers, PeersConfig, check_request_size
from ..runtime.wire import DEFAULT_ENCODING, ENCODINGS, pack_features, unpack_features
from ..types import InstanceMap
from .replay_score import ResultRecord


@dataclass
class OfflineReplayConfig:
    """coarse_period_s: seconds between two coarse graphs of one agent (each agent's timer
    starts at a seeded phase, as independent nodes do); tail_s: how long the agents go on
    after the last map; feature_encoding: what node descriptors lose on the wire; agent /
    peers / merge: the settings every agent runs (agent.name is set per agent); seed: the
    timer phases."""

    coarse_period_s: float = 1.0
    tail_s: float = 6.0
    feature_encoding: str = DEFAULT_ENCODING
    agent: AgentConfig = field(default_factory=AgentConfig)
    peers: PeersConfig = field(default_factory=PeersConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)
    seed: int = 0

    def __post_init__(self):
        check_request_size(self.peers, self.agent)     # refused before any bag, not at the first


def _over_the_wire(msg: GraphMessage, encoding: int) -> GraphMessage:
    """The message as a peer decodes it: descriptors through the wire encoding."""
    desc = msg.nodes.descriptor
    payload, scales = pack_features(desc, encoding)
    nodes = replace(msg.nodes, descriptor=unpack_features(payload, *desc.shape, encoding, scales),
                    centers=msg.nodes.centers.astype(np.float32))
    return replace(msg, nodes=nodes, extents=msg.extents.astype(np.float32))


def offline_replay(maps: list[tuple[float, str, InstanceMap]], model: SGRegModel,
                   cfg: OfflineReplayConfig | None = None, log=lambda s: None,
                   merges: dict | None = None, counters: dict | None = None) -> list[ResultRecord]:
    """Every estimate every agent makes while the maps arrive, as replay records (t and bag_t
    both in bag seconds)."""
    cfg = cfg or OfflineReplayConfig()
    encoding = ENCODINGS[cfg.feature_encoding]
    names = sorted({name for _, name, _ in maps})
    agents = {n: AgentCore(AgentConfig(**{**cfg.agent.__dict__, "name": n}), model) for n in names}
    peers_of = {n: Peers(cfg.peers, agents[n], model, log=log) for n in names}
    mergers = {n: Merger(cfg.merge, n) for n in names}
    map_seq = dict.fromkeys(names, 0)
    rng = np.random.default_rng(cfg.seed)
    end = (maps[-1][0] if maps else 0.0) + cfg.tail_s
    # (time, order, kind, agent, payload): maps before coarse ticks at equal times
    events = [(t, 0, i, name, imap) for i, (t, name, imap) in enumerate(maps)]
    t_first = maps[0][0] if maps else 0.0
    events += [(t_first + rng.uniform(0, cfg.coarse_period_s), 1, 0, n, None) for n in names]
    heapq.heapify(events)
    records: list[ResultRecord] = []

    def record(agent: str, est, now: float) -> None:
        if est is not None:
            for m in mergers.values():       # every agent hears every agent's results (and graphs)
                m.set_level(agent, agents[agent].level.R)
                m.set_level(est.peer_id, agents[est.peer_id].level.R)
                m.take(agent, est.peer_id, est.T, est.verified, est.reason, est.link, est.confidence, est.stamp_ns)
            # the peer hears the result too (its witness for the link, Peers.on_peer_result)
            if peers_of[est.peer_id].on_peer_result(agent, est.T, est.verified, est.mode, est.reason,
                                                    est.link, now):
                mergers[est.peer_id].drop(est.peer_id, agent)    # as the node does
            records.append(ResultRecord(t=now, agent=agent, peer=est.peer_id, T=est.T,
                                        verified=est.verified, mode=est.mode, reason=est.reason,
                                        node_matches=est.node_matches, inliers=est.inliers,
                                        total_ms=float(est.timing_ms.get("total", 0.0)),
                                        confidence=est.confidence, bag_t=now,
                                        evidence=est.evidence, link=est.link, stamp_ns=est.stamp_ns))

    while events:
        now, kind, _, name, imap = heapq.heappop(events)
        if now > end:
            break
        agent = agents[name]
        if kind == 0:
            why = peers_of[name].take_own_map(imap, map_seq[name], seconds_to_ns(now))
            map_seq[name] += 1
            if why is not None:
                log(f"{name}: {why}")
                continue
            for est, req in peers_of[name].on_own_map(now):
                record(name, est, now)
                if req is not None:
                    _deliver(req, agents, peers_of, name, encoding, now, record)
            continue
        heapq.heappush(events, (now + cfg.coarse_period_s, 1, 0, name, None))
        for line in mergers[name].update():
            log(f"{name}: {line}")
        peers_of[name].follow(mergers[name])
        for req in peers_of[name].on_tick(now):
            _deliver(req, agents, peers_of, name, encoding, now, record)
        if not agent.coarse_due(now):
            continue
        coarse = _over_the_wire(agent.broadcast(now), encoding)
        for peer in names:
            if peer == name:
                continue
            est, req = peers_of[peer].on_coarse(coarse, now)
            record(peer, est, now)
            if req is not None:
                _deliver(req, agents, peers_of, peer, encoding, now, record)
    if merges is not None:
        for name, m in mergers.items():
            m.update()
            merges[name] = m.result
    if counters is not None:
        for name in names:
            counters[name] = dict(agents[name].counters)
    return records


def _deliver(req, agents, peers_of, requester: str, encoding: int, now: float, record) -> None:
    """A dense request reaches its agent; an answer goes straight back to the requester."""
    dense, _ = agents[req.to_agent].answer_request(req, now)
    if dense is not None:
        record(requester, peers_of[requester].on_dense(_over_the_wire(dense, encoding), now), now)
