"""Pictures of registrations, graphs, replays and merged maps (matplotlib, imported only when
drawing).

Public API:
    figure_path(path) -> Path    path, once its extension names a format matplotlib writes and
                                 its folder exists and is writable; ValueError / OSError with a
                                 one-line reason otherwise: checked before the work it draws
"""
from __future__ import annotations

from pathlib import Path


def figure_path(path: str | Path) -> Path:
    from matplotlib.backend_bases import FigureCanvasBase

    from ..paths import make_folder

    p = Path(path)
    formats = FigureCanvasBase.get_supported_filetypes()
    if p.suffix[1:].lower() not in formats:
        raise ValueError(f"{p}: the extension must name a picture format ({', '.join(sorted(formats))})")
    make_folder(p.parent)
    return p
