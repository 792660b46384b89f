"""Synthetic indoor scenes (apartments, offices) as instance maps, for training and tests.

    from sgreg_core.simulation.synth import SynthConfig, generate_scene
    imap = generate_scene(seed=3, cfg=SynthConfig(kind="office", rooms=2))

Modules: shapes (surface primitives and sampling), objects (the object catalogue),
layout (rooms, walls, openings, placement), scene (furnishing and the generator).
"""
from .objects import KINDS
from .scene import ROOM_TYPES, SynthConfig, generate_scene

__all__ = ["KINDS", "ROOM_TYPES", "SynthConfig", "generate_scene"]
