"""Per-peer registration: the coarse-to-fine protocol of SG-Reg (paper section VI) as a plain
state machine, with every failure of docs/ARCHITECTURE.md ("Failure behaviour") turned into a counter and a one-line
reason instead of an exception.

For each peer: coarse graphs arrive at ~1 Hz -> an estimate from node centers (merged with the
point correspondences kept from the link's last dense estimate) and, when enough nodes match and
the minimum interval has passed, a dense request (as soon as the peer answers again when only
its points can take a coarse estimate that passed the verdict further: prompt_request). Before
the peer's points are at hand a coarse estimate cannot be verified: when a request goes out for
it, the dense answer answers the query and no coarse result is published (counter
deferred_to_dense). A dense answer -> point matching -> a dense estimate. Every estimate runs
the one pipeline of pipeline.py (same code and verdict as `sgreg register` and the benchmarks),
with the peer's graph as source and the agent's own as reference, so verification checks the
peer's sampled points against the agent's full cloud.

An estimate that passes the verdict is not yet published as verified. The link to a peer is:
- none -> candidate: a first estimate that passes the verdict;
- candidate -> confirmed: a second one, made from other data (a map of either agent with other
  content, or the other kind of correspondences: points of a dense answer against node centers
  of a coarse graph), at least one of the two dense (confirm_with_dense), and agreeing with the
  candidate (within agree_m / agree_deg); or one that the peer's own estimates of the link
  witness (heard on its sgreg/registration, made from this agent's points against the peer's
  whole map, so other data by construction; confirm_with_peer): the peer's confirmed link, or
  for a dense estimate a dense one of the peer that passed its verdict. When a dense answer
  arrives while no link is confirmed, the coarse estimate of the same graphs, now verifiable
  on its points, is made beside it, unpublished (coarse_with_dense): the second estimate that
  the next coarse graph would bring, so a right first dense estimate that it agrees with is
  confirmed at once. Every estimate of a first confirmation (the one the peer's word confirms
  too) rests on at least first_link_min_objects inlier objects. The transform is published
  from then on, for every estimate that passes the verdict and agrees with the link;
- confirmed -> none: an estimate made from new data (not merged with kept correspondences)
  that passes the verdict but disagrees with the link withdraws it (reason "contradicted"); it
  becomes the new candidate and nothing is published for that peer until a link is confirmed
  again. A link that the peer's word confirmed falls back to a candidate when the peer says its
  own link was contradicted (counter withdrawn_with_peer): the word is taken back.
Merged estimates rest on kept correspondences, which are no new evidence: they can keep a
confirmed link but never confirm or contradict one. The kept correspondences are re-checked
whenever either map changes: when the nodes they come from have moved in either map (a
front end that re-anchors its map, a peer whose frame jumped) they are dropped together with
the peer's dense cloud (so too when either map is levelled anew), and every merged estimate
that fails the verdict drops them too. Without kept correspondences the peer's dense cloud is
dropped when the nodes of the answer it came with have moved in the peer's map. Without a dense
cloud of the peer nothing is verified at all, so new points are then asked for at the search
interval, not the confirmed link's, and promptly when a coarse estimate passes the verdict
(prompt_request).
An estimate the verdict refused only for its confidence is taken when the peer's confirmed
link agrees with it (vouched_min_confidence). With first_link_hold_s, a first confirmation also
waits until the candidate has stood that long; with withdraw_on_tie, a confirmed link is
withdrawn when an estimate from new data finds a competing pose nearly as well supported
(refused as ambiguous). Both are for floors of identical rooms (config/profiles/identical_rooms.yaml).

With more agents, the merger (runtime/merge.py) checks every agent's links around cycles: while
it rejects this agent's link with a peer, estimates of that link are withheld (reason
"disputed_by_cycles"), though the link itself stays for the cycles to re-judge.

What a peer's message must be before it is used is runtime/intake.py; the kept correspondences
and the checks that they still hold, runtime/kept.py.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..config import param
from ..geometry import invert_transform, is_rigid
from ..metrics import rre, rte
from ..net.model import NodeFeatures, SGRegModel
from ..maps.level import Levelling
from ..pipeline import PipelineConfig, Registration, register_features, to_map_frames
from .agent import AgentConfig, AgentCore
from .intake import check_message
from .kept import Kept, centers_of, dense_shift, levelled_alike, median_shift, moved_between
from .merge import MergeConfig
from .messages import DenseRequestMessage, Estimate, GraphMessage


@dataclass
class PeersConfig:
    """min_node_matches: node matches needed before asking a peer for dense data.
    max_request_nodes: a dense request names at most this many of the peer's nodes, those of
        its most confident node matches: point matching and the peer's shape features cost per
        node, and a few dozen objects fix a pose (in a building's 200-node maps this keeps a
        dense estimate near a second and the answer small). Never below
        AgentConfig.min_nodes (check_request_size): an answer on fewer would be refused.
    min_request_interval_s: at most one dense request per peer per this interval once a link to
        it is confirmed. A request goes out only when either map changed since the last
        answered exchange: the same two graphs give the same dense estimate, so asking again
        would only cost bandwidth (an unanswered request is asked again).
    search_request_interval_s: the interval while no link is confirmed: dense exchanges find a
        first link, and confirm it, in seconds.
    attached_request_interval_s: the interval to a peer that the merger places in the agent's
        merged frame with no cycle disputing it (Peers.attached), when the link to it is
        confirmed (and its points at hand), or, with no link of this agent's own, when other
        agents' links place it through a consistent triangle (Peers.placed; a bridge no cycle
        checks is still searched every search interval, since this agent's own link is what
        would check it): more dense data would not place it better, so with N agents each
        one's dense traffic stays near the two-agent figure instead of growing with N^2
        (runtime/merge.py).
    request_timeout_s: an unanswered request is retried after this, then after
        timeout * retry_backoff^k, up to max_retries; then the link gives up until the next
        interval.
    min_coarse_matches: node matches needed to attempt a coarse estimate.
    sequence_window: a sequence is taken when it lies 1..window past the last one. Anything
        else (a jump, a step back) is held and taken only when the next message continues it,
        a step back then being a restart of the peer (its map frame is new): a single forged
        or replayed number can neither lock a peer out nor force a restart. A peer numbers its
        dense answers to every requester (at most AgentConfig.dense_answers_per_s, 100 at
        most), and only those to this agent arrive here: for them the window grows by itself
        for every second since the last one (a quiet link in a busy fleet is not locked out).
    max_peers / peer_timeout_s: at most this many peers are kept; a peer silent for
        peer_timeout_s is forgotten (expire()). max_peers is checked as a peer arrives:
        lowered live, it refuses new peers, and those already kept go only when silent.
    max_points: bigger dense messages are refused (oversized; graphs with more than
        AgentConfig.max_nodes nodes likewise).
    keep_correspondences: keep the inlier point correspondences of the link's last dense
        estimate and merge them with node-center matches when only coarse data arrives (the
        paper's scheme).
    confirm: publish a link only once two estimates from different data agree (see the
        module docstring); False publishes every estimate that passes the verdict.
    confirm_with_dense: one of the two agreeing estimates must be dense. Two coarse estimates
        from successive graphs share most of their node matches, so they are not independent,
        and node centers are the least accurate evidence (on the training rooms of the real
        suite, verified coarse estimates lie twice as far from the truth as dense ones).
    confirm_with_peer: the peer's own estimates of the link count as the other data for a
        confirmation (Peers._witnessed): its confirmed link for any estimate, its dense
        estimates that passed its verdict for a dense one.
    witness_max_age_s: a peer's estimate older than this no longer confirms anything (its age
        counted from when the peer signed it, with a keystore; from its arrival without).
    vouched_min_confidence: the confidence an estimate needs, instead of the verdict's
        min_confidence, when the peer's confirmed link (a witness, as above) agrees with it and
        only its confidence fell short (Peers._vouched). The verdict's confidence is P(right)
        from the estimate's own evidence at the base rate of all estimates; a confirmed link of
        the peer, itself two agreeing estimates on other data, that lands on the same pose is
        independent evidence that multiplies its odds. Without it the peer's side of a link
        the agent confirmed often never verifies: the peer sees fewer objects and its own
        fits stay just under min_confidence (synthetic and training-room bags, docs/VERDICT.md).
    tie_memory_s: after an estimate of a link is refused as ambiguous (a competing pose nearly
        as well supported), the link's own agreeing estimates do not confirm it for this long;
        only the peer's word does (Peers._link_rules). 0: off. Two estimates of the same two
        maps, one dense and one coarse, share the maps' repeated structure: in the 4-agent
        building bag both slid one identical room width together a second after a coarse
        estimate of the pair had been refused for that tie (withdrawn 2 s later, never on /tf).
        10 s removes that frame, but pairs of identical rooms tie every second, so their links
        wait for the peer and keep searching: per-agent traffic rose 1.36x -> 1.84x of the
        two-agent figure (issue 15 allows 1.5x). Off by default; a fleet that would rather wait
        than publish a wrong pairwise frame between identical rooms turns it on.
    first_link_hold_s: a link is first confirmed (by its own estimates or the peer's word) only
        once its candidate, estimates that agree with it, has stood for this long while the
        maps grow; 0: off. Two agents that start in two identical rooms (offices, hotel rooms)
        register them onto each other, and nothing in two one-room maps tells the copies apart:
        the building suite (config/suites/building.yaml) verifies such slides at first contact,
        and they stand until a map grows past the run of identical rooms and contradicts them.
        Holding first links lets that happen before anything is published: 10 s with
        withdraw_on_tie (config/profiles/identical_rooms.yaml) leaves that suite 4 wrong
        verified frames instead of about 150, at 48 % success over registrable frames instead
        of 74 % (README; docs/RESULTS.md, sessions 8, 29 and 36). Off by default: single rooms
        and apartments do not alias so, and the real suite would lose the first seconds of
        every link.
    withdraw_on_tie: a confirmed link is withdrawn (counter withdrawn_by_tie, logged) when an
        estimate from new data (dense or coarse, not merged) is refused as ambiguous: the maps
        have grown to show a second pose nearly as well supported, so the link may be a slide
        between identical rooms. Nothing is published for the peer until a link is confirmed
        again, and the peer and the merger stop counting on it. With first_link_hold_s 10 it
        cuts the building suite's merged map wrong from 17 s to 3 s; alone it lets links come
        back by the peer's word before the tie is settled (more wrong frames, not fewer), so
        it is off by default and on in the identical-rooms profile (docs/RESULTS.md, session 9).
    coarse_with_dense: when a dense answer arrives while no link is confirmed, the coarse
        estimate of the peer's last coarse graph (in the frame of the answer's points: levelled
        alike, its nodes not moved), now verifiable against those points, is made too (not
        published: the dense answer answers the query). It is the other kind of data (node
        centers against points) that the next coarse graph would bring a second later, so a
        right first dense estimate that it agrees with is confirmed at once instead of published
        as awaiting_confirmation. It confirms the dense estimate or nothing: it changes no link
        state of its own (a tie it finds is remembered, as any tie).
    first_link_min_objects: the inlier objects each of the two agreeing estimates of a first
        confirmation needs (and the estimate the peer's word confirms), above the verdict's own
        minimum for dense estimates (3). Two estimates of two small maps that share three
        objects rest on the same few node matches, so their agreement is not the independent
        evidence a first link needs: through real nodes, a dense estimate on three objects of
        scene0004 and the coarse estimate of the next graph, on four, agreed on a pose
        2.2 m / 6.7 deg off and it was published (docs/VERDICT.md section 3). A candidate on
        fewer objects gives way to an agreeing estimate on enough. A confirmed link is kept by
        estimates on fewer.
    prompt_request: a coarse estimate that passes the verdict asks for the peer's points as soon
        as the peer answers again (AgentConfig.dense_min_interval_s after the last request, the
        fleet's setting assumed), not after the search interval, when only they can take it
        further: it made the link's candidate, which only a dense estimate confirms
        (confirm_with_dense; until one comes every coarse estimate of the link awaits
        confirmation), or there are no points of the peer to verify it on (dropped when a map
        was levelled anew or moved; the dense answer then answers the query, as at first
        contact). One request per such estimate; none to a peer other agents' links place
        (attached_request_interval_s), nor to one that let the last request go unanswered after
        every retry (asked at the interval, as before).
    agree_m / agree_deg: two estimates agree when they differ by less than this.
    quiet_peer_s: a peer whose graph does not change sends coarse graphs only as a heartbeat
        (AgentConfig.heartbeat_period_s); when the own map changes and the peer's last coarse
        graph is older than this, the estimate is made against it instead of waiting.
    kept_max_shift_m: kept correspondences (and the peer's dense cloud) are dropped when the
        nodes they come from moved by more than this (median, in either map) since; without
        kept correspondences, the peer's dense cloud when the nodes of its answer moved so in
        the peer's map.
    pipeline: the one registration pipeline (pipeline.PipelineConfig): dense settings for
        dense answers, coarse settings for coarse and merged estimates, ICP before the verdict.
        The verdict needs, after ICP, at least pose.verdict.min_fitness of the peer's points
        that land on the agent's footprint to lie on its surfaces (pose/verify.py)."""

    min_node_matches: int = param(3, "node matches needed before a dense request", 1, 1000, live=True)
    max_request_nodes: int = param(48, "a dense request asks for the points of at most this many "
                                   "of the peer's nodes (its best matched)", 3, 100_000, live=True)
    min_request_interval_s: float = param(5.0, "at most one dense request per peer per interval once "
                                          "a link to it is confirmed", 0.0, 3600.0, live=True)
    search_request_interval_s: float = param(2.0, "the request interval while no link to the peer "
                                             "is confirmed", 0.0, 3600.0, live=True)
    attached_request_interval_s: float = param(30.0, "the request interval to a peer the merged "
                                               "frame places", 0.0,
                                               3600.0, live=True)
    request_timeout_s: float = param(2.0, "an unanswered dense request is retried after this",
                                     0.1, 600.0, live=True)
    retry_backoff: float = param(2.0, "each retry waits this factor longer", 1.0, 10.0, live=True)
    max_retries: int = param(3, "retries before giving up until the next interval", 0, 100, live=True)
    min_coarse_matches: int = param(4, "node matches needed for a coarse estimate", 3, 1000, live=True)
    sequence_window: int = 1000
    max_peers: int = param(16, "peers kept at most: a new peer over it is refused (lowered live, the "
                           "peers already kept stay until silent for peer_timeout_s)", 1, 1000, live=True)
    peer_timeout_s: float = param(120.0, "a peer silent for this long is forgotten", 10.0, 86400.0,
                                  live=True)
    max_points: int = param(500_000, "dense graphs with more points are refused", 1000, 50_000_000, live=True)
    keep_correspondences: bool = param(True, "merge the last dense correspondences into coarse "
                                       "estimates")
    confirm: bool = param(True, "publish a link only once two estimates from different data agree")
    confirm_with_dense: bool = param(True, "a first confirmation needs a dense estimate among the "
                                     "two that agree")
    confirm_with_peer: bool = param(True, "the peer's own estimates of the link may confirm it")
    witness_max_age_s: float = param(10.0, "a peer's estimate confirms for this long", 0.0,
                                     3600.0, live=True)
    vouched_min_confidence: float = param(0.5, "an estimate that the peer's confirmed link "
                                          "agrees with needs only this confidence", 0.0, 1.0, live=True)
    tie_memory_s: float = param(0.0, "after an ambiguous estimate, the link's own estimates "
                                "do not confirm it for this long (0: off)", 0.0, 3600.0, live=True)
    withdraw_on_tie: bool = param(False, "a confirmed link is withdrawn when an estimate from new "
                                  "data ties (is refused as ambiguous)")
    first_link_hold_s: float = param(0.0, "a link is first confirmed only once its candidate has "
                                     "held this long (0: off; for floors of identical rooms)",
                                     0.0, 3600.0, live=True)
    first_link_min_objects: int = param(4, "a first confirmation needs both agreeing estimates "
                                        "(or the estimate the peer's word confirms) on this many "
                                        "inlier objects", 1, 1000, live=True)
    prompt_request: bool = param(True, "a coarse estimate that passes the verdict asks for the peer's "
                                 "points as soon as the peer answers again when it made the link's "
                                 "candidate or there are none to verify it on", live=True)
    coarse_with_dense: bool = param(True, "with a dense answer while no link is confirmed, make "
                                    "the coarse estimate of the same graphs too, as the second "
                                    "estimate a confirmation needs")
    agree_m: float = param(0.3, "two estimates agree within this translation (m)", 0.01, 5.0)
    agree_deg: float = param(3.0, "two estimates agree within this rotation (deg)", 0.1, 90.0)
    kept_max_shift_m: float = 0.5
    quiet_peer_s: float = param(2.0, "re-estimate against a peer's last coarse graph when the own map "
                                "changes and the peer sent none for this long", 0.1, 3600.0, live=True)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)


@dataclass
class _PendingRequest:
    sequence: int
    coarse_sequence: int
    node_ids: np.ndarray
    sent_at: float
    data: tuple[str, str]       # (own, peer) graph digests the request was made for
    retries: int = 0
    earlier: tuple[int, ...] = ()   # the sequences it was sent under before its retries


@dataclass
class Hypothesis:
    """An estimate that passed the verdict. T: T_agent^peer; data: what it was made from (own
    graph digest, peer graph digest, "dense" or "coarse"); objects: the distinct objects among
    its inliers; kept: its inlier correspondences (peer -> own) when dense."""

    T: np.ndarray
    data: tuple[str, str, str]
    mode: str
    objects: int
    kept: Kept | None = None


@dataclass
class PeerLink:
    """What the agent knows about one peer."""

    peer_id: str
    coarse: GraphMessage | None = None
    coarse_at: float = -np.inf   # when the last coarse graph arrived
    coarse_data: tuple[str, str] | None = None   # (own, peer) digests of the last coarse estimate
    exchanged: tuple[str, str] | None = None     # (own, peer) digests of the last answered request
    wanted: tuple | None = None   # ((own, peer) digests, peer node ids): the dense data to ask for
    dense: GraphMessage | None = None
    dense_cloud: np.ndarray | None = None
    kept: Kept | None = None     # peer -> own inliers kept for merged estimates
    pending: _PendingRequest | None = None
    asked: list = field(default_factory=list)    # recent request sequences: dense answers must name one
    heard_at: float = -np.inf                    # when its last accepted message arrived
    held: dict = field(default_factory=dict)     # stream -> a sequence outside the window, held
    went_back: dict = field(default_factory=dict)   # stream -> whether the held one starts anew
    last_stamp: dict = field(default_factory=dict)  # stream -> map stamp of the last one taken
    last_request_at: float = -np.inf
    gave_up: bool = False        # its last request went unanswered after every retry
    prompt: bool = False         # a coarse estimate waits for the peer's points (prompt_request)
    last_seq: dict = field(default_factory=dict)   # stream -> last sequence seen
    last_seq_at: dict = field(default_factory=dict)   # stream -> when it was taken
    candidate: Hypothesis | None = None
    candidate_at: float = -np.inf   # when the candidate was first estimated
    confirmed: Hypothesis | None = None
    tie_at: float = -np.inf      # when an estimate of the link was last refused as ambiguous
    by_peer: bool = False        # the confirmed link rests on the peer's word (confirmed_by_peer)

    @property
    def state(self) -> str:
        return "confirmed" if self.confirmed else "candidate" if self.candidate else "none"


def check_request_size(cfg: PeersConfig, agent: AgentConfig) -> None:
    """ValueError when no dense request could ever go out, or be answered: a request names at
    most max_request_nodes nodes, an answer on fewer than min_nodes would be refused, and one on
    more than max_answer_nodes is refused by an agent run with these settings."""
    if cfg.max_request_nodes < agent.min_nodes:
        raise ValueError(f"peers: max_request_nodes ({cfg.max_request_nodes}) must not be below "
                         f"min_nodes ({agent.min_nodes}): no dense request would ever be sent")
    if cfg.max_request_nodes > agent.max_answer_nodes:
        raise ValueError(f"peers: max_request_nodes ({cfg.max_request_nodes}) must not exceed "
                         f"max_answer_nodes ({agent.max_answer_nodes}): peers run as this agent "
                         "would refuse every full request")


class Peers:
    """All peers of one agent: feed take_own_map / on_coarse / on_dense / on_tick; read links
    and counters."""

    def __init__(self, cfg: PeersConfig, agent: AgentCore, model: SGRegModel,
                 log: Callable[[str], None] = print,
                 on_restart: Callable[[str], None] = lambda peer: None):
        check_request_size(cfg, agent.cfg)
        self.cfg = cfg
        self.agent = agent
        self.model = model
        self.log = log
        # told a peer's id as soon as its restart is seen, before anything of its new stream is
        # estimated: every link to its old map goes (the node's merger forgets them)
        self.on_restart = on_restart
        self.links: dict[str, PeerLink] = {}       # peer id -> what the agent knows of it
        self.attached: set[str] = set()   # peers placed in the merged frame, links undisputed
        self.disputed: set[str] = set()   # peers whose link with this agent the cycles reject
        self.placed: set[str] = set()     # peers other agents' links place (Merger.placed_by_others)
        # T_agent^peer where other agents' links place the peer in the merged frame, or None;
        # an estimate farther from it than the merger's cycle tolerance is disputed_by_cycles
        self.expected: Callable[[str], np.ndarray | None] = lambda peer: None
        self.merged_tolerance: tuple[float, float] = (MergeConfig.cycle_m, MergeConfig.cycle_deg)
        self.counters: Counter = agent.counters     # one table per node: the agent's
        self._request_seq = 0
        self._witnesses: dict[str, dict] = {}   # peer -> {kind: (T_agent^peer, when heard)}
        self._said: set = set()
        self._dense_cfg = replace(cfg.pipeline, mode="dense")
        self._coarse_cfg = replace(cfg.pipeline, mode="coarse")

    def follow(self, merger) -> None:
        """Take what the agent's merger (runtime/merge.Merger) last decided: which peers are
        settled or placed by others (fewer dense requests), whose links the cycles dispute
        (withheld), and where the merged frame places each peer, within its cycle tolerance
        (MergeConfig.cycle_m / cycle_deg)."""
        self.attached = merger.settled_peers()
        self.disputed = merger.disputed_peers()
        self.placed = merger.placed_by_others()
        self.expected = merger.expected
        self.merged_tolerance = (merger.cfg.cycle_m, merger.cfg.cycle_deg)

    # ---- inputs --------------------------------------------------------------------------
    def take_own_map(self, imap, map_sequence: int, stamp_ns: int) -> str | None:
        """The agent's own new instance map (AgentCore.take_map), and its reference cloud
        (voxels, KD-tree, normals, footprint) built now, once per map update, so that no
        estimate waits for it. None when taken, agent.NotYet when too small to use yet, else
        the one-line reason it was refused."""
        why = self.agent.take_map(imap, map_sequence, stamp_ns)
        if why is None:
            self.agent.reference_cloud(self.cfg.pipeline.pose)
        return why

    def on_coarse(self, msg: GraphMessage, now: float) -> tuple[Estimate | None, DenseRequestMessage | None]:
        if msg.agent_id == self.agent.cfg.name:
            return None, None
        link = self._accept(msg, "coarse", now)
        if link is None:
            return None, None
        link.coarse, link.coarse_at = msg, now
        if not self.agent.ready:
            self._count("own_map_not_ready")
            return None, None
        return self._estimate_coarse(link, now)

    def on_peer_result(self, peer: str, T_peer_agent: np.ndarray, verified: bool, mode: str,
                       reason: str, link_state: str, now: float, age_s: float = 0.0) -> bool:
        """A peer's own estimate of its link to this agent (its RegistrationResult naming this
        agent), kept as a witness (see _witnessed) when the peer published it as verified, or
        when it is a dense estimate that passed the peer's verdict. It may be heard before the
        peer's first graph. A candidate it confirms is confirmed at once. A result that says
        the peer's link is no longer confirmed, or that its cycles dispute it, takes its
        confirmed link back as a witness; a contradicted one takes back every witness, and the
        confirmation of a link that rested on them, and a dense result that did not pass takes
        back the peer's passing dense one. age_s: how long before now the peer said it (a
        signed result's signing time): the witness ages from then, not from its arrival. True
        when that withdrew the link to the peer: the caller takes it out of its merge (no
        estimate says so before the next one)."""
        if peer == self.agent.cfg.name:
            return False
        withdrawn = False
        if reason == "contradicted":
            self._take_back(peer, "confirmed", "dense")
            link = self.links.get(peer)
            if link is not None and link.confirmed is not None and link.by_peer:
                # the word it was confirmed by is taken back: it stands on this agent's own
                # estimates again, a candidate until a second one from other data agrees (not
                # one on kept correspondences, which confirm nothing)
                was = link.confirmed
                self._withdraw(link, "withdrawn_with_peer", f"{peer} withdrew its link, whose word "
                               "confirmed this one", None if was.mode == "merged" else replace(was, kept=None),
                               now)
                withdrawn = True
        elif link_state != "confirmed" or reason == "disputed_by_cycles":
            self._take_back(peer, "confirmed")
        passed = verified or (mode == "dense" and reason in ("ok", "awaiting_confirmation"))
        if mode == "dense" and not passed:    # its newer points no longer bear the older estimate out
            self._take_back(peer, "dense")
        if not passed:
            return withdrawn
        if not is_rigid(T_peer_agent):   # the ROS layer decodes rigid ones only
            self.agent.refuse("bad_result", "")
            self._say_once(("bad_result", peer), f"result of {peer!r} with a transform that is not "
                           "rigid; no witness")
            return withdrawn
        T = np.asarray(T_peer_agent, np.float64)
        if peer not in self._witnesses and len(self._witnesses) >= self.cfg.max_peers:
            del self._witnesses[min(self._witnesses, key=lambda p: max(t for _, t in self._witnesses[p].values()))]
        kind = "confirmed" if verified else "dense"
        self._witnesses.setdefault(peer, {})[kind] = (invert_transform(T), now - max(float(age_s), 0.0))
        link = self.links.get(peer)
        if self.cfg.confirm and link is not None and link.confirmed is None and link.candidate is not None \
                and self._witnessed(link.candidate, peer, now) and self._held_long(link, now):
            self._confirm(link, link.candidate, "confirmed_by_peer")
        return withdrawn

    def _witnessed(self, hyp: Hypothesis, peer: str, now: float) -> bool:
        """Whether the peer's own estimates confirm hyp (confirm_with_peer): they register this
        agent's points against the peer's whole map, so they share no correspondence with this
        agent's. Either the peer's confirmed link (a transform it published as verified) agrees
        with hyp, or hyp is dense and so is a peer estimate that passed its verdict and agrees:
        two dense estimates from the two sides. A coarse estimate needs the peer's confirmation:
        two agents that each saw one of two identical rooms make the same wrong slide, and in
        the 4-agent building bag a coarse estimate and the peer's unconfirmed dense one agreed on
        one. Never an estimate on too few objects for a first link (_enough)."""
        return self._enough(hyp) and self._witness_agrees(
            peer, hyp.T, now, ("confirmed", "dense") if hyp.mode == "dense" else ("confirmed",))

    def _enough(self, hyp: Hypothesis) -> bool:
        """Whether hyp rests on enough inlier objects to take part in a first confirmation
        (first_link_min_objects)."""
        return hyp.objects >= self.cfg.first_link_min_objects

    def _vouched(self, peer: str, reg: Registration, T: np.ndarray, now: float) -> bool:
        """Whether an estimate that the verdict refused only for its confidence is taken all
        the same: the peer's confirmed link agrees with it (vouched_min_confidence)."""
        return reg.reason == "low_confidence" and reg.confidence >= self.cfg.vouched_min_confidence \
            and self._witness_agrees(peer, T, now, ("confirmed",))

    def _witness_agrees(self, peer: str, T: np.ndarray, now: float, kinds: tuple[str, ...]) -> bool:
        """Whether a witness of the peer of one of `kinds` ("confirmed", "dense"), no older than
        witness_max_age_s, agrees with T (always False without confirm_with_peer)."""
        if not self.cfg.confirm_with_peer:
            return False
        return any(kind in kinds and now - at <= self.cfg.witness_max_age_s and self._agree(T, W)
                   for kind, (W, at) in self._witnesses.get(peer, {}).items())

    def on_own_map(self, now: float) -> list[tuple[Estimate, DenseRequestMessage | None]]:
        """After the own map changed: estimates against the last coarse graph of every quiet
        peer (one that sent none for quiet_peer_s; the others' next graph is due anyway)."""
        out = []
        for link in self.links.values():
            if (link.coarse is not None and self.agent.ready and now - link.coarse_at >= self.cfg.quiet_peer_s
                    and link.coarse_data != (self.agent.digest, link.coarse.digest)):
                out.append(self._estimate_coarse(link, now))
        return out

    def _estimate_coarse(self, link: PeerLink, now: float) -> tuple[Estimate, DenseRequestMessage | None]:
        msg = link.coarse
        timings: dict = {}
        t0 = time.perf_counter()
        moved = self._recheck_kept(link, msg)
        kept = link.kept
        reg = register_features(self.model, msg.nodes, self.agent.features,
                                link.dense_cloud, self._own_reference(link.dense_cloud),
                                self._coarse_cfg, timings, kept=None if kept is None else kept.corr,
                                kept_pose=None if kept is None else kept.pose)
        link.coarse_data = (self.agent.digest, msg.digest)
        passes = reg.success and reg.node_matches >= max(self.cfg.min_coarse_matches,
                                                         self.cfg.min_node_matches)
        if passes and link.dense_cloud is None:
            link.prompt = True    # nothing to check it on: only the peer's points can
        request = self._maybe_request(link, reg, now)
        # after the request: a link still confirmed asks for the new points at once
        withdrawn = self._map_moved(link, moved, now)
        if link.dense_cloud is None and request is not None and not withdrawn:
            # Nothing to verify this estimate against: the dense answer to the request answers
            # this query (the paper's coarse-to-fine step), instead of a result bound to fail.
            # A link just withdrawn says so now: the mergers stop placing the peer at once.
            self._count("deferred_to_dense")
            return None, request
        est = self._judge(link, reg, msg.digest, timings, t0, now, withdrawn=withdrawn)
        if self.cfg.prompt_request and link.prompt and request is None:
            request = self._send_wanted(link, now)    # the estimate made a coarse candidate
        return est, request

    def answers_me(self, requester: str) -> bool:
        """Whether a dense graph answering `requester` is for this agent; a peer's answer to
        another agent reaches every agent that listens to the peer, and is counted, not refused
        (the node asks before it decodes the points or checks the signature)."""
        if requester and requester != self.agent.cfg.name:
            self._count("dense_for_others")
            return False
        return True

    def on_dense(self, msg: GraphMessage, now: float) -> Estimate | None:
        if msg.agent_id == self.agent.cfg.name or not self.answers_me(msg.requester):
            return None
        if msg.agent_id not in self.links or msg.request_sequence not in self.links[msg.agent_id].asked:
            self.agent.refuse("unrequested_dense", "")
            self._say_once(("unrequested_dense", msg.agent_id), f"dense graph from {msg.agent_id!r} "
                           f"answers no request of ours (requester {msg.requester!r}, request "
                           f"{msg.request_sequence}); refused")
            return None
        link = self._accept(msg, "dense", now)
        if link is None:
            return None
        if self._answers_pending(link, msg):
            self._close_request(link)
        if not self.agent.ready:
            self._count("own_map_not_ready")
            return None
        timings: dict = {}
        t0 = time.perf_counter()
        peer = self._dense_features(msg, timings)
        link.dense, link.dense_cloud, link.prompt = msg, msg.points, False
        self._drop_kept_of_old_levelling(link, msg.level)   # whether or not this answer replaces them
        link.coarse_data = None     # a coarse estimate on the same graphs is now verifiable
        beside = self._coarse_beside(link, msg, timings, now)
        reg = register_features(self.model, peer, self.agent.features, msg.points,
                                self._own_reference(msg.points), self._dense_cfg, timings)
        # the evidence is the requested nodes' content: two answers with the same content are
        # the same data, whatever the peer's map sequence says or holds elsewhere
        return self._judge(link, reg, msg.digest, timings, t0, now, dense=msg, beside=beside)

    def _answered_with_too_few(self, msg: GraphMessage) -> None:
        """An answer to the pending request that holds too few nodes still answers it: the
        peer no longer has the nodes asked for (its front end renumbered them), and asking
        again for them would get the same answer, so the next request waits for new graphs.
        (Other refused answers are asked for again: a damaged message says nothing of the
        graphs.)"""
        link = self.links.get(msg.agent_id)
        if link is not None and self._answers_pending(link, msg):
            self._close_request(link)
            self._count("answer_too_few_nodes")

    def _answers_pending(self, link: PeerLink, msg: GraphMessage) -> bool:
        p = link.pending
        return p is not None and msg.requester == self.agent.cfg.name \
            and msg.request_sequence in (p.sequence, *p.earlier)

    @staticmethod
    def _close_request(link: PeerLink) -> None:
        """The pending request is answered: its two graphs count as exchanged."""
        link.exchanged = link.pending.data
        link.pending, link.gave_up = None, False

    def _coarse_beside(self, link: PeerLink, dense: GraphMessage, timings: dict,
                       now: float) -> Hypothesis | None:
        """coarse_with_dense: while no link is confirmed, the coarse estimate of the peer's last
        coarse graph against the own map, verified on the points that just arrived. Returned
        when it passes the verdict, as the second estimate the dense one may be confirmed by
        (Peers._link_rules); it changes no link state itself, but a tie it finds is a tie.
        None when off, when the link is confirmed, or when the coarse graph is not the frame of
        the points (levelled otherwise, or its nodes moved since, as for kept correspondences)."""
        msg = link.coarse
        if not (self.cfg.coarse_with_dense and self.cfg.confirm and link.confirmed is None
                and msg is not None and levelled_alike(msg.level, dense.level)):
            return None
        if moved_between(msg, dense, self.cfg.kept_max_shift_m):
            return None
        t0 = time.perf_counter()
        reg = register_features(self.model, msg.nodes, self.agent.features, link.dense_cloud,
                                self._own_reference(link.dense_cloud), self._coarse_cfg, {})
        timings["coarse_with_dense"] = 1e3 * (time.perf_counter() - t0)
        self._count("coarse_with_dense")
        if reg.reason == "ambiguous":
            link.tie_at = now
        if not reg.success or reg.node_matches < self.cfg.min_coarse_matches:
            return None
        return Hypothesis(self._own_to_peer(reg, msg), (self.agent.digest, msg.digest, "coarse"), "coarse",
                          reg.evidence.objects)

    def on_tick(self, now: float) -> list[DenseRequestMessage]:
        """Requests the interval held back, retries of unanswered ones (with back-off), and
        giving up on silent peers."""
        out = []
        for link in self.links.values():
            p = link.pending
            if p is None:
                request = self._send_wanted(link, now)    # a wish the interval held back
                if request is not None:
                    out.append(request)
                continue
            deadline = p.sent_at + self.cfg.request_timeout_s * self.cfg.retry_backoff ** p.retries
            if now < deadline:
                continue
            if p.retries >= self.cfg.max_retries:
                self._count("request_gave_up")
                self.log(f"peer {link.peer_id} did not answer dense request {p.sequence} after "
                         f"{p.retries} retries; giving up until the next request interval")
                link.pending, link.gave_up = None, True
                link.last_request_at = now
                continue
            self._count("request_retry")
            self._request_seq += 1
            p.earlier, p.sequence = p.earlier + (p.sequence,), self._request_seq
            p.retries, p.sent_at = p.retries + 1, now
            out.append(self._request_message(link, p))
        return out

    def expire(self, now: float) -> list[str]:
        """Forget peers silent for peer_timeout_s; returns their ids (the node drops their topics)."""
        gone = [p for p, link in self.links.items() if now - link.heard_at > self.cfg.peer_timeout_s]
        for peer in gone:
            del self.links[peer]
            self._witnesses.pop(peer, None)
            self._count("peer_expired")
            self.log(f"peer {peer} silent for {self.cfg.peer_timeout_s:g} s: forgotten")
        return gone

    # ---- validation ----------------------------------------------------------------------
    def _accept(self, msg: GraphMessage, stream: str, now: float) -> PeerLink | None:
        """The peer's link if the message is usable; else None, with a counter and a log line."""
        problem = check_message(msg, self.agent, self.model, self.cfg.max_points)
        if problem is not None:
            counter, text = problem
            self.agent.refuse(counter, text)
            if stream == "dense" and counter == "too_few_nodes":
                self._answered_with_too_few(msg)
            self._say_once((counter, msg.agent_id), f"{stream} graph from {msg.agent_id!r} "
                           f"(seq {msg.sequence}) refused: {text}")
            return None
        link = self.links.get(msg.agent_id)
        if link is None:
            if len(self.links) >= self.cfg.max_peers:
                self.agent.refuse("too_many_peers", "")
                self._say_once(("too_many_peers", msg.agent_id), f"{stream} graph from {msg.agent_id!r} "
                               f"refused: already {len(self.links)} peers (max_peers)")
                return None
            link = self.links[msg.agent_id] = PeerLink(msg.agent_id)
        last = link.last_seq.get(stream)
        window = self.cfg.sequence_window
        if stream == "dense" and last is not None:
            window *= max(1.0, now - link.last_seq_at[stream])
        held = link.held.get(stream)
        continues_held = held is not None and msg.sequence == held + 1
        if last is not None and not 0 < msg.sequence - last <= window and not continues_held:
            # held until the next message continues it
            link.held[stream] = msg.sequence
            # a number gone back, or the last one again on other maps (a true duplicate repeats
            # the stamp): the first of a new stream if the next one continues it
            link.went_back[stream] = msg.sequence < last or (
                msg.sequence == last and msg.stamp_ns != link.last_stamp.get(stream))
            counter = ("duplicate_sequence" if msg.sequence == last else "out_of_order_sequence"
                       if msg.sequence < last else "sequence_jump")
            self.agent.refuse(counter, "")
            self.log(f"{stream} graph from {msg.agent_id} held back: sequence {msg.sequence} "
                     f"after {last} ({counter.replace('_', ' ')})")
            return None
        if continues_held and link.went_back.get(stream):     # a stream that went back and goes on
            self._count("peer_restart")
            self.log(f"peer {msg.agent_id} restarted (sequence {last} -> {held}, {msg.sequence}): "
                     "forgetting its old map")
            link = self.links[msg.agent_id] = PeerLink(msg.agent_id)
            self._witnesses.pop(msg.agent_id, None)
            self.on_restart(msg.agent_id)
        elif stream == "coarse" and last is not None and msg.sequence - last > 1:
            # lost on the way (a full queue, the network); dense answers also go to others
            self.counters["missed_messages"] += msg.sequence - last - 1
        link.held.pop(stream, None)
        link.last_seq[stream], link.last_seq_at[stream] = msg.sequence, now
        link.last_stamp[stream] = msg.stamp_ns
        link.heard_at = now
        return link

    # ---- estimation ----------------------------------------------------------------------
    def _own_reference(self, peer_cloud):
        """The own map's verification cloud, when there is a peer cloud to check against it."""
        return self.agent.reference_cloud(self.cfg.pipeline.pose) if peer_cloud is not None else None

    def _dense_features(self, msg: GraphMessage, timings: dict) -> NodeFeatures:
        """The peer's points per node, padded to the model's K, and their point features Z."""
        t0 = time.perf_counter()
        k = self.model.cfg.shape.points_per_node
        n = msg.num_nodes
        order = np.argsort(msg.point_node, kind="stable")
        node = msg.point_node[order]
        rank = np.arange(node.size) - np.searchsorted(node, node)
        keep = rank < k
        points = np.zeros((n, k, 3), np.float32)
        valid = np.zeros((n, k), bool)
        points[node[keep], rank[keep]] = msg.points[order][keep]
        valid[node[keep], rank[keep]] = True
        nodes = msg.nodes
        z = self.model.point_features(points, valid, nodes.centers, nodes.descriptor)
        timings["shape"] = timings.get("shape", 0.0) + 1e3 * (time.perf_counter() - t0)
        return replace(nodes, points=points, valid=valid, z=z)

    def _recheck_kept(self, link: PeerLink, msg: GraphMessage) -> float:
        """Drop the kept correspondences and the peer's dense cloud when the nodes they come
        from moved in either map since they were kept, or the peer's map was levelled anew (they
        are in its levelled frame of then); only the kept correspondences when the own map was
        (the peer's cloud is in the peer's frame); without kept correspondences, the cloud when
        the nodes of its dense answer moved in the peer's map. Returns how far they moved (0
        when nothing was dropped for it), for _map_moved: a new levelling moves no frame."""
        if link.dense is not None and not levelled_alike(link.dense.level, msg.level) \
                and (link.kept is not None or link.dense_cloud is not None):
            self.log(f"kept correspondences with {link.peer_id} dropped: its map was levelled anew")
            self._drop_dense(link)
            return 0.0
        if link.kept is not None and not levelled_alike(link.kept.own_level, self.agent.level.R):
            self.log(f"kept correspondences with {link.peer_id} dropped: the own map was levelled anew")
            self._drop_kept(link)
        # pairs of the peer's old levelling can come back (a candidate's, confirmed after a
        # dense answer at the new one): they go, the peer's points of now stay
        self._drop_kept_of_old_levelling(link, msg.level)
        if link.kept is None:
            # the peer's points alone: stale once the peer's frame moved under them
            if link.dense_cloud is None or link.dense is None:
                return 0.0
            shift, what = dense_shift(msg, link.dense), f"dense points of {link.peer_id}"
        else:
            own = self.agent.features
            shift = max(median_shift(link.kept.peer_nodes, msg.nodes.node_ids, msg.nodes.centers),
                        median_shift(link.kept.own_nodes, own.node_ids, own.centers))
            what = f"kept correspondences with {link.peer_id}"
        if not shift <= self.cfg.kept_max_shift_m:     # NaN: cannot be told, dropped
            self.log(f"{what} dropped: their nodes moved {shift:.2f} m since the dense exchange")
            self._drop_dense(link)
            return shift
        return 0.0

    def _map_moved(self, link: PeerLink, shift: float, now: float) -> bool:
        """The nodes a confirmed link was verified on moved (a measured median shift, in either
        map): a map's frame moved under them (re-anchored, a loop closed), so the link's T may
        no longer hold. It is withdrawn, and its next result tells the mergers, rather than
        placing a moved map on /tf until new points contradict it. Nodes that are gone
        (shift inf) say nothing of the frame: the link stays, its points dropped. True when
        withdrawn."""
        if link.confirmed is None or not (self.cfg.kept_max_shift_m < shift < np.inf):
            return False
        self._withdraw(link, "withdrawn_map_moved", f"the nodes it was verified on moved {shift:.2f} m "
                       "in a map since the dense exchange", None, now)
        return True

    def _drop_kept_of_old_levelling(self, link: PeerLink, peer_level: np.ndarray) -> None:
        """Forget the kept correspondences when the peer has levelled its map anew since: they
        are in its levelled frame of then."""
        if link.kept is not None and not levelled_alike(link.kept.peer_level, peer_level):
            self._drop_kept(link)

    def _drop_kept(self, link: PeerLink) -> None:
        self._count("kept_dropped")
        link.kept = None

    def _drop_dense(self, link: PeerLink) -> None:
        """Forget the kept correspondences and the peer's points. Without them nothing about
        the link can be verified: new points are asked for as while searching
        (search_request_interval_s), even for the same two graphs, rather than after the
        confirmed link's interval (a map is levelled anew several times while it is small), and
        promptly once a coarse estimate passes the verdict (prompt_request)."""
        self._drop_kept(link)
        link.dense_cloud, link.exchanged = None, None

    def _judge(self, link: PeerLink, reg: Registration, peer_digest: str, timings: dict,
               t0: float, now: float, dense: GraphMessage | None = None,
               beside: Hypothesis | None = None, withdrawn: bool = False) -> Estimate:
        """The estimate as published: the verdict of the pipeline, then the link's rules
        (beside: an unpublished estimate of the same query from other data, _coarse_beside;
        withdrawn: the link's own pairs, re-checked on the maps of now, contradicted it, which
        the result and the counters say whatever the pipeline's verdict)."""
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        self._count(f"estimates_{reg.mode}")
        peer_msg = dense if dense is not None else link.coarse
        T = self._own_to_peer(reg, peer_msg)
        vouched = self._vouched(link.peer_id, reg, T, now)
        if vouched:
            reg.success, reg.reason = True, "ok"
        if reg.mode == "coarse" and reg.node_matches < self.cfg.min_coarse_matches:
            reason = "too_few_matches"
        elif reg.success and link.dense_cloud is None:
            reason = "no_peer_cloud_to_verify"
        else:
            kept = None
            if dense is not None and reg.success and self.cfg.keep_correspondences:
                corr, own = reg.inlier_corr(), self.agent.features
                kept = Kept(corr, centers_of(corr.pairs[:, 0], dense.nodes.node_ids, dense.nodes.centers),
                            centers_of(corr.pairs[:, 1], own.node_ids, own.centers), reg.T_levelled.copy(),
                            self.agent.level.R, np.asarray(dense.level))
            kind = "dense" if reg.mode == "dense" else "coarse"
            hyp = Hypothesis(T, (self.agent.digest, peer_digest, kind), reg.mode, reg.evidence.objects,
                             kept)
            reason = self._link_rules(link, reg, hyp, now, beside, vouched)
        if reason == "ok" and (link.peer_id in self.disputed or self._off_merged_frame(link.peer_id, T)):
            # the other agents' links say otherwise: withheld, and the link kept to be re-judged
            reason = "disputed_by_cycles"
        if withdrawn:
            reason = "contradicted"
        if vouched:
            if reason == "ok":
                self._count("vouched_by_peer")
            else:       # not taken: the estimate is what the verdict said
                reg.success, reg.reason = False, "low_confidence"
        if reason != "ok":
            self._count(reason)
        est = Estimate(peer_id=link.peer_id, T=T, verified=reason == "ok", reason=reason,
                       link=link.state, registration=reg, stamp_ns=max(self.agent.stamp_ns, peer_msg.stamp_ns),
                       peer_coarse_sequence=link.coarse.sequence if link.coarse else 0,
                       peer_dense_sequence=dense.sequence if dense is not None else
                       (link.dense.sequence if link.dense else 0), timing_ms=timings)
        if est.verified:
            self._count("verified")
        return est

    def _own_to_peer(self, reg: Registration, peer_msg: GraphMessage) -> np.ndarray:
        """T_agent^peer of an estimate: estimated between the levelled graphs (peer -> own),
        published between the maps as they are, own -> peer."""
        to_map_frames(reg, Levelling.from_rotation(peer_msg.level), self.agent.level)
        return invert_transform(reg.T)

    def _off_merged_frame(self, peer: str, T: np.ndarray) -> bool:
        """Whether T disagrees with where other agents' links put the peer in the merged frame
        (by the cycle tolerance): a link that the next merge would reject is not published in
        the second before it."""
        expected = self.expected(peer)
        tol_m, tol_deg = self.merged_tolerance
        return expected is not None and not (rte(T, expected) < tol_m and rre(T, expected) < tol_deg)

    def _agree(self, a: np.ndarray, b: np.ndarray) -> bool:
        return rte(a, b) < self.cfg.agree_m and rre(a, b) < self.cfg.agree_deg

    def _link_rules(self, link: PeerLink, reg: Registration, hyp: Hypothesis, now: float,
                    beside: Hypothesis | None = None, vouched: bool = False) -> str:
        """"ok" when the estimate may be published as verified, else why not; updates the link.
        beside: an unpublished estimate of the same query that passed the verdict
        (coarse_with_dense), one more estimate that may confirm hyp; it changes nothing else.
        vouched: hyp fell short only of the verdict's confidence and the peer's confirmed link
        agrees with it (_vouched): it keeps a confirmed link it agrees with, confirms a first
        one where the peer's word does (under first_link_hold_s only a held candidate it agrees
        with), and is otherwise what the verdict said, "low_confidence": no candidate, no second
        estimate, and no passing dense estimate for the peer to take as its own witness (the
        peer's link would vouch for itself). One that contradicts a confirmed link withdraws
        it without becoming the candidate."""
        merged = reg.mode == "merged"
        if not reg.success:
            if reg.reason == "ambiguous":
                link.tie_at = now
                if link.confirmed is not None and not merged and self.cfg.withdraw_on_tie:
                    self._withdraw(link, "withdrawn_by_tie", f"a {reg.mode} estimate from new data "
                                   "finds a competing pose nearly as well supported (ambiguity "
                                   f"{reg.evidence.ambiguity:.2f})", None, now)
            if merged:   # the kept correspondences no longer hold on the current maps
                link.kept = None
                self._count("kept_dropped")
            return reg.reason
        if not self.cfg.confirm:
            link.confirmed = hyp
            self._keep(link, hyp)
            return "ok"
        if link.confirmed is not None:
            if self._agree(hyp.T, link.confirmed.T):
                link.confirmed = replace(hyp, kept=None)
                self._keep(link, hyp)
                return "ok"
            if merged:
                link.kept = None
                return "disagrees_with_link"
            d = rte(hyp.T, link.confirmed.T), rre(hyp.T, link.confirmed.T)
            self._withdraw(link, "withdrawn", f"a {reg.mode} estimate from new data ({reg.inliers} "
                           f"inliers on {reg.evidence.objects} objects) lies {d[0]:.2f} m / "
                           f"{d[1]:.1f} deg from it", None if vouched else hyp, now)
            return "contradicted"
        if merged:      # kept correspondences without a confirmed link: nothing new
            return "awaiting_confirmation"
        if vouched:
            held = self.cfg.first_link_hold_s <= 0 or (
                link.candidate is not None and self._agree(hyp.T, link.candidate.T) and self._held_long(link, now))
            if held and self._witnessed(hyp, link.peer_id, now):
                self._confirm(link, hyp, "confirmed_by_peer")
                return "ok"
            return "low_confidence"
        cand = link.candidate
        if cand is None or not self._agree(hyp.T, cand.T):
            link.candidate, link.candidate_at = hyp, now
            cand = None
            self._await_dense(link)
        if self._witnessed(hyp, link.peer_id, now) and self._held_long(link, now):
            self._confirm(link, hyp, "confirmed_by_peer")
            return "ok"
        # the estimates from other data that agree with hyp: the link's candidate (still set
        # only when hyp agrees with it) and the unpublished one beside this query
        # (coarse_with_dense), each on enough objects, as hyp
        seconds = [o for o in (cand, beside) if o is not None and self._agree(hyp.T, o.T)
                   and self._independent(o, hyp) and self._enough(o) and self._enough(hyp)]
        if seconds and self._held_long(link, now):
            if not (self.cfg.tie_memory_s > 0 and now - link.tie_at <= self.cfg.tie_memory_s):
                self._confirm(link, hyp, "confirmed", kept_from=hyp if hyp.kept is not None else seconds[0])
                return "ok"
            self._count("held_by_tie")    # a tie was seen: only the peer's word confirms
        if cand is None:
            return "awaiting_confirmation"
        if self._enough(hyp) and not self._enough(cand):
            # an estimate on enough objects stands for a candidate on too few (keeping its dense
            # inliers); a coarse one then waits for a dense estimate, as a new candidate would
            link.candidate = hyp if hyp.kept is not None else replace(hyp, kept=cand.kept)
            self._await_dense(link)
        elif hyp.mode == "dense" and cand.mode != "dense" and (self._enough(hyp) or not self._enough(cand)):
            # the dense estimate stands for the coarse candidate it agrees with (while the hold
            # or a tie keeps it from confirming): the coarse graphs to come are other data for
            # it, not for the candidate they may repeat, and it brings its inliers to keep
            link.candidate = hyp
        elif cand.kept is None:   # no confirmation, but keep dense inliers
            cand.kept = hyp.kept
        return "awaiting_confirmation"

    def _withdraw(self, link: PeerLink, counter: str, why: str, candidate: Hypothesis | None,
                  now: float) -> None:
        """The confirmed link is taken back (logged, counted): its kept correspondences go, and
        candidate (or nothing) is what a new link starts from."""
        self.log(f"link to {link.peer_id} withdrawn: {why}")
        self._count(counter)
        link.confirmed, link.kept, link.candidate, link.candidate_at = None, None, candidate, now
        link.by_peer = False
        # the peer's confirmed link heard before may rest on this agent's word alone (it was
        # confirmed by it): only what the peer says from now on may vouch for the next link
        self._take_back(link.peer_id, "confirmed")
        self._await_dense(link)

    def _take_back(self, peer: str, *kinds: str) -> None:
        """The peer's word of these kinds no longer counts; a peer left with none has no entry
        (the eviction in on_peer_result ranks peers by their latest witness)."""
        held = self._witnesses.get(peer)
        if held is not None:
            for kind in kinds:
                held.pop(kind, None)
            if not held:
                del self._witnesses[peer]

    def _await_dense(self, link: PeerLink) -> None:
        """A new coarse candidate asks for the peer's points promptly (prompt_request): only a
        dense estimate confirms it (confirm_with_dense)."""
        if link.candidate is not None and link.candidate.mode != "dense" and self.cfg.confirm_with_dense:
            link.prompt = True

    def _held_long(self, link: PeerLink, now: float) -> bool:
        """Whether the link's candidate has stood long enough to be confirmed (first_link_hold_s)."""
        return now - link.candidate_at >= self.cfg.first_link_hold_s

    def _independent(self, a: Hypothesis, b: Hypothesis) -> bool:
        """Whether two agreeing estimates may confirm a link: made from different data and,
        with confirm_with_dense, at least one of them from a dense answer."""
        if a.data == b.data:
            return False
        return not self.cfg.confirm_with_dense or "dense" in (a.data[2], b.data[2])

    def _confirm(self, link: PeerLink, hyp: Hypothesis, counter: str,
                 kept_from: Hypothesis | None = None) -> None:
        """The link is confirmed with hyp; its dense inliers (or kept_from's) are kept."""
        link.confirmed, link.candidate, link.prompt = hyp, None, False
        link.by_peer = counter == "confirmed_by_peer"
        self._keep(link, kept_from or hyp)
        self._count(counter)

    def _keep(self, link: PeerLink, hyp: Hypothesis) -> None:
        if hyp.kept is not None and len(hyp.kept.corr):
            link.kept = hyp.kept

    # ---- dense requests ------------------------------------------------------------------
    def _maybe_request(self, link: PeerLink, reg: Registration, now: float) -> DenseRequestMessage | None:
        """Wish for the points of the peer's matched nodes, and ask now if allowed (else on_tick
        asks once the interval has passed)."""
        if reg.node_matches >= self.cfg.min_node_matches:
            # the peer's graph is the source of the estimate; its best matched nodes first
            order = np.argsort(-reg.node_scores, kind="stable")
            ids = reg.node_pairs[order, 0]
            _, first = np.unique(ids, return_index=True)
            best = ids[np.sort(first)][: self.cfg.max_request_nodes]
            if len(best) >= self.agent.cfg.min_nodes:   # an answer on fewer would be refused
                link.wanted = ((self.agent.digest, link.coarse.digest), np.sort(best))
        return self._send_wanted(link, now)

    def _send_wanted(self, link: PeerLink, now: float) -> DenseRequestMessage | None:
        """The request for the link's wish: one at a time, rate-limited, and only for graphs not
        yet exchanged."""
        if link.wanted is None or link.pending is not None:
            return None
        data, wanted = link.wanted
        if data == link.exchanged:      # nothing new to learn from the same two graphs
            return None
        # the points of a confirmed link at hand: new ones would only refine it
        settled = link.confirmed is not None and link.dense_cloud is not None
        interval = self.cfg.min_request_interval_s if settled else self.cfg.search_request_interval_s
        if (settled and link.peer_id in self.attached) \
                or (link.confirmed is None and link.peer_id in self.placed):
            # settled: a placed peer whose points are at hand (dropped when its map moved), or
            # one that other agents' links place through a consistent triangle
            interval = max(interval, self.cfg.attached_request_interval_s)
        elif self.cfg.prompt_request and link.prompt and not link.gave_up:
            # a coarse estimate waits for these points: asked as soon as the peer answers again
            interval = min(interval, self.agent.cfg.dense_min_interval_s)
        if now - link.last_request_at < interval:
            return None
        self._request_seq += 1
        link.pending = _PendingRequest(self._request_seq, link.coarse.sequence, wanted, now, data)
        link.last_request_at, link.prompt = now, False
        self._count("requests")
        return self._request_message(link, link.pending)

    def _request_message(self, link: PeerLink, p: _PendingRequest) -> DenseRequestMessage:
        link.asked = (link.asked + [p.sequence])[-8:]
        return DenseRequestMessage(from_agent=self.agent.cfg.name, to_agent=link.peer_id,
                                   sequence=p.sequence, coarse_sequence=p.coarse_sequence,
                                   weights_id=self.agent.weights_id, node_ids=p.node_ids)

    # ---- bookkeeping ---------------------------------------------------------------------
    def _count(self, name: str) -> None:
        self.counters[name] += 1

    def _say_once(self, key, text: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.log(text)
