"""Agents name their objects themselves: nothing in sgreg may compare one agent's instance or
node ids with another's. Bags cut from one scan give both agents the scan's ids, so a code path
that matched objects by id would look right there and fail on real robots; this test would
catch it. Agent b's ids are renamed (in the same order, so every graph and feature is built
alike) and every estimate of the fleet must stay the same."""
import numpy as np

from sgreg_core.bench.offline_replay import OfflineReplayConfig, offline_replay
from sgreg_core.net.model import load_model
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.simulation.walks import WalkConfig, simulate
from sgreg_core.simulation.observe import TrajectoryConfig
from sgreg_core.types import InstanceMap


def renamed(imap: InstanceMap, rename) -> InstanceMap:
    inst = np.where(imap.instance > 0, rename(imap.instance), imap.instance).astype(np.int32)
    return InstanceMap(points=imap.points, instance=inst,
                       labels={int(rename(k)): v for k, v in imap.labels.items()},
                       scores={int(rename(k)): v for k, v in imap.scores.items()})


def test_estimates_do_not_depend_on_the_ids_the_peer_gives_its_objects():
    scene = generate_scene(3, SynthConfig(rooms=1))
    run = simulate(scene, np.random.default_rng(1),
                   WalkConfig(opposite=True, voxel=0.08,
                              trajectory=TrajectoryConfig(speed=0.5, clearance=0.3)))
    maps = sorted(((t, r.name, m) for r in run.agents for t, m in r.snapshots), key=lambda e: (e[0], e[1]))
    model = load_model()

    def estimates(maps):
        return [(r.t, r.agent, r.peer, r.mode, r.verified, r.reason, np.round(r.T, 6).tolist())
                for r in offline_replay(maps, model, OfflineReplayConfig())]

    before = estimates(maps)
    after = estimates([(t, name, renamed(m, lambda i: 3 * np.asarray(i) + 1000) if name == "b" else m)
                       for t, name, m in maps])
    assert sum(e[4] for e in before) >= 3, before      # verified estimates to compare
    assert after == before
