"""What a peer's coarse or dense graph must be before any of it reaches a link's state.

The ROS layer decodes messages into arrays of the right types; a message made otherwise (a
direct caller of the core, a fuzzer) is checked here too. Each refusal is a counter name and a
one-line reason (docs/ARCHITECTURE.md, "Failure behaviour").

Public API:
    check_message(msg, agent, model, max_points) -> (counter, reason) or None
"""
from __future__ import annotations

import numpy as np

from ..maps.instance_map import points_problem
from ..maps.level import MAX_TILT_DEG, tilt_deg
from ..geometry import is_rotation
from ..net.model import SGRegModel
from .agent import AgentCore
from .messages import GraphMessage


def _numeric(a, ndim: int | None, kinds: str = "fiu") -> bool:
    """a is a numpy array of ndim dimensions (None: any) whose dtype kind is among kinds (f:
    float, i / u: integers)."""
    return isinstance(a, np.ndarray) and ndim in (None, a.ndim) and a.dtype.kind in kinds


def check_message(msg: GraphMessage, agent: AgentCore, model: SGRegModel,
                  max_points: int) -> tuple[str, str] | None:
    """None when the agent can use msg (a peer's graph, with points when dense), else the
    counter it is refused under and why. Sizes are those a peer of the same weights sends (at
    most agent.cfg.max_nodes nodes, each with at most the model's points per node)."""
    if not msg.agent_id or msg.agent_id == agent.cfg.name:
        return "bad_agent_id", f"agent id {msg.agent_id!r}"
    if msg.weights_id != agent.weights_id:
        return ("rejected_weights", f"features from weights {msg.weights_id!r}, this agent "
                f"runs {agent.weights_id!r}")
    dense = msg.points is not None
    if not (_numeric(msg.nodes.node_ids, 1, "iu") and _numeric(msg.nodes.descriptor, None)
            and _numeric(msg.nodes.centers, 2) and _numeric(msg.extents, 2)
            and (not dense or (_numeric(msg.points, 2) and _numeric(msg.point_node, 1, "iu")))):
        return "malformed_message", "node ids, features, centers, extents or points are not numeric arrays"
    if msg.nodes.node_ids.size and msg.nodes.node_ids.max() > np.iinfo(np.int64).max:
        return "bad_nodes", "a node id is past the largest int64"
    n, max_nodes = msg.num_nodes, agent.cfg.max_nodes
    k = model.cfg.shape.points_per_node    # what a peer of the same weights samples per node
    if n > max_nodes or (dense and msg.points.shape[0] > min(max_points, n * k)):
        return ("oversized_message", f"{n} nodes / {msg.points.shape[0] if dense else 0} points "
                f"over max_nodes={max_nodes}, max_points={max_points} or {k} per node")
    desc, centers = msg.nodes.descriptor, msg.nodes.centers
    if desc.ndim != 2:
        return "bad_feature_size", f"features {desc.shape}, expected ({n}, dim)"
    dim = model.cfg.match.d_match     # what every peer of the same weights sends
    if desc.shape != (n, dim) or centers.shape != (n, 3):
        return "bad_feature_size", f"features {desc.shape}, centers {centers.shape}, expected ({n}, {dim})"
    if msg.extents.shape != (n, 3) or np.unique(msg.nodes.node_ids).size != n:
        return "bad_nodes", "extents do not match the nodes, or a node id repeats"
    if not is_rotation(msg.level) or tilt_deg(msg.level) > MAX_TILT_DEG:
        return "bad_level", f"the levelling is not a rotation that tilts by {MAX_TILT_DEG:g} deg at most"
    arrays = [desc, centers, msg.extents] + ([msg.points] if dense else [])
    if not all(np.isfinite(a).all() for a in arrays):
        return "invalid_values", "NaN or inf in features, centers, extents or points"
    if n < agent.cfg.min_nodes:
        return "too_few_nodes", f"{n} nodes (min_nodes={agent.cfg.min_nodes})"
    if dense:
        if msg.points.shape[1] != 3 or msg.point_node.shape[0] != msg.points.shape[0] \
                or (msg.point_node.size and (msg.point_node.min() < 0 or msg.point_node.max() >= n)):
            return "bad_points", "points name nodes that are not in the message"
        if msg.point_node.size and np.bincount(msg.point_node, minlength=n).max() > k:
            return "bad_points", f"a node has more than the {k} points a peer samples per node"
    far = points_problem(centers) or (dense and points_problem(msg.points))
    if far:   # as for the own map: grids and trees over it must fit
        return "invalid_values", f"centers or points: {far}"
    return None
