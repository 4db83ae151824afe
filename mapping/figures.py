"""Writing a matplotlib figure as a PNG, headless (Agg): one helper for every layer's pictures (a run's, in
``mapping.pipeline.plots``; a world's, in ``openmulti_env.world.plots``), so neither layer reaches into the
other's modules for it."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def save_figure(fig, path: str | Path, title: str = "", dpi: int = 100) -> Path:
    """Title, tighten, write the PNG (creating its folder) and free the figure."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
