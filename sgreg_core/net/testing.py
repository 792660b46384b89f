"""Tiny stand-ins for the tests (tests/core, tests/ros): no MiniLM load, no data on disk.

Public API:
    hashed_text_encoder() -> TextEncoder       pseudo-random unit embeddings seeded by the label
    toy_graph(rng, n=20) -> SceneGraph         random boxes filled with points, radius edges
    moved_graph(graph, T, rng, jitter) -> SceneGraph
        the same nodes seen again: every point jittered, then everything moved by T
"""
from __future__ import annotations

import hashlib

import numpy as np

from ..geometry import transform_points
from ..types import SceneGraph
from .text import TEXT_DIM, TextEncoder

TOY_LABELS = ["chair", "table", "sofa", "lamp", "cabinet", "bed", "door", "plant", "wall", "floor"]


def _hashed_embed(labels: list[str]) -> np.ndarray:
    seeds = [int(hashlib.sha256(s.encode()).hexdigest()[:8], 16) for s in labels]
    emb = np.stack([np.random.default_rng(s).normal(size=TEXT_DIM) for s in seeds])
    return (emb / np.linalg.norm(emb, axis=1, keepdims=True)).astype(np.float32)


def hashed_text_encoder() -> TextEncoder:
    return TextEncoder(embed_fn=_hashed_embed, name="hashed")


def toy_graph(rng: np.random.Generator, n: int = 20, edge_radius: float = 3.0) -> SceneGraph:
    centers = np.c_[rng.uniform(-4, 4, (n, 2)), rng.uniform(0, 1.5, n)].astype(np.float32)
    extents = rng.uniform(0.3, 1.5, (n, 3)).astype(np.float32)
    counts = rng.integers(20, 200, n)
    offsets = rng.uniform(-0.5, 0.5, (int(counts.sum()), 3)) * np.repeat(extents, counts, 0)
    flat = (np.repeat(centers, counts, 0) + offsets).astype(np.float32)
    points = np.split(flat, np.cumsum(counts)[:-1])
    dist = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    edges = np.argwhere(np.triu(dist < edge_radius, 1)).astype(np.int64)
    return SceneGraph(node_ids=np.arange(1, n + 1, dtype=np.int64),
                      labels=[TOY_LABELS[k] for k in rng.integers(len(TOY_LABELS), size=n)],
                      scores=np.ones(n, np.float32), centers=centers, extents=extents,
                      points=points, edges=edges, structural=np.zeros(n, bool))


def moved_graph(graph: SceneGraph, T: np.ndarray, rng: np.random.Generator,
                jitter: float = 0.01) -> SceneGraph:
    counts = np.fromiter(map(len, graph.points), dtype=np.int64, count=graph.num_nodes)
    flat = np.concatenate(graph.points)
    flat = transform_points(T, flat + rng.normal(0, jitter, flat.shape).astype(np.float32))
    return SceneGraph(node_ids=graph.node_ids.copy(), labels=list(graph.labels),
                      scores=graph.scores.copy(), centers=transform_points(T, graph.centers),
                      extents=graph.extents.copy(), points=np.split(flat, np.cumsum(counts)[:-1]),
                      edges=graph.edges.copy(), structural=graph.structural.copy())
