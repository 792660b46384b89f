"""Replay suites: a YAML file of two-agent bags to make (or take as they are) and replay, and the
summary of their scores.

A suite file (see bench/suites/*.yaml):

    name: real
    data: ../../../shared/data        # scan paths below are relative to this (itself
                                      # relative to the suite file)
    bag_dir: ../../../bags/generated/real   # where made bags go (git-ignored)
    held_out: [scene0005]             # rooms reported on their own rows
    seeds: [1, 2, 3]
    defaults: {voxel: 0.05, clearance: 0.15}      # make-bag settings (commands/make_bag.BagSpec)
    walks:                            # every scan entry is made once per walk and seed
      slow_opposite: {speed: 0.2, opposite: true}
      fast_same: {speed: 0.5, opposite: false}
    scans:                            # make-bag inputs: a scan, or two captures of a room
      - scan: scans/scannet-picwoon_scene0000_00
      - {scan: scans/scannet-picwoon_scene0003_00, scan_b: scans/scannet-picwoon_scene0003_01,
         gt: rescan_gt.json}
      - synth: {kind: office, rooms: 5, seed: 4}  # a synthetic scene made first (any
                                                  # simulation.synth.SynthConfig setting)
    bags:                             # bags taken as they are (paths relative to the file)
      - ../../../bags/apartment_opposite

Public API:
    BagJob                        one bag of a suite: name, how to make it (or its path), tags
    Suite                         name, jobs, held-out rooms, directories
    load_suite(path, seeds=None, bag_spec=None) -> Suite    raises SuiteError with a one-line
                                  reason (a key not known or a value of the wrong type is named);
                                  seeds: walk seeds instead of the file's (cases nothing was
                                  chosen on), without the bags the file takes as they are;
                                  bag_spec: the dataclass of make-bag settings
                                  (commands.make_bag.BagSpec) that defaults, walks and scans
                                  entries are checked against; a synthetic scene's folder
                                  (and so its bags' names and specs) names every setting
    build_spec(bag_spec, spec) -> the make-bag settings of a job (each value as its field's type)
    missed(frames) -> dict        registrable frames not verified: a wrong estimate, a right one
                                  the verdict refused, or one the runtime's rules held (RUNTIME_RULES)
    out_of_reach(frames, word) -> int    registrable frames no link rule could have published
                                  right from these estimates as the verdict judged them
    summarize(results, suite, word=None) -> dict     rows: overall, held-out and training rooms, single /
                                  cross capture, synthetic, each walk; "bags": one row per bag
    format_summary(summary) -> str
    reliability(frames, bins) -> dict    stated confidence against observed correctness
    ResultCache(folder)           per-bag results kept for the next run, never one another fleet
                                  took part in
"""
from __future__ import annotations

import hashlib
import json
import typing
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..config import as_hinted, check_types, from_dict, to_dict
from ..metrics import SUCCESS_RRE_DEG
from ..rescan_gt import SCANNET_CAPTURE, room_of
from ..simulation.synth import SynthConfig


class SuiteError(ValueError):
    """A suite file that cannot be used; the message says why in one line."""


@dataclass
class _SuiteFile:
    """The keys of a suite file and what each holds (null: left out)."""

    name: str | None = None
    data: str | None = None
    bag_dir: str | None = None
    held_out: list[str] | None = None
    seeds: list[int] | None = None
    defaults: dict | None = None
    walks: dict[str, dict] | None = None
    scans: list[dict] | None = None
    bags: list[str] | None = None


@dataclass
class _SynthScene(SynthConfig):
    """A scans entry's synth settings: the generator's and its seed."""

    seed: int = 0


@dataclass
class BagJob:
    """name: unique within the suite (also the bag's folder under bag_dir);
    spec: make-bag settings (dict of commands.make_bag.BagSpec fields) or None for a bag
    taken as it is at `path`; synth: settings of a synthetic scene to generate first (then
    spec["scan"] is where it goes); room / capture ("single", "cross", "synthetic") / walk /
    seed: tags the summary groups by."""

    name: str
    path: Path
    spec: dict | None = None
    synth: dict | None = None
    room: str = ""
    capture: str = "single"
    walk: str = ""
    seed: int | None = None


@dataclass
class Suite:
    name: str
    path: Path
    jobs: list[BagJob]
    held_out: tuple[str, ...] = ()
    bag_dir: Path | None = None


class ResultCache:
    """Per-bag results of a suite run, one `<folder>/<bag>.json` each, reused by the next run when
    made with the same key (bag spec, backend, weights, parameters, source code), so an
    interrupted run resumes. A result another fleet took part in (`report["foreign"]`: its
    nodes may have taken that fleet's maps) is written for reading but never reused."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.json"

    def load(self, name: str, key: str) -> dict | None:
        try:
            report = json.loads(self.path(name).read_text())
        except (OSError, ValueError):
            return None
        return report if isinstance(report, dict) and report.get("cache_key") == key else None

    def save(self, name: str, report: dict, key: str) -> None:
        """Write report (its "cache_key" set here: key, or None when another fleet took part)."""
        report["cache_key"] = None if report.get("foreign") else key
        self.path(name).write_text(json.dumps(report, indent=1, default=float) + "\n")


def _short(scan: str) -> str:
    m = SCANNET_CAPTURE.search(Path(scan).name)
    return m.group(0) if m else Path(scan).name


def _synth_scene(settings: dict) -> tuple[str, str]:
    """(folder name, room) of the synthetic scene of a scans entry's synth settings (checked):
    the room is kind, rooms and seed (as held_out names it); the folder adds a digest of the
    settings that differ from SynthConfig's defaults, so that a changed setting is a new scene
    and bag, and a suite that sets none of them keeps its names."""
    scene = from_dict(_SynthScene, settings)
    room = f"synth_{scene.kind}{scene.rooms}_{scene.seed}"
    default = to_dict(_SynthScene(seed=scene.seed))
    changed = {k: v for k, v in to_dict(scene).items() if v != default[k] and k not in ("kind", "rooms")}
    if not changed:
        return room, room
    digest = hashlib.sha256(json.dumps(changed, sort_keys=True).encode()).hexdigest()[:8]
    return f"{room}_{digest}", room


def _checked(cls, data, where: str) -> dict:
    """data, once every key is a field of cls and every value fits its type."""
    try:
        check_types(cls, data, where)
    except ValueError as exc:
        raise SuiteError(str(exc)) from None
    return data


def build_spec(bag_spec: type, spec: dict):
    """The bag_spec (make-bag settings dataclass) of a job's spec, each value as its field's
    type (lists as tuples, as YAML and JSON give them; `1` for a float as 1.0); raises what
    bag_spec raises for a setting out of range."""
    hints = typing.get_type_hints(bag_spec)
    values = {}
    for key, value in spec.items():
        try:
            values[key] = as_hinted(hints[key], value) if key in hints else value
        except ValueError as exc:
            raise ValueError(f"{key} {exc}") from None
    return bag_spec(**values)


def _buildable(bag_spec: type, spec: dict, where: str) -> None:
    """A job's make-bag settings build a bag_spec (whose ranges it checks): for every job
    before any bag is made, not after minutes of making the ones before it."""
    try:
        build_spec(bag_spec, spec)
    except ValueError as exc:
        raise SuiteError(f"{where}: {exc}") from None


def load_suite(path: str | Path, seeds: list[int] | None = None, bag_spec: type | None = None) -> Suite:
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SuiteError(f"cannot read suite {path}: {' '.join(str(exc).split())}") from None
    if not isinstance(doc, dict):
        raise SuiteError(f"suite {path} is not a mapping")
    where = f"suite {path}"
    _checked(_SuiteFile, doc, where)

    def spec_part(data, part: str) -> dict:
        """make-bag settings of the suite, checked where the dataclass of them is known."""
        return dict(_checked(bag_spec, data, f"{where}: {part}") if bag_spec else data)

    base = path.parent
    data = (base / (doc.get("data") or ".")).resolve()
    bag_dir = (base / (doc.get("bag_dir") or f"generated/{path.stem}")).resolve()
    walk_seeds = list(seeds or doc.get("seeds") or [0])
    walks = {w: spec_part(v, f"walks: {w}") for w, v in (doc.get("walks") or {"default": {}}).items()}
    defaults = spec_part(doc.get("defaults") or {}, "defaults")
    jobs: list[BagJob] = []
    for i, entry in enumerate(doc.get("scans") or []):
        if not ({"scan", "synth"} & set(entry)):
            raise SuiteError(f"{where}: a scans entry needs 'scan' or 'synth', got {entry!r}")
        synth = entry.get("synth")
        extra = spec_part({k: v for k, v in entry.items() if k != "synth"}, f"scans[{i}]")
        extra.pop("scan", None)
        if "synth" in entry:
            if not isinstance(synth, dict):
                raise SuiteError(f"{where}: scans[{i}]: synth must be a mapping, got {synth!r}")
            stem, room = _synth_scene(_checked(_SynthScene, synth, f"{where}: scans[{i}]: synth"))
            scan, capture = str(bag_dir / "scenes" / stem), "synthetic"
        else:
            scan = str(data / entry["scan"])
            capture = "cross" if entry.get("scan_b") else "single"
            room = room_of(scan)
            stem = _short(scan) + (f"x{_short(entry['scan_b'])[-2:]}" if entry.get("scan_b") else "")
            if not Path(scan).exists():
                raise SuiteError(f"{where}: scan {scan} not found (is {data} the data folder?)")
        for key in ("scan_b", "gt"):
            if extra.get(key) is not None:
                extra[key] = str(data / extra[key])
        for walk, walk_settings in walks.items():
            for seed in walk_seeds:
                name = f"{stem}_{walk}_s{seed}"
                spec = {**defaults, **walk_settings, **extra, "scan": scan, "seed": int(seed)}
                if bag_spec is not None:
                    _buildable(bag_spec, spec, f"{where}: {name}")
                jobs.append(BagJob(name, bag_dir / name, spec, synth, room, capture, walk, int(seed)))
    # bags taken as they are have no walk to seed: other seeds leave them out
    shipped = [(base / entry).resolve() for entry in doc.get("bags") or []]
    for bag in shipped if seeds is None else []:
        jobs.append(BagJob(bag.name, bag, room=bag.name, capture="synthetic", walk="shipped"))
    held_out = tuple(doc.get("held_out") or ())
    rooms = {j.room for j in jobs} | {bag.name for bag in shipped}
    unknown = [room for room in held_out if room not in rooms]
    if unknown:     # a typo would report no held-out row and count the room as a training one
        raise SuiteError(f"{where}: held_out names no room of the suite: {', '.join(map(str, unknown))} "
                         f"(its rooms: {', '.join(sorted(rooms))})")
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise SuiteError(f"{where}: two bags share a name")
    if not jobs:
        raise SuiteError(f"{where} names no bags")
    return Suite(doc.get("name") or path.stem, path, jobs, held_out, bag_dir)


# ---- summary --------------------------------------------------------------------------------
# what the suite reports of dense requests -> the runtime counter that counts it
REQUEST_COUNTERS = {"sent": "requests", "retried": "request_retry", "gave_up": "request_gave_up",
                    "refused_within_interval": "request_rate_limited",
                    "refused_over_budget": "request_over_budget"}


# reasons of runtime/peers.py, not the verdict's, for not publishing an estimate as verified:
# the link rules (time, the peer's word, the merged frame), which hold estimates that passed the
# verdict, and its own gates (too few node matches to try; no points of the peer to verify on)
RUNTIME_HELD_AFTER_VERDICT = ("awaiting_confirmation", "contradicted", "disagrees_with_link",
                              "disputed_by_cycles")
RUNTIME_RULES = RUNTIME_HELD_AFTER_VERDICT + ("no_peer_cloud_to_verify", "too_few_matches")
# what missed() calls each cause, in the suite's printout and its plot
MISSED_LABELS = {"wrong_estimate": "wrong estimate", "right_refused": "right, refused by the verdict",
                 "right_held": "right, held by the runtime's rules"}


def missed(frames: list[dict]) -> dict:
    """The registrable frames whose estimate was not published as verified, by cause and reason:
    "wrong_estimate" (wrong by ground truth, and not published), "right_refused" (right, but the
    verdict refused it), "right_held" (right, but held by the runtime's rules: RUNTIME_RULES).
    Tells a miss the estimator caused from one that trust cost. Wrong estimates published as
    verified are not here: they are the reports' wrong_verified."""
    out: dict[str, Counter] = {"wrong_estimate": Counter(), "right_refused": Counter(),
                               "right_held": Counter()}
    for f in frames:
        if not f.get("registrable") or f["verified"]:
            continue
        reason = f.get("reason") or "unknown"
        cause = "wrong_estimate" if not f["correct"] else \
            "right_held" if reason in RUNTIME_RULES else "right_refused"
        out[cause][reason] += 1
    return {cause: dict(c.most_common()) for cause, c in out.items()}


@dataclass(frozen=True)
class PeersWord:
    """What the link rules let the peer's confirmed link do (PeersConfig fields of the same
    names): vouch for an estimate the verdict refused for its confidence alone, at no less than
    vouched_min_confidence, when the two agree (within agree_deg in rotation, among others)."""
    vouched_min_confidence: float
    agree_deg: float


def out_of_reach(frames: list[dict], word: PeersWord) -> int:
    """The registrable frames that no link rule could have published right from this run's
    estimates. A link first rests on an estimate that passed the verdict, and so does the peer's
    word, which vouches only where it agrees with a right estimate, so within the criterion's
    rotation plus agree_deg of the truth (rotation error, unlike translation error, is the same
    both ways round); so in each pair of agents nothing is published before the first estimate
    of either direction that passed the verdict that near the truth. A direction then publishes
    right only from its own first right estimate that passed, or that the verdict refused for
    its confidence alone at no less than vouched_min_confidence (what the peer's word vouches
    for). Frames before that are out of reach; every later one counts as within reach, since a
    link confirmed by then would have made it from its kept correspondences (a merged estimate)
    instead of the estimate this run made without one. So 1 - out_of_reach / registrable bounds
    from above what any link rules reach with this run's estimates (rules that ask for points
    at other times make other estimates: it bounds this run, not every run); above the bound
    lies what takes estimates that are right sooner. "Passed the verdict" is read from the
    reasons the runtime gave (RUNTIME_HELD_AFTER_VERDICT), which only loosens the bound where a
    withdrawal relabelled a refused estimate."""
    links: dict[tuple, list[dict]] = {}
    for f in frames:
        links.setdefault((f["agent"], f["peer"]), []).append(f)

    def passed(f):
        return f["reason"] == "ok" or f["reason"] in RUNTIME_HELD_AFTER_VERDICT

    def first(fs, take):
        return min((f["t"] for f in fs if take(f)), default=np.inf)

    def near(f):
        return f["rre"] < SUCCESS_RRE_DEG + word.agree_deg

    def own(f):
        return f["correct"] and (passed(f) or (f["reason"] == "low_confidence"
                                               and f["confidence"] >= word.vouched_min_confidence))

    n = 0
    for (agent, peer), fs in links.items():
        pair = first(fs + links.get((peer, agent), []), lambda f: passed(f) and near(f))
        start = max(pair, first(fs, own))
        n += sum(1 for f in fs if f.get("registrable") and f["t"] < start)
    return n


def _median(values) -> float | None:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


def _row(results: list[dict], word: PeersWord | None = None) -> dict:
    """One summary row over the bags' results (frames pooled); with the peer's word, the
    registrable frames out of reach of any link rule (out_of_reach, bag by bag)."""
    frames = [f for r in results for f in r["frames"]]
    reg = [f for f in frames if f.get("registrable")]
    links = [link for r in results for link in r.get("links", {}).values()]
    # links whose maps could be registered by ground truth (older results: that published a
    # registrable frame)
    reg_links = [link for link in links if link.get("registrable_since_bag_s", link["first_registrable_s"]) is not None]
    # bytes over frames of the bags whose traffic was metered (replays through real nodes)
    metered = [r for r in results if r.get("bytes_per_topic") is not None]
    metered_frames = sum(r["query_frames"] for r in metered)
    # seconds the merged frame held a wrong link or misplaced an agent (what /tf carried)
    merged_wrong = [(r.get("merge") or {}).get("while_replayed", {}).get("wrong_s") for r in results]
    return {
        "bags": len(results),
        "query_frames": len(frames),
        "registrable_frames": len(reg),
        "success_rate": (sum(f["success"] for f in frames) / len(frames)) if frames else None,
        "success_rate_registrable": (sum(f["success"] for f in reg) / len(reg)) if reg else None,
        "wrong_verified": int(sum(f["verified"] and not f["correct"] for f in frames)),
        "bags_with_wrong_verified": int(sum(r["wrong_verified"] > 0 for r in results)),
        "median_time_to_success_s": _median(link["time_to_success_s"] for link in reg_links),
        "merged_wrong_s": (float(sum(w for w in merged_wrong if w is not None))
                           if any(w is not None for w in merged_wrong) else None),
        "links_never_registered": int(sum(link["time_to_success_s"] is None for link in reg_links)),
        "kb_per_query_frame": (sum(sum(r["bytes_per_topic"].values()) for r in metered) / 1e3 / metered_frames
                               if metered_frames else None),
        "coarse_latency_ms": _median(f.get("total_ms") for f in frames if f.get("mode") in ("coarse", "merged")),
        "dense_latency_ms": _median(f.get("total_ms") for f in frames if f.get("mode") == "dense"),
        "dense_requests": _requests(results),
        "missed": missed(frames),
        "out_of_reach": None if word is None else sum(out_of_reach(r["frames"], word) for r in results),
    }


def _requests(results: list[dict]) -> dict | None:
    """Dense requests over the bags, from every agent's counters: sent, retried, given up after
    every retry, and refused by the answering agent (within its interval of the requester's last
    answer, or over its answer budget); None where no bag reports counters (an older cache)."""
    tables = [c for r in results for c in (r.get("counters") or {}).values()]
    if not tables:
        return None
    total = Counter()
    for table in tables:
        total.update(table)
    return {name: int(total[key]) for name, key in REQUEST_COUNTERS.items()}


def summarize(results: dict[str, dict], suite: Suite, word: PeersWord | None = None) -> dict:
    """results: bag name -> replay report (with frames and links); word: what the run's link
    rules let the peer's word do, for out_of_reach."""
    jobs = {j.name: j for j in suite.jobs if j.name in results}
    groups: dict[str, list[str]] = {"all": list(jobs)}
    held = [n for n, j in jobs.items() if j.room in suite.held_out]
    if held:
        groups["held-out rooms (" + ", ".join(suite.held_out) + ")"] = held
        # real rooms are held out of the network's training; generated ones out of tuning
        rest = "the other scenes" if all(jobs[n].capture == "synthetic" for n in held) \
            else "rooms seen in training"
        groups[rest] = [n for n in jobs if n not in held]
    for capture in ("single", "cross", "synthetic"):
        names = [n for n, j in jobs.items() if j.capture == capture]
        if names and len(names) < len(jobs):
            groups[f"{capture} capture" if capture != "synthetic" else "synthetic"] = names
    walks = sorted({j.walk for j in jobs.values()})
    if len(walks) > 1:
        for walk in walks:
            groups[f"walk {walk}"] = [n for n, j in jobs.items() if j.walk == walk]
    return {"suite": suite.name,
            "peers_word": None if word is None else asdict(word),
            "rows": {g: _row([results[n] for n in names], word) for g, names in groups.items()
                     if names or g == "all"},     # a run of held-out bags only (--only) has no others
            "bags": {n: {**_row([results[n]], word), "room": j.room, "capture": j.capture,
                         "walk": j.walk, "seed": j.seed} for n, j in jobs.items()}}


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _num(v, fmt="{:.1f}") -> str:
    return "-" if v is None else fmt.format(v)


HEADER = ["", "bags", "frames", "registrable", "success", "success (registrable)",
          "wrong verified", "merged map wrong", "time to success (median)", "never registered", "kB / frame",
          "coarse / dense ms"]


def _cells(name: str, r: dict) -> list[str]:
    return [name, str(r["bags"]), str(r["query_frames"]), str(r["registrable_frames"]),
            _pct(r["success_rate"]), _pct(r["success_rate_registrable"]),
            str(r["wrong_verified"]), _num(r.get("merged_wrong_s"), "{:.0f} s"),
            _num(r["median_time_to_success_s"], "{:.1f} s"),
            str(r["links_never_registered"]), _num(r["kb_per_query_frame"]),
            f"{_num(r['coarse_latency_ms'], '{:.0f}')} / {_num(r['dense_latency_ms'], '{:.0f}')}"]


def format_summary(summary: dict) -> str:
    from .bandwidth import format_table

    per_bag = format_table(HEADER, [_cells(n, r) for n, r in summary["bags"].items()])
    overall = format_table(HEADER, [_cells(n, r) for n, r in summary["rows"].items()])
    text = f"{per_bag}\n\nsuite {summary['suite']}:\n{overall}"
    req = summary["rows"]["all"].get("dense_requests")
    if req:
        text += (f"\n\ndense requests: {req['sent']} sent, {req['retried']} retried, {req['gave_up']} "
                 f"given up after every retry; refused by the answering agent: "
                 f"{req['refused_within_interval']} within its interval, {req['refused_over_budget']} "
                 "over its budget")
    miss = summary["rows"]["all"].get("missed")
    if miss and any(miss.values()):
        def said(cause: str) -> str:
            n = sum(miss[cause].values())
            return f"{n}" + (f" ({', '.join(f'{r} {k}' for r, k in miss[cause].items())})" if n else "")
        text += "\nregistrable frames not verified:" + "".join(
            f"\n  {label}: {said(cause)}" for cause, label in MISSED_LABELS.items())
    row = summary["rows"]["all"]
    if row.get("out_of_reach") is not None and row["registrable_frames"]:
        reg, n = row["registrable_frames"], row["out_of_reach"]
        text += (f"\nwithin reach of the link rules: at most {reg - n} of {reg} registrable frames "
                 f"({100 * (1 - n / reg):.2f} %) with these estimates, each published as soon as a rule "
                 f"could take it; {n} came before their pair's first estimate to pass the verdict (near "
                 "the truth), or before their own direction's first right one that passed it or that the "
                 "peer's word could vouch for (refused for its confidence alone, at "
                 f"{summary['peers_word']['vouched_min_confidence']:g} or more)")
    return text


def reliability(frames: list[dict], bins: int = 10) -> dict:
    """Stated confidence against observed correctness over frames with an estimate: per bin
    the mean confidence, the share of correct estimates and the count; ECE (count-weighted
    mean gap)."""
    conf = np.array([f["confidence"] for f in frames], np.float64)
    ok = np.array([f["correct"] for f in frames], bool)
    keep = np.isfinite(conf)
    conf, ok = conf[keep], ok[keep]
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.digitize(conf, edges[1:-1]), 0, bins - 1)
    rows = []
    for b in range(bins):
        m = idx == b
        rows.append({"lo": float(edges[b]), "hi": float(edges[b + 1]), "n": int(m.sum()),
                     "confidence": float(conf[m].mean()) if m.any() else None,
                     "correct": float(ok[m].mean()) if m.any() else None})
    ece = sum(r["n"] * abs(r["confidence"] - r["correct"]) for r in rows if r["n"]) / max(len(conf), 1)
    return {"bins": rows, "ece": float(ece), "n": int(len(conf))}
