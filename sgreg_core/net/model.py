"""The SG-Reg network: scene graph -> node descriptors and point features -> matches.

    F, H = ShapeEncoder(node points in the node frame)
    x0 = [text || MLP_b(extents)]            NodeEncoder      (early fusion: || F as well)
    x1 = TripletGNN(x0, centers, edges)
    x2 = [x1 || F]                            late fusion (the paper's); "none": x2 = x1
    descriptor = W x2                         what a coarse message carries per node
    Z = PointEncoder(H, F, context of the nearest nodes' centers and descriptors)

Runtime API (numpy in, numpy out; eval mode, no grad):
    model.encode(graph, dense=True) -> NodeFeatures
    model.match_coarse(src, ref) -> NodeMatches
    model.match_dense(src, ref) -> DenseMatches
    model.point_features(points, valid, centers, descriptor) -> Z   (a peer's dense message: its points,
        centers and descriptors; each point's context is the nodes the message carries, so Z
        is close to, not equal to, what the peer's own encode() of its whole graph gives)
Training uses model.prepare(graph, ...) -> GraphInput and model(GraphInput) -> Encoded.

Weights: save_model(model, path) writes path (.safetensors) and path.with_suffix(".json")
(the ModelConfig); load_model(path=None) reads them, by default the shipped
sgreg_core/weights/sgreg.safetensors. weights_id(state_dict) names a set of weights.
"""
from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..types import SceneGraph
from ..config import from_dict, to_dict
from ..paths import weights_files
from .matching import MatchConfig, NodeMatcher, PointMatcher
from .node_encoder import NodeEncoder, NodeEncoderConfig
from .shape import PointEncoder, ShapeConfig, ShapeEncoder, sample_node_points
from .text import TextEncoder, default_text_encoder
from .triplet_gnn import GNNConfig, TripletGNN

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "sgreg.safetensors"
FUSIONS = ("late", "early", "none")


@dataclass
class ModelConfig:
    """fusion: where the shape feature F enters: "late" x2 = [x1 || F] (the paper),
    "early" x0 = [text || box || F] before the GNN, "none" no F at all (ablation).
    Point features Z are computed in every mode (dense matching needs them)."""

    node: NodeEncoderConfig = field(default_factory=NodeEncoderConfig)
    gnn: GNNConfig = field(default_factory=GNNConfig)
    shape: ShapeConfig = field(default_factory=ShapeConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    fusion: str = "late"

    def __post_init__(self):
        if self.fusion not in FUSIONS:
            raise ValueError(f"fusion must be one of {FUSIONS}, got {self.fusion!r}")

    def to_dict(self) -> dict:
        return to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping | None) -> "ModelConfig":
        return from_dict(cls, data)


@dataclass
class GraphInput:
    """A scene graph as tensors. points: (n, K, 3) sampled node points in the graph frame."""

    text: torch.Tensor
    extents: torch.Tensor
    centers: torch.Tensor
    edges: torch.Tensor
    points: torch.Tensor
    valid: torch.Tensor


@dataclass
class Encoded:
    """Network outputs for one graph (tensors, differentiable in training)."""

    x1: torch.Tensor          # (n, d) GNN output
    shape: torch.Tensor       # (n, d_shape) F
    descriptor: torch.Tensor  # (n, d_match)
    z: torch.Tensor           # (n, K, d_z)


@dataclass
class NodeFeatures:
    """What the network makes of a graph. Coarse: descriptors + centers (what a coarse message
    carries); dense adds the sampled points, their validity and point features z."""

    node_ids: np.ndarray               # (n,) int64
    centers: np.ndarray                # (n, 3) float32
    descriptor: np.ndarray             # (n, d_match) node descriptors
    points: np.ndarray | None = None   # (n, K, 3) float32 sampled node points, graph frame
    valid: np.ndarray | None = None    # (n, K) bool, False for padding
    z: np.ndarray | None = None        # (n, K, d_z) point features

    @property
    def num_nodes(self) -> int:
        return int(self.descriptor.shape[0])

    @property
    def is_dense(self) -> bool:
        return self.z is not None


@dataclass
class NodeMatches:
    src_idx: np.ndarray   # (m,) node index in the src features
    ref_idx: np.ndarray   # (m,) node index in the ref features
    score: np.ndarray     # (m,) dual-softmax confidence
    src_xyz: np.ndarray   # (m, 3) node centers: coarse correspondences
    ref_xyz: np.ndarray

    def __len__(self) -> int:
        return int(self.src_idx.shape[0])


@dataclass
class PointMatches:
    src_xyz: np.ndarray     # (c, 3) in the src graph frame
    ref_xyz: np.ndarray     # (c, 3) in the ref graph frame
    score: np.ndarray       # (c,) transport mass
    node_match: np.ndarray  # (c,) index into NodeMatches

    def __len__(self) -> int:
        return int(self.score.shape[0])


@dataclass
class DenseMatches:
    nodes: NodeMatches
    points: PointMatches


@contextmanager
def _timed(timings: dict | None, stage: str):
    start = time.perf_counter()
    yield
    if timings is not None:
        timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - start)


class SGRegModel(nn.Module):
    def __init__(self, cfg: ModelConfig | None = None, text_encoder: TextEncoder | None = None):
        super().__init__()
        self.cfg = cfg = cfg or ModelConfig()
        self._text_encoder = text_encoder
        self.node_encoder = NodeEncoder(cfg.node)
        self.shape = ShapeEncoder(cfg.shape)
        d0 = cfg.node.d_out + (cfg.shape.d_shape if cfg.fusion == "early" else 0)
        self.gnn = TripletGNN(cfg.gnn, d0)
        self.node_matcher = NodeMatcher(d0 + (cfg.shape.d_shape if cfg.fusion == "late" else 0),
                                        cfg.match)
        self.point_encoder = PointEncoder(cfg.shape, cfg.match.d_match)
        self.point_matcher = PointMatcher(cfg.match)

    @property
    def text_encoder(self) -> TextEncoder:
        if self._text_encoder is None:
            self._text_encoder = default_text_encoder()
        return self._text_encoder

    @text_encoder.setter
    def text_encoder(self, encoder: TextEncoder) -> None:
        self._text_encoder = encoder

    @property
    def weights_id(self) -> str:
        return weights_id(self.state_dict())

    # ---- network -------------------------------------------------------------------------
    def prepare(self, graph: SceneGraph, text: np.ndarray | None = None,
                rng: np.random.Generator | None = None,
                timings: dict | None = None) -> GraphInput:
        """Tensors of a graph. text: precomputed label embeddings; rng: point sampling (the
        fixed ShapeConfig.sample_seed when None, so encoding is deterministic)."""
        with _timed(timings, "text"):
            if text is None:
                text = self.text_encoder.encode(graph.labels)
        with _timed(timings, "sample"):
            rng = rng or np.random.default_rng(self.cfg.shape.sample_seed)
            points, valid = sample_node_points(graph.points, self.cfg.shape.points_per_node, rng)
        return GraphInput(
            text=torch.as_tensor(np.asarray(text, dtype=np.float32)),
            extents=torch.as_tensor(np.asarray(graph.extents, dtype=np.float32)).reshape(-1, 3),
            centers=torch.as_tensor(np.asarray(graph.centers, dtype=np.float32)).reshape(-1, 3),
            edges=torch.as_tensor(np.asarray(graph.edges, dtype=np.int64)).reshape(-1, 2),
            points=torch.from_numpy(points),
            valid=torch.from_numpy(valid),
        )

    def forward(self, inp: GraphInput, timings: dict | None = None) -> Encoded:
        with _timed(timings, "shape"):
            local = _local(inp.points, inp.valid, inp.centers)
            shape, hidden = self.shape(local, inp.valid)
        with _timed(timings, "gnn"):
            x0 = self.node_encoder(inp.text, inp.extents)
            if self.cfg.fusion == "early":
                x0 = torch.cat([x0, shape], dim=-1)
            x1 = self.gnn(x0, inp.centers, inp.edges)
            x2 = torch.cat([x1, shape], dim=-1) if self.cfg.fusion == "late" else x1
            descriptor = self.node_matcher.descriptor(x2)
        with _timed(timings, "shape"):
            # detached: the point losses must not pull the node descriptors around
            z = self.point_encoder(local, inp.valid, hidden, shape, inp.centers, descriptor.detach())
        return Encoded(x1=x1, shape=shape, descriptor=descriptor, z=z)

    # ---- runtime -------------------------------------------------------------------------
    @torch.no_grad()
    def encode(self, graph: SceneGraph, dense: bool = True,
               timings: dict | None = None) -> NodeFeatures:
        """Features of a graph for coarse (x, centers) or dense (+ points, z) matching, in the
        graph's node order. The network runs on the nodes in ascending id order (the order
        build_scene_graph lists them in), because its point samples and triplets are drawn row
        by row: a graph that lists the same nodes in another order gets the same features."""
        if self.training:
            raise RuntimeError("encode() needs eval mode (call model.eval())")
        ids = np.asarray(graph.node_ids, dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        canonical = np.array_equal(order, np.arange(len(ids)))
        inp = self.prepare(graph if canonical else graph.reordered(order), timings=timings)
        out = self(inp, timings=timings)
        back = slice(None) if canonical else np.argsort(order)
        feats = NodeFeatures(node_ids=ids, centers=np.asarray(graph.centers, np.float32).reshape(-1, 3),
                             descriptor=out.descriptor.numpy()[back])
        if dense:
            feats.points, feats.valid = inp.points.numpy()[back], inp.valid.numpy()[back]
            feats.z = out.z.numpy()[back]
        return feats

    @torch.no_grad()
    def point_features(self, points: np.ndarray, valid: np.ndarray, centers: np.ndarray,
                       descriptor: np.ndarray) -> np.ndarray:
        """Z of sampled node points (n, K, 3) in the graph frame, from the node centers and
        descriptors (as a dense message carries them) -> (n, K, d_z) float32. The context nodes
        are the given ones only: a dense answer's subset of the peer's graph gives Z that
        differ from the peer's own encode() (matching quality measured the same, session 39)."""
        pts, mask, ctr = _f32(points), torch.as_tensor(np.asarray(valid, bool)), _f32(centers)
        local = _local(pts, mask, ctr)
        shape, hidden = self.shape(local, mask)
        return self.point_encoder(local, mask, hidden, shape, ctr, _f32(descriptor)).numpy()

    @torch.no_grad()
    def match_coarse(self, src: NodeFeatures, ref: NodeFeatures,
                     timings: dict | None = None) -> NodeMatches:
        with _timed(timings, "node_match"):
            i_src, i_ref, conf = self.node_matcher.match(_f32(src.descriptor), _f32(ref.descriptor))
            i_src, i_ref = i_src.numpy(), i_ref.numpy()
            return NodeMatches(src_idx=i_src, ref_idx=i_ref, score=conf.numpy(),
                               src_xyz=np.asarray(src.centers, np.float32)[i_src],
                               ref_xyz=np.asarray(ref.centers, np.float32)[i_ref])

    @torch.no_grad()
    def match_dense(self, src: NodeFeatures, ref: NodeFeatures,
                    timings: dict | None = None) -> DenseMatches:
        if not (src.is_dense and ref.is_dense):
            raise ValueError("match_dense needs dense features (encode(graph, dense=True))")
        nodes = self.match_coarse(src, ref, timings)
        with _timed(timings, "point_match"):
            i_src, i_ref = torch.from_numpy(nodes.src_idx), torch.from_numpy(nodes.ref_idx)
            valid_src = torch.as_tensor(np.asarray(src.valid, bool))[i_src]
            valid_ref = torch.as_tensor(np.asarray(ref.valid, bool))[i_ref]
            pair, p_src, p_ref, mass = self.point_matcher.match(_f32(src.z)[i_src], valid_src,
                                                                _f32(ref.z)[i_ref], valid_ref)
            pair, p_src, p_ref = pair.numpy(), p_src.numpy(), p_ref.numpy()
            points = PointMatches(
                src_xyz=np.asarray(src.points, np.float32)[nodes.src_idx[pair], p_src],
                ref_xyz=np.asarray(ref.points, np.float32)[nodes.ref_idx[pair], p_ref],
                score=mass.numpy(), node_match=pair)
        return DenseMatches(nodes=nodes, points=points)


def _local(points: torch.Tensor, valid: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Node points relative to their node center, zero at padding."""
    return (points - centers.unsqueeze(1)) * valid.unsqueeze(-1)


def _f32(a) -> torch.Tensor:
    """Features may arrive as float16 (messages): compute in float32."""
    return torch.as_tensor(np.asarray(a, dtype=np.float32))


# ---- weights ---------------------------------------------------------------------------
def weights_id(state_dict: Mapping[str, torch.Tensor]) -> str:
    """12 hex chars of sha256 over every tensor's name, dtype, shape and bytes."""
    digest = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        digest.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()[:12]


def save_model(model: SGRegModel, path: str | Path, meta: Mapping | None = None) -> str:
    """Write path (.safetensors) and its .json (config, weights_id, meta); return the id."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    wid = weights_id(state)
    save_file(state, str(path), metadata={"weights_id": wid})
    info = {"weights_id": wid, "config": model.cfg.to_dict(), **(meta or {})}
    path.with_suffix(".json").write_text(json.dumps(info, indent=1) + "\n")
    return wid


def load_model(path: str | Path | None = None, text_encoder: TextEncoder | None = None) -> SGRegModel:
    """Model in eval mode from a .safetensors file and the ModelConfig in its .json."""
    from safetensors.torch import load_file

    path, info_path = weights_files(path or DEFAULT_WEIGHTS)
    try:
        info = json.loads(info_path.read_text())
        model = SGRegModel(ModelConfig.from_dict(info.get("config")), text_encoder=text_encoder)
        state = load_file(str(path))
        model.load_state_dict(state)
    except Exception as exc:   # bad JSON, a cut file (SafetensorError), wrong shapes: one message
        raise ValueError(f"model weights {path} (with {info_path.name}) cannot be loaded: "
                         f"{' '.join(str(exc).split())[:300]}") from None
    # a .json beside weights of another run would lend them its settings and its name
    stated, actual = info.get("weights_id"), weights_id(state)
    if stated is not None and stated != actual:
        raise ValueError(f"model weights {path} are {actual}, but {info_path.name} describes "
                         f"{stated}: the two files come from different training runs")
    return model.eval()
