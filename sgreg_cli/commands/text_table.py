"""sgreg text-table [--out FILE] [--scans DIR]: the label embeddings that ship beside the model
(sgreg_core/weights/labels_<text model>.npz), so that nodes and `sgreg register` never load
the text model for a label of the training vocabulary: the NYU40 classes of the ScanNet scans,
every name of the synthetic object catalogue and the paraphrases of the noise model, plus the
labels of any instance maps under --scans."""
from __future__ import annotations

import json
import sys
from pathlib import Path

NAME = "text-table"
HELP = "write the shipped label-embedding table (the training vocabulary)"

# The 40 classes of NYU Depth v2 (Gupta et al. 2013) that ScanNet's instance labels use, spelled
# as the benchmark spells them.
NYU40 = ("wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
         "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror",
         "floor mat", "clothes", "ceiling", "books", "refridgerator", "television", "paper", "towel",
         "shower curtain", "box", "whiteboard", "person", "night stand", "toilet", "sink", "lamp",
         "bathtub", "bag", "otherstructure", "otherfurniture", "otherprop")


def add_arguments(p):
    p.add_argument("--out", help="default: the shipped table, sgreg_core/weights/labels_<model>.npz")
    p.add_argument("--scans", help="also every label of the instance maps under this folder")


def vocabulary(scans: str | None = None) -> list[str]:
    from sgreg_core.net.text import normalize_label
    from sgreg_core.simulation.noise import CONFUSIONS, INVENT_LABELS, PARAPHRASES
    from sgreg_core.simulation.synth.objects import KINDS

    labels = set(NYU40) | set(PARAPHRASES) | {x for alts in PARAPHRASES.values() for x in alts}
    labels |= set(CONFUSIONS) | {x for alts in CONFUSIONS.values() for x in alts} | set(INVENT_LABELS)
    for kind in KINDS.values():
        labels |= {kind.nyu40, *kind.names}
    if scans:
        if not Path(scans).is_dir():
            raise ValueError(f"--scans {scans} is not a folder")
        for path in sorted(Path(scans).rglob("instances.json")):
            try:
                items = json.loads(path.read_text())
                labels |= {item["label"] for item in items}
            except (OSError, ValueError, TypeError, KeyError) as exc:
                raise ValueError(f"{path}: not a list of instances with a 'label' ({exc})") from None
    return sorted({normalize_label(s) for s in labels})


def run(args) -> int:
    from sgreg_core.net.text import SHIPPED_TABLE, TextEncoder
    from sgreg_core.paths import output_file

    out = Path(args.out) if args.out else SHIPPED_TABLE
    try:
        labels = vocabulary(args.scans)
        output_file(out)
    except (OSError, ValueError) as exc:
        print(f"sgreg text-table: {exc}", file=sys.stderr)
        return 2
    TextEncoder().write_table(out, labels)
    print(f"wrote {len(labels)} label embeddings to {out} ({out.stat().st_size / 1024:.0f} kB)")
    return 0
