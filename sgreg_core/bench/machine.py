"""What machine a timed benchmark ran on, and how fast it was running at the time.

Wall times on a shared or throttled machine move by tens of percent between runs of the same
code: on the development machine the same held-out front-end pairs had a dense median of 284 ms
one day and 196-215 ms the next, and 286 ms in a run whose reference time rose by 40 % while it
ran. So a timed benchmark records the machine and the time of a fixed reference workload before
and after its run (bench-register also every REFERENCE_EVERY cases, reported per setting): two
results are comparable when their reference times are, and a run whose reference took 20 %
longer ran on a machine 20 % slower.

The reference workload is a small, seeded copy of what the dense pipeline spends its time on:
voxelising points, local planes from KD-tree neighbourhoods, and a few layers of a small
network on one thread of torch (the benchmarks' own setting).

Public API:
    reference_ms(repeats) -> float   median wall time (ms) of the reference workload
    describe() -> dict               cpu, cores, load average, library versions, torch threads
"""
from __future__ import annotations

import os
import platform
import time

import numpy as np

from ..geometry import local_planes, voxel_downsample

# a long benchmark times the reference every this many cases too: the machine's speed moved by
# 40 % within one run of 360 pairs (60.9 -> 85.3 ms), so a median is read beside the speed of
# the machine while its cases ran
REFERENCE_EVERY = 30


def _workload() -> None:
    import torch

    rng = np.random.default_rng(0)
    planes = rng.uniform([0.0, 0.0, 0.0], [6.0, 5.0, 0.02], (20000, 3))
    walls = rng.uniform([0.0, 0.0, 0.0], [6.0, 0.02, 2.5], (10000, 3))
    local_planes(voxel_downsample(np.concatenate([planes, walls]), 0.05), 12)
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(2048, 64, generator=gen)
    weights = [torch.randn(64, 64, generator=gen) / 8.0 for _ in range(4)]
    with torch.no_grad():
        for w in weights:
            x = torch.relu(x @ w)


def reference_ms(repeats: int = 7) -> float:
    """Median wall time (ms) of the reference workload over `repeats` runs, after one unmeasured
    run (imports, caches)."""
    _workload()
    times = []
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        _workload()
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times))


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def describe() -> dict:
    """The machine and the software a benchmark ran with."""
    import scipy
    import torch

    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "load_average": load,
            "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "torch": torch.__version__,
            "torch_threads": torch.get_num_threads()}


def summary_line(machine: dict) -> str:
    """One line for a benchmark's printout."""
    ref = machine.get("reference_ms", {})
    load = machine.get("load_average")
    during = ", ".join(f"{k} {v:.1f}" for k, v in ref.get("by_setting", {}).items())
    return (f"machine: {machine.get('cpu')}, {machine.get('cores')} cores, load "
            f"{load[0] if load else '?'} at the start; reference workload "
            f"{ref.get('before', float('nan')):.1f} / {ref.get('after', float('nan')):.1f} ms "
            f"before / after" + (f", median among the cases of {during} ms" if during else "")
            + " (sgreg_core/bench/machine.py; lower is faster, compare runs by it)")
