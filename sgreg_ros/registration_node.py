"""The `registration` node: one per robot, in the robot's namespace (e.g. /a).

Builds its own graph from mapping/instances, listens to the coarse and dense graphs of its peers
(the `peers` parameter, or every /<x>/sgreg/coarse it discovers), asks them for dense data, and
publishes every estimate T_<agent>^<peer> on sgreg/registration and the verified ones on
sgreg/transform, stamped with the time of the newer of the two maps.

It is also the agent's merger: it hears every agent's sgreg/registration, keeps the links that
the cycles agree on, and publishes every attached agent's map in one merged frame on /tf
(`<merged_frame>` -> `<id>/map`; every agent given the same links publishes the same tree), and
stops asking peers that are already placed for dense data (runtime/merge.py).

All decisions live in sgreg_core.runtime.peers.Peers and runtime.merge.Merger; the parameters
are declared from the configs (PeersConfig, AgentConfig, GraphConfig, the verdict's min_fitness
and min_confidence, the verification's footprint_probe, MergeConfig, HealthConfig and
RegistrationNodeConfig below)."""
from __future__ import annotations

import re
from dataclasses import dataclass, replace

from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult
from tf2_msgs.msg import TFMessage

from sgreg_core.config import param
from sgreg_core.maps.scene_graph import GraphConfig
from sgreg_core.pose.estimator import PoseConfig
from sgreg_core.pose.verdict import VerdictConfig
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.auth import AGENT_ID, AuthConfig, is_agent_id
from sgreg_core.runtime.health import HealthConfig
from sgreg_core.runtime.merge import MergeConfig, Merger
from sgreg_core.runtime.peers import Peers, PeersConfig, check_request_size
from sgreg_core.runtime import views

from . import convert, markers, qos
from .node_base import SgregNode
from .params import ParameterError, frame_ok, parameter_errors, params_of, pick


@dataclass
class RegistrationNodeConfig:
    """What only the registration node decides: who it is, which model, whom it listens to."""

    agent_name: str = param("", "agent id and topic prefix (/<id>/sgreg/...); empty: the node's namespace")
    weights_path: str = param("", "model weights (.safetensors with its .json); empty: the shipped model")
    peers: list = param(help="peer agent ids; [''] or []: every agent whose /<id>/sgreg/coarse appears",
                        factory=lambda: [""])
    discovery_period_s: float = param(2.0, "how often to look for new peers (none with a fixed peers list)",
                                      0.1, 60.0, live=True)
    max_message_mb: float = param(32.0, "bigger peer messages are refused before they are decoded",
                                  0.1, 1024.0, live=True)
    merge_period_s: float = param(1.0, "how often the merged frame is recomputed and sent on /tf",
                                  0.1, 60.0)
    view_period_s: float = param(2.0, "how often sgreg/markers (graph, node matches) go out; 0: never",
                                 0.0, 600.0)
    cloud_period_s: float = param(5.0, "how often sgreg/merged_cloud goes out; 0: never", 0.0, 600.0)
    cloud_voxel: float = param(0.15, "voxel of the merged cloud (m)", 0.02, 2.0)


# the agent's own map is refused or kept as the agent node does; it answers no requests and
# sends no coarse graphs. dense_min_interval_s stays: it is when the peers' agents answer again,
# which a prompt request waits for (PeersConfig.prompt_request); one value serves the fleet
PARAMS = params_of(RegistrationNodeConfig, PeersConfig, AgentConfig, GraphConfig, VerdictConfig,
                   PoseConfig, MergeConfig, HealthConfig, AuthConfig,
                   skip=("dense_answers_per_s", "heartbeat_period_s", "quiet_after_s"))
COARSE_TOPIC = re.compile(rf"^/({AGENT_ID.pattern})/sgreg/coarse$")


# unsigned, anyone could echo this agent's candidate back as the peer's verified link and skip
# the two-estimate rule: the peer's word counts only when signed
CONFIRM_UNSIGNED = "confirm_with_peer off: a peer's results count as evidence only when signed (no keystore)"


class RegistrationNode(SgregNode):
    def __init__(self):
        super().__init__("registration", PARAMS, "sgreg/registration")
        p = self.p
        self.fixed_peers = self.peer_list(p["peers"])
        self.check_merged_frame(p["merged_frame"])
        model = self.load_model()
        self.peers = None
        self.result_seq = 0
        self.request_pubs: dict[str, object] = {}
        self.peer_entities: dict[str, list] = {}    # peer -> its publisher and subscriptions
        self.discovery_timer = None
        if model is not None:
            with parameter_errors():
                agent_cfg = AgentConfig(name=self.name, **pick(AgentConfig, p), graph=GraphConfig(**pick(GraphConfig, p)))
                pipeline = PeersConfig().pipeline.with_verdict(**pick(VerdictConfig, p))
                peers_cfg = PeersConfig(**pick(PeersConfig, p),
                                        pipeline=pipeline.with_pose(**pick(PoseConfig, p)))
                check_request_size(peers_cfg, agent_cfg)
            self.agent = AgentCore(agent_cfg, model)
            self.agent.warm_up()
            self.merger = Merger(MergeConfig(**pick(MergeConfig, p)), self.name)
            self.peers = Peers(peers_cfg, self.agent, model, log=self.refusal, on_restart=self._forget_peer)
            self.peers.follow(self.merger)
            self.tf_pub = self.create_publisher(TFMessage, "/tf", qos.TF)
            self.transform_pub = self.create_publisher(TransformStamped, self.topic("sgreg/transform"), qos.RESULTS)
            self.result_pub = self.create_publisher(RegistrationResult, self.topic("sgreg/registration"),
                                                    qos.RESULTS)
            self.create_subscription(InstanceMap, self.topic("mapping/instances"), self.on_instances,
                                     qos.INSTANCES, raw=True)
            for peer in self.fixed_peers:
                self.add_peer(peer)
            if not self.fixed_peers:
                self.discovery_timer = self.create_timer(p["discovery_period_s"], self.on_discovery)
            self.create_timer(0.2, lambda: self.guarded("the request timers", self.on_tick))
            self.create_timer(p["merge_period_s"], self.on_merge)
            self.matches: dict[str, object] = {}     # peer -> inlier node pairs of its last verified estimate
            if p["view_period_s"] > 0:
                self.marker_pub = self.create_publisher(MarkerArray, self.topic("sgreg/markers"), qos.VIEW)
                self.create_timer(p["view_period_s"], self.publish_markers)
            if p["cloud_period_s"] > 0:
                self.cloud_pub = self.create_publisher(PointCloud2, self.topic("sgreg/merged_cloud"), qos.VIEW)
                self.create_timer(p["cloud_period_s"], self.publish_cloud)
            self.get_logger().info(f"registration for '{self.name}' up, peers: "
                                   f"{self.fixed_peers or 'discovered'}, weights {self.agent.weights_id}")
        self.accept_live_parameters()

    def in_effect(self, overrides: dict) -> None:
        """Without a keystore the peer's word is off (CONFIRM_UNSIGNED), and the parameter says so."""
        from rclpy.parameter import Parameter

        keystore, confirm = overrides.get("keystore"), overrides.get("confirm_with_peer")
        wanted = PeersConfig.confirm_with_peer if confirm is None else confirm.value is True   # else check() says why
        if not (keystore and keystore.value) and wanted:
            overrides["confirm_with_peer"] = Parameter("confirm_with_peer", Parameter.Type.BOOL, False)
            self.get_logger().warning(CONFIRM_UNSIGNED)

    def peer_list(self, peers: list) -> list[str]:
        """The fixed peers ([] or [''] to discover them), or ParameterError: each must be an
        agent id, and not this agent's own (a list of only that would hear nobody)."""
        fixed = [x for x in peers if x]
        bad = [x for x in fixed if not is_agent_id(x)]
        if bad:
            raise ParameterError(f"peers {bad} are not agent ids (a letter, then letters, digits "
                                 "and single underscores)")
        if self.name in fixed:
            raise ParameterError(f"peers lists this agent's own name {self.name!r}")
        return fixed

    def check_merged_frame(self, frame: str) -> None:
        """The shared frame must be a valid tf frame id and no agent's own map frame (a frame
        that is its own parent breaks every tf tree that holds it)."""
        if not frame_ok(frame) or frame.endswith("/map"):
            raise ParameterError(f"merged_frame {frame!r} must be a tf frame id (tokens of letters, "
                                 "digits and underscores joined by '/') and not an agent's <id>/map")

    def apply(self, changes: dict) -> None:
        if self.peers is None:
            return
        # the new configs first: values that do not fit the others change nothing (ValueError)
        peers_cfg = replace(self.peers.cfg, **pick(PeersConfig, changes))
        agent_cfg = replace(self.agent.cfg, **pick(AgentConfig, changes))
        check_request_size(peers_cfg, agent_cfg)
        if "discovery_period_s" in changes and self.discovery_timer is not None:
            self.destroy_timer(self.discovery_timer)
            self.discovery_timer = self.create_timer(changes["discovery_period_s"], self.on_discovery)
        self.peers.cfg, self.agent.cfg = peers_cfg, agent_cfg

    # ---- peers ---------------------------------------------------------------------------
    def on_discovery(self) -> None:
        self.guarded("peer discovery", self.discover_peers)

    def discover_peers(self) -> None:
        """Listen to every agent whose coarse topic appears: with a keystore only the fleet's
        agents, and never more than max_peers (a flood of fake topics costs nothing)."""
        fleet = set(self.auth.keystore.owners.values()) if self.auth.keystore else None
        for topic, _ in self.get_topic_names_and_types():
            m = COARSE_TOPIC.match(topic)
            peer = m.group(1) if m else None
            if peer is None or peer == self.name or peer in self.request_pubs or (fleet is not None and peer not in fleet):
                continue
            if len(self.request_pubs) >= self.peers.cfg.max_peers:
                self.refusal(f"not listening to '{peer}': already {len(self.request_pubs)} peers (max_peers)",
                             key="max_peers")
                continue
            self.add_peer(peer)

    def add_peer(self, peer: str) -> None:
        if peer == self.name or peer in self.request_pubs:
            return
        self.request_pubs[peer] = self.create_publisher(DenseRequest, f"/{peer}/sgreg/dense_request",
                                                        qos.DENSE_REQUEST)
        self.peer_entities[peer] = [
            self.create_subscription(CoarseGraph, f"/{peer}/sgreg/coarse", lambda raw: self.on_coarse(raw, peer),
                                     qos.COARSE_SUB, raw=True),
            self.create_subscription(DenseGraph, f"/{peer}/sgreg/dense", lambda raw: self.on_dense(raw, peer),
                                     qos.DENSE, raw=True),
            self.create_subscription(RegistrationResult, f"/{peer}/sgreg/registration",
                                     lambda raw: self.on_result(raw, peer), qos.RESULTS, raw=True)]
        self.get_logger().info(f"listening to peer '{peer}'")

    def drop_peer(self, peer: str) -> None:
        """Stop listening to a discovered peer that went silent (discovery may add it again)."""
        if peer in self.fixed_peers or peer not in self.request_pubs:
            return
        self.destroy_publisher(self.request_pubs.pop(peer))
        for sub in self.peer_entities.pop(peer, []):
            self.destroy_subscription(sub)

    # ---- callbacks -----------------------------------------------------------------------
    def on_instances(self, raw: bytes) -> None:
        why = convert.take_instance_map(raw, self.peers.take_own_map, self.agent.refuse,
                                        self.agent.cfg.name, self.stamp_clock_ns(),
                                        self.agent.cfg.max_points_in_map)
        self.map_taken(why)
        if why is None:
            self.merger.set_level(self.name, self.agent.level.R)
            self.guarded("the own map's estimates", lambda: self.publish_all(self.peers.on_own_map(self.clock_s())))

    def on_coarse(self, raw: bytes, peer: str) -> None:
        graph = self._decode(convert.coarse_from_msg, raw, CoarseGraph, "coarse", peer)
        if graph is not None:
            self.guarded(f"coarse graph {graph.sequence} of {graph.agent_id}",
                         lambda: self.publish_all([self.peers.on_coarse(graph, self.clock_s())]))
            # after the graph is taken: a restart seen in it forgets the peer's old levelling too
            self.merger.set_level(peer, graph.level)

    def on_dense(self, raw: bytes, peer: str) -> None:
        graph = self._decode(convert.dense_from_msg, raw, DenseGraph, "dense", peer,
                             wanted=lambda msg: self.peers.answers_me(msg.requester))
        if graph is not None:
            self.guarded(f"dense graph {graph.sequence} of {graph.agent_id}",
                         lambda: self.publish(self.peers.on_dense(graph, self.clock_s())))

    def on_result(self, raw: bytes, peer: str) -> None:
        """A peer's registration result: its links, for the merger."""
        result = self._decode(convert.result_from_msg, raw, RegistrationResult, "registration", peer)
        if result is None:
            return
        self.guarded(f"registration result of {result.agent}", lambda: self._take_result(result))

    def _take_result(self, result) -> None:
        if result.peer != self.name and result.peer not in self.request_pubs:
            # a link to an agent this node does not listen to (at most max_peers): results
            # naming made-up agents would grow the merge without bound. Counted, not refused: a
            # fleet larger than max_peers, or fixed peers naming part of it, hears such results
            self.agent.counters["result_names_unknown_agent"] += 1
            self.refusal(f"result of {result.agent} about '{result.peer}', an agent not listened "
                         "to: left out of the merge", key=f"result_names_unknown_agent {result.agent}")
            return
        self.merger.take(result.agent, result.peer, result.T, result.verified, result.reason,
                         result.link, result.confidence, result.stamp_ns)
        if result.peer == self.name:     # the peer's own estimate of our link: a witness
            if self.peers.on_peer_result(result.agent, result.T, result.verified, result.mode,
                                         result.reason, result.link, self.clock_s(),
                                         age_s=self.auth.said_s_ago(result.signed_ns)):
                # our link, confirmed on its word, is withdrawn: out of the merge and the views
                # now (the other agents' mergers drop it with our next result about that peer)
                self.merger.drop(self.name, result.agent)
                self.matches.pop(result.agent, None)

    def on_merge(self) -> None:
        self.guarded("the merge", self._merge)

    def _merge(self) -> None:
        """Merge every agent's links; /tf gets the attached agents' maps in the merged frame."""
        for line in self.merger.update():
            self.get_logger().info(line)
        self.peers.follow(self.merger)
        result = self.merger.result
        self.agent.counters["agents_attached"] = len(result.attached)
        self.agent.counters["links_rejected"] = len(result.rejected)
        if len(result.attached) > 1:
            self.tf_pub.publish(convert.tf_msg(self.merger.raw_poses(), self.merger.cfg.merged_frame,
                                               self.now_ns()))

    def _forget_peer(self, peer: str) -> None:
        """Every link to or from the peer's map goes from the merge and the views at once: it
        went silent (its last links would place it on /tf for good, no new result ageing them),
        or it restarted and its new map lies in another frame (Peers.on_restart)."""
        self.merger.forget(peer)
        self.matches.pop(peer, None)

    def on_tick(self) -> None:
        now = self.clock_s()
        for request in self.peers.on_tick(now):
            self.send_request(request)
        for peer in self.peers.expire(now):
            self._forget_peer(peer)     # fixed peer or not: its next results bring its links back
            self.drop_peer(peer)

    def guarded(self, what: str, work) -> None:
        super().guarded(what, work, self.agent.refuse)

    # ---- helpers -------------------------------------------------------------------------
    def _decode(self, fn, raw: bytes, cls, topic: str, peer: str, wanted=None):
        """What a peer's message on /<peer>/sgreg/<topic> carries (fn of the message), or None
        (refusal counted): oversized, undecodable, sent in another agent's name, or (with a
        keystore) not signed by the peer's key; also None when wanted(message) says the message
        is not for this agent (nothing more of it is converted or checked)."""
        what = {"coarse": "coarse graph", "dense": "dense graph"}.get(topic, "result")
        if len(raw) > self.p["max_message_mb"] * 1e6:   # refused before a copy is decoded
            size, raw = len(raw), None
            self.refusal(self.agent.refuse("oversized_message", f"{what} of {size / 1e6:.1f} MB on "
                                           f"/{peer}'s topic refused (max_message_mb)"))
            return None
        try:
            msg = convert.decode(raw, cls)
            if wanted is not None and msg.agent_id == peer and not wanted(msg):
                return None   # (one that claims another agent is refused below, as ever)
            out = fn(msg)
        except convert.ConversionError as exc:
            self.refusal(self.agent.refuse("malformed_message", f"malformed {what} refused: {exc}"),
                         key=f"malformed {what} {peer}")
            return None
        refused = "agent_mismatch" if msg.agent_id != peer else \
            self.auth.check(msg, f"/{peer}/sgreg/{topic}", peer)
        if refused:
            self.refusal(self.agent.refuse(refused, f"{what} {msg.sequence} on /{peer}'s topic "
                                                    f"(agent_id {msg.agent_id!r}) refused: {refused}"),
                         key=f"{refused} {what} {peer}")
            return None
        return out

    def send_request(self, request) -> None:
        pub = self.request_pubs.get(request.to_agent)
        if pub is not None:
            msg = convert.request_to_msg(request, self.now_ns())
            pub.publish(self.auth.sign(msg, f"/{request.to_agent}/sgreg/dense_request"))

    def publish_all(self, outcomes) -> None:
        for estimate, request in outcomes:
            if request is not None:
                self.send_request(request)
            self.publish(estimate)

    def publish(self, estimate) -> None:
        if estimate is None:
            return
        self.result_seq += 1
        msg = convert.result_to_msg(estimate, self.name, self.result_seq, estimate.stamp_ns,
                                    dict(self.peers.counters))
        self.result_pub.publish(self.auth.sign(msg, self.topic("sgreg/registration")))
        self.merger.take(self.name, estimate.peer_id, estimate.T, estimate.verified, estimate.reason,
                         estimate.link, estimate.confidence, estimate.stamp_ns)
        if estimate.verified:
            self.transform_pub.publish(convert.transform_msg(estimate.T, self.name, estimate.peer_id, estimate.stamp_ns))
            self.matches[estimate.peer_id] = estimate.registration.inlier_node_pairs()[:, ::-1]
        elif estimate.link != "confirmed":      # withdrawn: its matches are no longer shown
            self.matches.pop(estimate.peer_id, None)

    # ---- views ---------------------------------------------------------------------------
    def publish_markers(self) -> None:
        self.guarded("the markers", self._markers)

    def _markers(self) -> None:
        """The own scene graph (in <id>/map) and, in the merged frame, the node matches of every
        verified link whose two ends it places."""
        if not self.agent.ready:
            return
        stamp = self.get_clock().now().to_msg()
        out = markers.graph_markers(views.graph_view(self.agent.graph), f"{self.name}/map", stamp)
        poses, frame = self.merger.raw_poses(), self.merger.cfg.merged_frame
        own = views.centers_in_map(self.agent.graph.node_ids, self.agent.graph.centers, self.agent.level)
        for k, (peer, pairs) in enumerate(sorted(self.matches.items())):
            link = self.peers.links.get(peer)
            if link is None or link.coarse is None or self.name not in poses or peer not in poses:
                continue
            theirs = views.centers_in_map(link.coarse.nodes.node_ids, link.coarse.nodes.centers,
                                          link.coarse.level)
            lines = views.match_lines(own, theirs, pairs, poses[self.name], poses[peer])
            out.append(markers.match_marker(lines, peer, frame, stamp, views.agent_rgb(k) / 255.0))
        self.marker_pub.publish(markers.markers_msg(out))

    def publish_cloud(self) -> None:
        self.guarded("the merged cloud", self._cloud)

    def _cloud(self) -> None:
        """Every map this agent knows of in the merged frame: its own, and the points of each
        placed peer's last dense answer."""
        poses = self.merger.raw_poses()
        if not self.agent.ready or self.name not in poses:
            return
        clouds = {self.name: views.points_in_map(self.agent.own_cloud(), self.agent.level)}
        for peer, link in self.peers.links.items():
            if link.dense is not None and link.dense_cloud is not None and peer in poses:
                clouds[peer] = views.points_in_map(link.dense_cloud, link.dense.level)
        pts, rgb = views.merged_cloud(clouds, poses, self.p["cloud_voxel"])
        self.cloud_pub.publish(markers.cloud_msg(pts, rgb, self.merger.cfg.merged_frame,
                                                 self.get_clock().now().to_msg()))

    # ---- diagnostics ---------------------------------------------------------------------
    def counters(self) -> dict:
        return dict(self.peers.counters) if self.peers else {}

    def refused(self) -> int:
        return self.agent.refused if self.peers else 0

    def summary(self) -> str:
        if self.peers is None:
            return ""
        links = ", ".join(f"{p}: {'registered' if link.confirmed else 'not registered'}"
                          for p, link in self.peers.links.items()) or "no peers yet"
        merged = self.merger.result
        return f"{links}; {len(merged.attached)} agents in {self.merger.cfg.merged_frame}" \
            + (f", {len(merged.rejected)} links rejected" if merged.rejected else "")
