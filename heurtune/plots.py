"""Figures drawn with matplotlib (Agg backend: no display needed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from heurtune.io import atomic_path  # noqa: E402

__all__ = ["plot_responses"]


def plot_responses(traj, path, title: str = "") -> None:
    """Levels (measured y and true h) and pump voltages per scenario.

    Parameters
    ----------
    traj : pandas.DataFrame
        Columns ``scenario, t, h1, h2, y1, y2, u1, u2``.
    path : str or Path
        PNG written atomically.
    """
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for name, df in traj.groupby("scenario", sort=False):
        for i in (1, 2):
            line, = axes[0, i - 1].plot(df["t"], df[f"y{i}"], lw=1.2, label=f"{name}: y{i}")
            if f"h{i}" in df:
                axes[0, i - 1].plot(df["t"], df[f"h{i}"], lw=0.8, ls="--", color=line.get_color(),
                                    label=f"{name}: h{i}")
            axes[1, i - 1].plot(df["t"], df[f"u{i}"], lw=1.2, label=name)
    for i in (1, 2):
        axes[0, i - 1].set_ylabel(f"level {i} (cm)")
        axes[1, i - 1].set_ylabel(f"pump voltage u{i} (V)")
        axes[1, i - 1].set_xlabel("t (s)")
        axes[0, i - 1].legend(fontsize=7)
        axes[1, i - 1].legend(fontsize=7)
        for ax in axes[:, i - 1]:
            ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
