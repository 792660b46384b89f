"""The SG-Reg network on CPU: text + box node encoding, triplet GNN, shape network,
hierarchical node/point matching, training. See model.py for the runtime API."""
from .model import (DenseMatches, ModelConfig, NodeFeatures, NodeMatches, PointMatches,
                    SGRegModel, load_model, save_model, weights_id)
from .text import TextEncoder, default_text_encoder

__all__ = ["DenseMatches", "ModelConfig", "NodeFeatures", "NodeMatches", "PointMatches",
           "SGRegModel", "TextEncoder", "default_text_encoder", "load_model", "save_model",
           "weights_id"]
