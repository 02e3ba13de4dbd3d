"""The report's PNG plots (matplotlib, no display needed): each function writes one file.

Error bars on success rates are the Wilson 95% intervals of the tables; bands on the
learning curves are +- one standard deviation over seeds.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: works on machines without a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

DPI = 110
PALETTE = ["#3b7dd8", "#e8833a", "#3aa76d", "#c8473f", "#8a63c7", "#8c6d4f", "#d26fb5", "#7f7f7f"]


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _error(table: pd.DataFrame, prefix: str) -> np.ndarray:
    rate = table[f"{prefix}rate"].to_numpy(float)
    below = rate - table[f"{prefix}ci_low"].to_numpy(float)
    above = table[f"{prefix}ci_high"].to_numpy(float) - rate
    return np.clip(np.nan_to_num(np.vstack([below, above])), 0.0, None)  # rounding can leave -1e-17


def grouped_rate_bars(table: pd.DataFrame, group: str, hue: str | None, path: Path, title: str,
                      prefix: str = "success_") -> Path:
    """Bars of ``{prefix}rate`` per ``group`` (x axis), one color per ``hue`` value, Wilson error bars."""
    hues = sorted(table[hue].astype(str).unique()) if hue else [None]
    groups = list(dict.fromkeys(table[group].astype(str)))
    width = 0.8 / len(hues)
    fig, ax = plt.subplots(figsize=(max(5.0, 1.1 * len(groups) * max(1, len(hues)) + 1.5), 3.6))
    for j, value in enumerate(hues):
        part = table if value is None else table[table[hue].astype(str) == value]
        x = np.array([groups.index(g) for g in part[group].astype(str)]) + (j - (len(hues) - 1) / 2) * width
        ax.bar(x, part[f"{prefix}rate"], width, yerr=_error(part, prefix), capsize=3,
               color=PALETTE[j % len(PALETTE)], label=value)
        for xi, rate in zip(x, part[f"{prefix}rate"]):
            ax.text(xi, 0.02, f"{rate:.0%}", ha="center", va="bottom", fontsize=7, color="white")
    ax.set_xticks(range(len(groups)), groups)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate (Wilson 95%)")
    ax.set_title(title)
    if hue and len(hues) > 1:
        ax.legend(title=hue, fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return _save(fig, path)


def attempt_bars(table: pd.DataFrame, path: Path) -> Path:
    """First-attempt and any-attempt success per object (the paper's real-robot figure)."""
    labels = (table["source"].astype(str) + "\n" + table["object"].astype(str)).tolist()
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(5.0, 1.2 * len(labels) + 1.5), 3.6))
    for j, (prefix, name) in enumerate((("first_attempt_", "first attempt"), ("any_attempt_", "any attempt"))):
        ax.bar(x + (j - 0.5) * 0.38, table[f"{prefix}rate"], 0.38, yerr=_error(table, prefix), capsize=3,
               color=PALETTE[j], label=name)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("share of trials (Wilson 95%)")
    ax.set_title("success at the first attempt and after several")
    ax.legend(fontsize=8)
    return _save(fig, path)


def histograms(episodes: pd.DataFrame, column: str, path: Path, xlabel: str) -> Path:
    """Histogram of ``column`` per source (overlaid)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    values = episodes[column].astype("float64")
    finite = values[np.isfinite(values)]
    bins = np.histogram_bin_edges(finite, bins=min(30, max(5, int(np.sqrt(len(finite)))))) if len(finite) else 10
    for j, (source, part) in enumerate(episodes.groupby("source", sort=True)):
        ax.hist(part[column].astype("float64").dropna(), bins=bins, alpha=0.6, color=PALETTE[j % len(PALETTE)],
                label=f"{source} (n={len(part)})")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("episodes")
    ax.set_title(f"episode {column}")
    ax.legend(fontsize=8)
    return _save(fig, path)


# success_rate: the runs' one verdict; last_step_success_rate: ToolShape-v0's secondary one-frame verdict;
# settled_success_rate: the column of learning_curves.csv tables written before schema 2 (their settled verdict)
CURVE_PANELS = {"success_rate": "success rate", "settled_success_rate": "settled success rate",
                "last_step_success_rate": "last-step success rate (secondary)",
                "return": "return", "final_latent_distance": "final latent distance",
                "tool_drift_mm_mean": "tool drift (mm, mean of episode max)",
                "first_attempt_success_rate": "first-attempt success rate"}


def learning_curve_plot(curves: pd.DataFrame, path: Path) -> Path:
    """Success rate and return (and the optional metrics the runs record) against env steps:
    mean over seeds, band +- one std."""
    metrics = [m for m in CURVE_PANELS if f"{m}_mean" in curves.columns]
    columns = min(len(metrics), 3)
    rows = -(-len(metrics) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 3.6 * rows), squeeze=False)
    axes = axes.ravel()
    for j, (run, part) in enumerate(curves.groupby("run", sort=True)):
        part = part.sort_values("env_steps")
        color = PALETTE[j % len(PALETTE)]
        for ax, metric in zip(axes, metrics):
            mean, std = part[f"{metric}_mean"].to_numpy(float), part[f"{metric}_std"].to_numpy(float)
            steps = part["env_steps"].to_numpy(float)
            ax.plot(steps, mean, color=color, label=f"{run} ({int(part['seeds'].max())} seeds)")
            ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.2)
    for ax, metric in zip(axes, metrics):
        ax.set_xlabel("environment steps")
        ax.set_ylabel(CURVE_PANELS[metric])
        ax.grid(alpha=0.3)
        if metric.endswith("success_rate"):
            ax.set_ylim(-0.02, 1.02)
    for ax in axes[len(metrics):]:
        ax.set_visible(False)
    axes[0].legend(fontsize=8)
    fig.suptitle("learning curves (mean over seeds, band: +- 1 std)")
    return _save(fig, path)


def seed_curve_plot(seeds: pd.DataFrame, path: Path) -> Path:
    """Success rate (and the return: the paper's Fig. 5a plots it) against env steps: every seed's curve (thin)
    and their mean (thick), per run."""
    metrics = [m for m in ("success_rate", "first_attempt_success_rate", "return") if m in seeds.columns]
    fig, axes = plt.subplots(1, len(metrics), figsize=(6 * len(metrics), 4), squeeze=False)
    for j, (run, part) in enumerate(seeds.groupby("run", sort=True)):
        color = PALETTE[j % len(PALETTE)]
        for ax, metric in zip(axes[0], metrics):
            for _, one in part.groupby("seed"):
                ax.plot(one["env_steps"], one[metric], color=color, alpha=0.35, linewidth=1)
            mean = part.groupby("env_steps")[metric].mean()
            ax.plot(mean.index, mean.to_numpy(), color=color, linewidth=2.5,
                    label=f"{run} (mean of {part['seed'].nunique()} seeds)")
    for ax, metric in zip(axes[0], metrics):
        ax.set_xlabel("environment steps")
        ax.set_ylabel(CURVE_PANELS[metric])
        if metric != "return":
            ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"{' and '.join(CURVE_PANELS[m] for m in metrics)} against env steps: each seed (thin) and the "
                 "mean (thick)")
    return _save(fig, path)


__all__ = ["grouped_rate_bars", "attempt_bars", "histograms", "learning_curve_plot", "seed_curve_plot"]
