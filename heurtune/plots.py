"""Figures drawn with matplotlib (Agg backend: no display needed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from heurtune.io import atomic_path  # noqa: E402
from heurtune.objectives.loop import RANGE_RTOL  # noqa: E402

__all__ = ["plot_responses"]

OUTSIDE = "outside physical range"


def _outside(values, lo, hi) -> bool:
    """True when a finite value lies below ``lo`` or above ``hi`` by more than the tolerance."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return False
    tol = RANGE_RTOL * max(abs(lo), abs(hi), 1.0)
    return bool(v.min() < lo - tol or v.max() > hi + tol)


def _draw_limits(ax, lo, hi, label):
    """Dashed lines at ``lo`` and ``hi`` that do not rescale the panel.

    The view stays on the response: a limit far from it is named in the legend only, one that
    the response approaches or crosses is also drawn.
    """
    ylim = ax.get_ylim()
    ax.axhline(lo, color="0.35", lw=0.9, ls=(0, (5, 3)), label=label)
    ax.axhline(hi, color="0.35", lw=0.9, ls=(0, (5, 3)))
    ax.set_ylim(ylim)


def plot_responses(traj, path, title: str = "", plant=None) -> None:
    """Levels (measured y and true h) and pump voltages per scenario.

    Parameters
    ----------
    traj : pandas.DataFrame
        Columns ``scenario, t, h1, h2, y1, y2, u1, u2`` (``h3, h4`` optional).
    path : str or Path
        PNG written atomically.
    title : str
        Figure title.
    plant : QTPParams, optional
        When it has physical limits (``plant.has_limits``), the tank heights (level panels,
        with the empty tank at 0 cm) and the pump voltage range (voltage panels) are drawn as
        dashed lines, and a panel whose trajectory leaves that range says so in its title; the
        figure title names the scenarios that leave it (upper tanks included, when h3 and h4
        are given).
    """
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for name, df in traj.groupby("scenario", sort=False):
        for i in (1, 2):
            line, = axes[0, i - 1].plot(df["t"], df[f"y{i}"], lw=1.2, label=f"{name}: y{i}")
            if f"h{i}" in df:
                axes[0, i - 1].plot(df["t"], df[f"h{i}"], lw=0.8, ls="--", color=line.get_color(),
                                    label=f"{name}: h{i}")
            axes[1, i - 1].plot(df["t"], df[f"u{i}"], lw=1.2, label=name)
    limited = plant is not None and getattr(plant, "has_limits", False)
    if limited:
        u_lo, u_hi = plant.u_range
        for i in (1, 2):
            H = plant.height[i - 1]
            # the true level when recorded (the measured one carries the output disturbance)
            level = traj[f"h{i}"] if f"h{i}" in traj else traj[f"y{i}"]
            _draw_limits(axes[0, i - 1], 0.0, H, f"tank {i}: 0 and {H:g} cm")
            _draw_limits(axes[1, i - 1], u_lo, u_hi, f"pump range {u_lo:g} to {u_hi:g} V")
            axes[0, i - 1].set_title(f"tank {i}" + (f": {OUTSIDE}" if _outside(level, 0.0, H) else ""),
                                     fontsize=10)
            axes[1, i - 1].set_title(f"pump {i}" + (f": {OUTSIDE}" if _outside(traj[f"u{i}"], u_lo, u_hi) else ""),
                                     fontsize=10)
        leaving = []
        for name, df in traj.groupby("scenario", sort=False):
            tanks = [j for j in range(1, 5) if f"h{j}" in df] or [1, 2]
            out = any(_outside(df[f"h{j}"] if f"h{j}" in df else df[f"y{j}"], 0.0, plant.height[j - 1])
                      for j in tanks)
            out = out or any(_outside(df[f"u{j}"], u_lo, u_hi) for j in (1, 2))
            if out:
                leaving.append(str(name))
        if leaving:
            title = f"{title}\n{OUTSIDE}: {', '.join(leaving)}" if title else f"{OUTSIDE}: {', '.join(leaving)}"
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
