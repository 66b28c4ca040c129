"""The two time plots a dive report draws, shared by the evaluation report and the archive's campaign page:
depth over time and semantic score over time, each with the summary frames marked. PNGs through matplotlib's
Agg backend (no display on the vehicle or in CI)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

Points = Sequence[tuple[float, float]]


def _pyplot():
    import matplotlib  # with pyplot 1.0 s (measured): only when a plot is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_depth(path: Path, title: str, track: Points, marked: Points, *, xlabel: str = "time (s)",
               track_label: str = "depth") -> None:
    """Depth (down is down) with the summary frames at their tagged depths."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3))
    if track:
        ax.plot(*zip(*track, strict=True), lw=1, color="tab:blue", label=track_label)
    if marked:
        ax.scatter(*zip(*marked, strict=True), color="tab:orange", zorder=3, label="summary frames")
    ax.invert_yaxis()
    ax.set_xlabel(xlabel)
    ax.set_ylabel("depth (m)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"{title}: depth profile")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_scores(path: Path, title: str, scores: Points, marked: Points, *, tau: float | None = None,
                xlabel: str = "time (s)", ylim: tuple[float, float] | None = None) -> None:
    """The semantic score over time, the threshold in force and the summary frames' scores."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(*zip(*scores, strict=True), lw=1, color="tab:blue", label="semantic score")
    if tau is not None:
        ax.axhline(tau, color="tab:red", ls="--", lw=1, label=f"tau_ss = {tau:g}")
    if marked:
        ax.scatter(*zip(*marked, strict=True), color="tab:orange", zorder=3, label="summary frames")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("score")
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{title}: score over time")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
