"""One row per ``hingelab eval low`` folder: the success verdict (and the secondary one), Wilson 95%, drift, truth.

    python -m hingelab.analysis.low_level_summary OUT EVAL_DIR...

reads each EVAL_DIR/regions.csv (its ``all`` row and the three goal regions) and writes
OUT.csv and OUT.md (``analysis/low-level-ablation/final_policies`` was made this way).
``success`` is ToolShape-v0's verdict, settled over the last 0.5 s; ``success_last_step``
the secondary one-frame verdict. ``regions.csv`` files written before episode schema 2
(``success_rate`` = last step, ``settled_success_rate``) are read under today's names
(``read_regions``), so old and new evaluations give the same columns.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from hingelab.analysis.documents import markdown_table
from hingelab.errors import ConfigError

REGIONS = ("closed", "middle", "open")


VERDICT_COLUMNS = ("successes", "success_rate", "ci_low", "ci_high", "success_and_drift_under_1cm")
NOTE = ("success: ToolShape-v0's verdict, z_bar averaged over the last 0.5 s (10 steps) within the success "
        "threshold, Wilson 95%; success_last_step: the last step's z_bar alone (secondary, not counted).")


def read_regions(path) -> pd.DataFrame:
    """A ``regions.csv`` of ``hingelab eval low`` under today's names, indexed by goal region: an old
    file's (before schema 2) ``settled_*`` columns become the verdict's and its unprefixed ones ``last_step_*``."""
    regions = pd.read_csv(path)
    if "settled_success_rate" in regions.columns and "last_step_success_rate" not in regions.columns:
        renames = {column: f"last_step_{column}" for column in VERDICT_COLUMNS}
        renames |= {f"settled_{column}": column for column in VERDICT_COLUMNS}
        regions = regions.rename(columns=renames)
    return regions.set_index("goal_region")


def summary_row(eval_dir: Path) -> dict:
    path = Path(eval_dir) / "regions.csv"
    if not path.exists():
        raise ConfigError(f"{path} does not exist; give folders written by `hingelab eval low`")
    regions = read_regions(path)
    a = regions.loc["all"]
    return {"policy": Path(eval_dir).name, "episodes": int(a.episodes),
            "success": f"{a.success_rate:.2f} [{a.ci_low:.2f}, {a.ci_high:.2f}]",
            "success_and_drift_under_1cm": round(float(a.success_and_drift_under_1cm), 2),
            "success_closed/middle/open": "/".join(f"{regions.loc[r, 'success_rate']:.2f}"
                                                   for r in REGIONS if r in regions.index),
            "settled_latent_distance": round(float(a.settled_latent_distance), 3),
            "success_last_step": f"{a.last_step_success_rate:.2f} [{a.last_step_ci_low:.2f}, "
                                 f"{a.last_step_ci_high:.2f}]",
            "tip_gap_error_mm_median": round(float(a.tip_gap_error_mm_median), 1),
            "tool_drift_mm_max_median": round(float(a.tool_drift_mm_max_median), 1)}


def write_summary(out: Path, eval_dirs) -> pd.DataFrame:
    table = pd.DataFrame([summary_row(d) for d in eval_dirs])
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out.with_suffix(".csv"), index=False)
    out.with_suffix(".md").write_text(NOTE + "\n\n" + markdown_table(table) + "\n")
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="output path without suffix (OUT.csv and OUT.md are written)")
    parser.add_argument("eval_dirs", type=Path, nargs="+", help="folders written by hingelab eval low")
    args = parser.parse_args(argv)
    print(write_summary(args.out, args.eval_dirs).to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
