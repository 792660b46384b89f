"""Agents level their own maps (gravity from VIO is off differently per robot): messages carry
the sender's levelling, and the transform a peer publishes is between the maps as they are."""
import numpy as np
import pytest

from sgreg_core.geometry import invert_transform
from sgreg_core.metrics import rre, rte
from sgreg_core.net.model import load_model
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.peers import Peers, PeersConfig
from sgreg_core.simulation.pairs import PairConfig, make_pair
from sgreg_core.simulation.noise import tilt_rotation
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.types import InstanceMap


@pytest.fixture(scope="module")
def model():
    return load_model()


def test_tilted_agents_publish_the_transform_between_their_maps(model):
    pair = make_pair(generate_scene(6, SynthConfig(rooms=2)), PairConfig(overlap=0.8), np.random.default_rng(2))
    A, B = tilt_rotation(1.7, 30.0), tilt_rotation(1.1, 160.0)       # each robot's gravity error
    a = AgentCore(AgentConfig(name="a"), model)
    b = AgentCore(AgentConfig(name="b"), model)
    assert a.take_map(pair.src.transformed(A), 1, 0) is None
    assert b.take_map(pair.ref.transformed(B), 1, 0) is None
    assert abs(a.level.tilt_deg - 1.7) < 0.2 and abs(b.level.tilt_deg - 1.1) < 0.2
    msg = b.coarse_message(1)
    assert np.allclose(msg.level, b.level.R)
    # the centers travel levelled: upright, whatever b's gravity error
    assert np.allclose(msg.nodes.centers, b.graph.centers)

    peers = Peers(PeersConfig(), a, model)
    _, req = peers.on_coarse(msg, now=0.0)
    est = peers.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    assert est.reason in ("ok", "awaiting_confirmation"), est.reason
    T_ab = B @ pair.T_src_ref @ invert_transform(A)      # a's map as given -> b's map as given
    assert rte(est.T, T_ab) < 0.05 and rre(est.T, T_ab) < 0.5
    assert est.registration.levelling["ref"]["tilt_deg"] == pytest.approx(a.level.tilt_deg, abs=1e-3)


def test_a_growing_map_keeps_its_levelling(model):
    """Small changes of the estimate do not re-level the map (its frame would move under the
    peers' kept correspondences); a real change does."""
    scene = generate_scene(6, SynthConfig(rooms=2)).transformed(tilt_rotation(1.5, 80.0))
    a = AgentCore(AgentConfig(name="a"), model)
    a.take_map(scene, 1, 0)
    first = a.level
    keep = np.random.default_rng(0).random(len(scene.points)) < 0.9
    a.take_map(InstanceMap(scene.points[keep], scene.instance[keep], scene.labels), 2, 1_000_000_000)
    assert a.level is first
    # the map leans 2.5 deg more: re-levelled
    a.take_map(scene.transformed(tilt_rotation(2.5, 0.0)), 3, 2_000_000_000)
    assert a.level is not first and abs(a.level.tilt_deg - first.tilt_deg) > 1.0
