"""One row per ``hingelab eval low`` folder: both success verdicts with Wilson intervals, drift, truth.

    python -m hingelab.analysis.low_level_summary OUT EVAL_DIR...

reads each EVAL_DIR/regions.csv (its ``all`` row and the three goal regions) and writes
OUT.csv and OUT.md (``analysis/low-level-ablation/final_policies`` was made this way).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from hingelab.analysis.documents import markdown_table
from hingelab.errors import ConfigError

REGIONS = ("closed", "middle", "open")


def summary_row(eval_dir: Path) -> dict:
    path = Path(eval_dir) / "regions.csv"
    if not path.exists():
        raise ConfigError(f"{path} does not exist; give folders written by `hingelab eval low`")
    regions = pd.read_csv(path).set_index("goal_region")
    a = regions.loc["all"]
    return {"policy": Path(eval_dir).name, "episodes": int(a.episodes),
            "success_last_step": f"{a.success_rate:.2f} [{a.ci_low:.2f}, {a.ci_high:.2f}]",
            "settled_success": f"{a.settled_success_rate:.2f} [{a.settled_ci_low:.2f}, {a.settled_ci_high:.2f}]",
            "settled_and_drift_under_1cm": round(float(a.settled_success_and_drift_under_1cm), 2),
            "settled_closed/middle/open": "/".join(f"{regions.loc[r, 'settled_success_rate']:.2f}"
                                                   for r in REGIONS if r in regions.index),
            "settled_latent_distance": round(float(a.settled_latent_distance), 3),
            "tip_gap_error_mm_median": round(float(a.tip_gap_error_mm_median), 1),
            "tool_drift_mm_max_median": round(float(a.tool_drift_mm_max_median), 1)}


def write_summary(out: Path, eval_dirs) -> pd.DataFrame:
    table = pd.DataFrame([summary_row(d) for d in eval_dirs])
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out.with_suffix(".csv"), index=False)
    out.with_suffix(".md").write_text(markdown_table(table) + "\n")
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
