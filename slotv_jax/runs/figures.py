"""The figure style of the recorded reports: matplotlib on its file-only backend, a mean ± SD
band over repeated runs, one colour per selection strategy, and a figure written atomically
and closed.

matplotlib is an optional dependency: it is imported on the first call, never when this
module is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from jaxtyping import Float

from slotv_jax.core.fileio import save_figure

# One colour per active-selection strategy and oracle, in every figure (strategies no longer
# in the library keep theirs: their recorded runs are still drawn).
STRATEGY_COLORS = {
    "random": "black",
    "uncertainty": "tab:orange",
    "margin": "tab:red",
    "margin_cluster": "tab:brown",
    "error": "tab:cyan",
    "bald": "tab:blue",
    "bald_fantasy": "tab:green",
    "bald_cluster": "tab:purple",
    "epig": "tab:olive",
    "oracle_loss": "tab:gray",
    "oracle_margin": "tab:pink",
}


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | Path, **savefig_kw) -> None:
    """Write ``fig`` to ``path`` (atomically, :func:`slotv_jax.core.fileio.save_figure`; the
    suffix picks the format) and close it, also when writing fails."""
    import matplotlib.pyplot as plt

    try:
        save_figure(fig, path, **savefig_kw)
    finally:
        plt.close(fig)


def mean_sd(
    runs: Float[np.ndarray, "R V"], ddof: int = 0
) -> tuple[Float[np.ndarray, " V"], Float[np.ndarray, " V"]]:
    """Mean and SD over the runs (rows) of ``runs``; with ``ddof`` = 1 and a single run the
    SD is 0."""
    runs = np.asarray(runs)
    m = runs.mean(0)
    if ddof and len(runs) <= ddof:
        return m, np.zeros(runs.shape[1])
    return m, runs.std(0, ddof=ddof)


def band(ax, x, mean, sd, *fmt, alpha: float = 0.15, outline: bool = False, **line):
    """A line at ``mean`` and a shaded band mean ± sd around it, in the line's colour (with
    ``outline`` the band keeps matplotlib's edge, else it has none). Returns the line."""
    (ln,) = ax.plot(x, mean, *fmt, **line)
    edge = {} if outline else {"linewidth": 0}
    ax.fill_between(x, mean - sd, mean + sd, color=line.get("color", ln.get_color()),
                    alpha=alpha, **edge)  # fmt: skip
    return ln
