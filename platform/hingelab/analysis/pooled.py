"""Pooled success rates over several evaluation folders (``hingelab report --pool DIR...``).

Each folder is what ``hingelab eval low --out DIR`` writes (its ``episodes.csv``: one row per
goal episode), or an ``episodes.csv`` file itself, or an evaluation dataset without one (the
episodes' recorded ``success`` and their ``goal_region`` / ``goal_opening_rad`` metadata; no
drift or tip-gap figures then). Per folder and pooled over the folders of a pool: episodes,
successes, the rate with its Wilson 95% interval (``hingelab.analysis.wilson``), the same
with the tool's largest drift in the hand under 1 cm (``tool_drift_mm_max < 10``), the
last-step verdict where recorded, the median tip-gap error and the median largest drift;
and all of that per goal third (``region``: thirds of the reachable opening range) and per
band of the goal's opening (``goal_opening_rad``; default edges 0.10, 0.18, 0.22 rad).

Which column is the verdict. ``episodes.csv`` files have two layouts:

- old (written before episode schema 2): ``success`` is the last step's verdict and
  ``settled_success`` the settled one (z_bar averaged over the last 0.5 s within the
  threshold). The settled verdict is the task's, so ``settled_success`` is counted.
- new: ``success`` is already the env's settled verdict (no ``settled_success`` column);
  the one-frame verdict, where present, is ``last_step_success``.

The output says per folder which column it counted. Writes ``pooled.md``, ``pooled.csv``
(one row per folder and one ``pooled`` row per pool) and ``by_region.csv`` (the same per goal
third and per opening band) into OUT; ``pooled.md`` names the command and the code version.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.analysis.episode_table import load_dataset_table
from hingelab.analysis.wilson import wilson_interval
from hingelab.episodes import EpisodeFile
from hingelab.episodes.dataset import open_dataset
from hingelab.errors import ConfigError
from hingelab.provenance import git_commit

DEFAULT_BAND_EDGES = (0.10, 0.18, 0.22)  # rad: the bands analysis/low-level-experts/README.md reads
THIRDS = ("closed", "middle", "open")  # hingelab.rollouts.low_level_goals.REGIONS
DRIFT_LIMIT_MM = 10.0  # "the tool < 1 cm": its largest drift in the hand over the episode
EPISODES_FILE = "episodes.csv"

OLD_LAYOUT = "old"
NEW_LAYOUT = "new"
DATASET_LAYOUT = "dataset"


@dataclass
class EvalFolder:
    """One evaluation's episodes, normalized: ``verdict`` (the counted success), ``last_step``,
    ``region``, ``goal_opening_rad``, ``tool_drift_mm_max``, ``tip_gap_error_mm``."""

    path: Path
    label: str
    layout: str
    verdict_column: str
    episodes: pd.DataFrame

    @property
    def verdict_note(self) -> str:
        if self.layout == OLD_LAYOUT:
            return "settled_success (old layout)"
        if self.layout == NEW_LAYOUT:
            return "success"
        return f"recorded success ({self.verdict_column})"


@dataclass
class PooledReport:
    out: Path
    pooled: pd.DataFrame
    by_region: pd.DataFrame
    markdown: Path
    files: list[Path] = field(default_factory=list)


def _bool_column(values: pd.Series, where: str) -> pd.Series:
    """True/False/1/0/"True"/"False" as a nullable boolean column."""
    if values.dtype == bool:
        return values.astype("boolean")
    mapped = values.map(lambda v: {"true": True, "false": False, "1": True, "0": False,
                                   "1.0": True, "0.0": False}.get(str(v).strip().lower(), pd.NA)
                        if not (isinstance(v, float) and math.isnan(v)) else pd.NA)
    bad = values.notna() & mapped.isna()
    if bad.any():
        raise ConfigError(f"{where} has values that are not booleans: {sorted(set(values[bad].astype(str)))[:3]}")
    return mapped.astype("boolean")


def _from_episodes_csv(csv: Path, label: str) -> EvalFolder:
    try:
        raw = pd.read_csv(csv)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{csv} cannot be read as a CSV table ({exc})") from exc
    if "settled_success" in raw.columns:
        layout, verdict, last_step = OLD_LAYOUT, "settled_success", "success"
    else:
        layout, verdict, last_step = NEW_LAYOUT, "success", "last_step_success"
    missing = [c for c in (verdict, "goal_opening_rad") if c not in raw.columns]
    if missing:
        raise ConfigError(f"{csv} lacks the column(s) {', '.join(missing)}; give episodes.csv files written by "
                          "`hingelab eval low` (one row per goal episode)")
    if raw.empty:
        raise ConfigError(f"{csv} has no episodes")
    table = pd.DataFrame({
        "verdict": _bool_column(raw[verdict], f"{csv} column {verdict}"),
        "last_step": (_bool_column(raw[last_step], f"{csv} column {last_step}") if last_step in raw.columns
                      else pd.Series(pd.NA, index=raw.index, dtype="boolean")),
        "region": raw["region"].astype("string") if "region" in raw.columns else pd.NA,
        "goal_opening_rad": pd.to_numeric(raw["goal_opening_rad"], errors="coerce"),
        "tool_drift_mm_max": pd.to_numeric(raw.get("tool_drift_mm_max", np.nan), errors="coerce"),
        "tip_gap_error_mm": pd.to_numeric(raw.get("tip_gap_error_mm", np.nan), errors="coerce"),
    })
    if table["verdict"].isna().any():
        raise ConfigError(f"{csv}: {int(table['verdict'].isna().sum())} episode(s) without a {verdict} value")
    return EvalFolder(path=csv.parent, label=label, layout=layout, verdict_column=verdict, episodes=table)


def _from_dataset(root: Path, label: str) -> EvalFolder:
    """An evaluation dataset without episodes.csv: the recorded success and goal metadata."""
    index = load_dataset_table(root)  # refuses a missing, empty or outcome-less dataset with one line
    versions = pd.to_numeric(index.get("schema_version", pd.Series(1, index=index.index)), errors="coerce")
    verdicts = index.get("success_verdict", pd.Series(pd.NA, index=index.index))
    tasks = index.get("task", pd.Series("", index=index.index)).astype("string").fillna("")
    old_shape = (versions.fillna(1) < 2) & verdicts.isna() & tasks.str.contains("ToolShape")
    if old_shape.any():
        raise ConfigError(f"{root}: {int(old_shape.sum())} ToolShape-v0 episode(s) of episode schema 1 record the "
                          "last step's verdict as `success`, not the settled one; pool the folder's episodes.csv "
                          "(written by `hingelab eval low`) instead")
    regions, openings = [], []
    for path in open_dataset(root).paths():
        with EpisodeFile(path) as episode_file:
            meta = episode_file.raw_metadata().get("episode", {})
        regions.append(meta.get("goal_region", pd.NA) or pd.NA)
        try:
            openings.append(float(meta.get("goal_opening_rad", "nan")))
        except ValueError:
            openings.append(np.nan)
    named = sorted(set(verdicts.dropna().astype(str)))
    table = pd.DataFrame({
        "verdict": index["success"].astype("boolean").to_numpy(),
        "last_step": (index["last_step_success"].astype("boolean").to_numpy() if "last_step_success" in index
                      else pd.array([pd.NA] * len(index), dtype="boolean")),
        "region": pd.array(regions, dtype="string"),
        "goal_opening_rad": openings,
        "tool_drift_mm_max": np.nan,
        "tip_gap_error_mm": np.nan,
    })
    table = table[table["verdict"].notna()].reset_index(drop=True)
    return EvalFolder(path=root, label=label, layout=DATASET_LAYOUT,
                      verdict_column=", ".join(named) if named else "the only verdict recorded", episodes=table)


def load_folder(path, label: str | None = None) -> EvalFolder:
    """One evaluation folder (or its episodes.csv); a missing or unreadable one is a ConfigError naming it."""
    path = Path(path)
    label = label or str(path)
    if not path.exists():
        raise ConfigError(f"{path} does not exist; give folders written by `hingelab eval low` (with episodes.csv)")
    if path.is_file():
        return _from_episodes_csv(path, label)
    if (path / EPISODES_FILE).exists():
        return _from_episodes_csv(path / EPISODES_FILE, label)
    if (path / "dataset.json").exists():
        return _from_dataset(path, label)
    raise ConfigError(f"{path} has no {EPISODES_FILE} and is not a dataset (no dataset.json); give folders written "
                      "by `hingelab eval low`")


def band_labels(edges) -> list[str]:
    edges = list(edges)
    return ([f"< {edges[0]:.2f}"] + [f"{a:.2f}-{b:.2f}" for a, b in zip(edges[:-1], edges[1:])]
            + [f">= {edges[-1]:.2f}"])


def opening_bands(openings: pd.Series, edges) -> pd.Series:
    """Each goal's band: ``< e0``, ``e0-e1``, ..., ``>= en`` (left-closed); NaN openings are NA."""
    labels = band_labels(edges)
    values = pd.to_numeric(openings, errors="coerce").to_numpy(dtype=float)
    index = np.searchsorted(np.asarray(edges, float), values, side="right")
    out = pd.Series([labels[i] if not math.isnan(v) else pd.NA for i, v in zip(index, values)],
                    index=openings.index, dtype="string")
    return out


def _rate(k: int, n: int) -> tuple[float, float, float]:
    low, high = wilson_interval(np.array([k]), np.array([n]))
    return (k / n if n else float("nan")), float(low[0]), float(high[0])


def count(episodes: pd.DataFrame) -> dict:
    """Counts and rates of one group of normalized episodes (``EvalFolder.episodes`` rows)."""
    n = len(episodes)
    verdict = episodes["verdict"].astype(bool)
    k = int(verdict.sum())
    rate, low, high = _rate(k, n)
    row = {"episodes": n, "successes": k, "success_rate": rate, "ci_low": low, "ci_high": high}
    drift = episodes["tool_drift_mm_max"]
    if n and drift.notna().all():
        kd = int((verdict & (drift < DRIFT_LIMIT_MM)).sum())
        rate_d, low_d, high_d = _rate(kd, n)
        row |= {"successes_drift_under_1cm": kd, "success_drift_under_1cm_rate": rate_d,
                "drift_ci_low": low_d, "drift_ci_high": high_d}
    else:
        row |= {"successes_drift_under_1cm": pd.NA, "success_drift_under_1cm_rate": np.nan,
                "drift_ci_low": np.nan, "drift_ci_high": np.nan}
    last = episodes["last_step"]
    if n and last.notna().all():
        row |= {"last_step_successes": int(last.astype(bool).sum()),
                "last_step_success_rate": float(last.astype(bool).mean())}
    else:
        row |= {"last_step_successes": pd.NA, "last_step_success_rate": np.nan}
    row |= {"tip_gap_error_mm_median": float(episodes["tip_gap_error_mm"].median()) if n else np.nan,
            "tool_drift_mm_max_median": float(drift.median()) if n else np.nan}
    return row


def pool_name(paths) -> str:
    """A pool's default name from its folders' names: ``experts_goals_seed3-5`` for
    ``.../experts_goals_seed3``, ``...4``, ``...5``; else the names joined with ``+``."""
    names = [Path(p).name if Path(p).name != EPISODES_FILE else Path(p).parent.name for p in paths]
    matches = [re.fullmatch(r"(.*?)(\d+)", name) for name in names]
    if len(names) > 1 and all(matches) and len({m.group(1) for m in matches}) == 1:
        numbers = sorted({int(m.group(2)) for m in matches})
        if numbers == list(range(numbers[0], numbers[-1] + 1)) and len(numbers) > 2:
            return f"{matches[0].group(1)}{numbers[0]}-{numbers[-1]}"
        return matches[0].group(1) + ",".join(str(v) for v in numbers)
    return "+".join(dict.fromkeys(names))


def pooled_tables(pools, edges=DEFAULT_BAND_EDGES) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``pools``: [(name, [EvalFolder, ...]), ...] -> (pooled, by_region) tables.

    ``pooled``: one row per folder and one ``pooled`` row per pool of more than one folder.
    ``by_region``: the same per goal third (``split`` = ``goal_third``) and per opening band
    (``split`` = ``opening_band``)."""
    edges = tuple(float(e) for e in edges)
    if list(edges) != sorted(set(edges)):
        raise ConfigError(f"--bands must be increasing opening edges in rad, not {list(edges)}")
    overall, regions = [], []
    for name, folders in pools:
        groups = [(f.label, f.layout, f.verdict_note, f.episodes) for f in folders]
        if len(folders) > 1:
            notes = "; ".join(dict.fromkeys(f.verdict_note for f in folders))
            groups.append(("pooled", "+".join(dict.fromkeys(f.layout for f in folders)), notes,
                           pd.concat([f.episodes for f in folders], ignore_index=True)))
        for label, layout, note, episodes in groups:
            base = {"pool": name, "folder": label, "layout": layout, "verdict": note}
            overall.append(base | count(episodes))
            thirds = episodes["region"].astype("string")
            for third in [*THIRDS, *sorted(set(thirds.dropna()) - set(THIRDS))]:
                part = episodes[(thirds == third).fillna(False).to_numpy()]
                if len(part):
                    regions.append(base | {"split": "goal_third", "region": third} | count(part))
            bands = opening_bands(episodes["goal_opening_rad"], edges)
            for band in band_labels(edges):
                part = episodes[(bands == band).fillna(False).to_numpy()]
                regions.append(base | {"split": "opening_band", "region": band} | count(part))
    return pd.DataFrame(overall), pd.DataFrame(regions)


def _fmt_rate(k, n, rate, low, high, digits: int = 3) -> str:
    if n == 0:
        return "-"
    if pd.isna(k):
        return "n/a"
    return f"{rate:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}] ({int(k)}/{int(n)})"


def _fmt_short(k, n, rate) -> str:
    if n == 0:
        return "-"
    if pd.isna(k):
        return "n/a"
    return f"{rate:.2f} ({int(k)}/{int(n)})"


def _fmt_number(v, digits: int = 1) -> str:
    return "n/a" if pd.isna(v) else f"{v:.{digits}f}"


def _md_table(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _region_section(by_region: pd.DataFrame, split: str, regions, drift: bool) -> str:
    part = by_region[by_region["split"] == split]
    rows = []
    for (pool, folder), group in part.groupby(["pool", "folder"], sort=False):
        cells = group.set_index("region")
        row = [pool, folder]
        for region in regions:
            if region not in cells.index:
                row.append("-")
                continue
            r = cells.loc[region]
            row.append(_fmt_short(r["successes_drift_under_1cm"], r["episodes"], r["success_drift_under_1cm_rate"])
                       if drift else _fmt_short(r["successes"], r["episodes"], r["success_rate"]))
        rows.append(row)
    return _md_table(["pool", "folder", *regions], rows)


def render_markdown(pooled: pd.DataFrame, by_region: pd.DataFrame, edges, title: str, command: str,
                    version: str) -> str:
    bands = band_labels(edges)
    thirds_present = [t for t in THIRDS if t in set(by_region.loc[by_region["split"] == "goal_third", "region"])]
    extra = sorted(set(by_region.loc[by_region["split"] == "goal_third", "region"]) - set(THIRDS))
    overall_rows = [[r.pool, r.folder, r.verdict, r.episodes,
                     _fmt_rate(r.successes, r.episodes, r.success_rate, r.ci_low, r.ci_high),
                     _fmt_rate(r.successes_drift_under_1cm, r.episodes, r.success_drift_under_1cm_rate,
                               r.drift_ci_low, r.drift_ci_high),
                     _fmt_number(r.last_step_success_rate, 3), _fmt_number(r.tip_gap_error_mm_median),
                     _fmt_number(r.tool_drift_mm_max_median)] for r in pooled.itertuples()]
    parts = [
        f"# {title}",
        "",
        f"Made by `{command}` (hingelab.analysis.pooled) with the code at {version}. Rates with Wilson 95% "
        "intervals and (successes/episodes). \"verdict counted\" names the column counted as success: "
        "episodes.csv files of the old layout (their `success` is the last step's verdict) are counted by "
        "`settled_success` (\"settled_success (old layout)\"), files of the new layout by `success` (already the "
        "settled verdict: the smoothed latent averaged over the last 0.5 s within the threshold). \"tool < 1 cm\": "
        f"the tool's largest drift in the hand over the episode under {DRIFT_LIMIT_MM:g} mm "
        "(`tool_drift_mm_max`). \"pooled\": all episodes of the pool's folders together. Medians are over "
        "episodes. Tables: `pooled.csv` (these rows), `by_region.csv` (per goal third and opening band).",
        "",
        "## Overall",
        "",
        _md_table(["pool", "folder", "verdict counted", "episodes", "success", "success, tool < 1 cm",
                   "last-step success", "median tip-gap error (mm)", "median largest drift (mm)"], overall_rows),
        "",
        "## Success with the tool < 1 cm, by the goal's opening (rad, `goal_opening_rad`)",
        "",
        _region_section(by_region, "opening_band", bands, drift=True),
        "",
        "## Success, by the goal's opening (rad)",
        "",
        _region_section(by_region, "opening_band", bands, drift=False),
        "",
    ]
    if thirds_present or extra:
        parts += ["## Success with the tool < 1 cm, by goal third (`region`: thirds of the reachable opening range)",
                  "", _region_section(by_region, "goal_third", [*thirds_present, *extra], drift=True), "",
                  "## Success, by goal third", "",
                  _region_section(by_region, "goal_third", [*thirds_present, *extra], drift=False), ""]
    return "\n".join(parts)


def write_pooled(pools, out, edges=DEFAULT_BAND_EDGES, title: str | None = None,
                 command: str = "hingelab report --pool ...") -> PooledReport:
    """Load every folder of ``pools`` ([(name or None, [path, ...]), ...]), write pooled.md, pooled.csv and
    by_region.csv into ``out``; every folder is read (and any error raised) before anything is written."""
    if not pools:
        raise ConfigError("give at least one --pool DIR... to pool")
    loaded = []
    for name, paths in pools:
        paths = list(paths)
        if not paths:
            raise ConfigError("a --pool needs at least one folder")
        loaded.append((name or pool_name(paths), [load_folder(p) for p in paths]))
    names = [name for name, _ in loaded]
    if len(set(names)) != len(names):
        raise ConfigError(f"two pools have the same name ({', '.join(names)}); name them with --pool-name")
    pooled, by_region = pooled_tables(loaded, edges)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    title = title or "Pooled success: " + ", ".join(names)
    files = [out / "pooled.csv", out / "by_region.csv", out / "pooled.md"]
    pooled.to_csv(files[0], index=False)
    by_region.to_csv(files[1], index=False)
    files[2].write_text(render_markdown(pooled, by_region, edges, title, command, git_commit()) + "\n")
    return PooledReport(out=out, pooled=pooled, by_region=by_region, markdown=files[2], files=files)


__all__ = ["write_pooled", "pooled_tables", "load_folder", "count", "pool_name", "band_labels", "opening_bands",
           "EvalFolder", "PooledReport", "DEFAULT_BAND_EDGES", "DRIFT_LIMIT_MM"]
