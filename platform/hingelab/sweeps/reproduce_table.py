"""The final table of ``hingelab reproduce``: each reproduced product against the shipped asset, and the
wall time of the stages that made it (``DIR/reproduce.md`` and ``DIR/reproduce.csv``).

- Encoder: the opening R^2 of both checkpoints on the same fresh clouds (``encoder_opening_r2``: in-hand
  poses, 20% removal, ``encoder_noise_m`` of noise, the seed ``encoder_seed``: what ``hingelab bench
  perception``'s encoder row measures), and each checkpoint's own record (R^2 on its held-out clouds).
- Low level: settled success, and settled with the tool moving under 1 cm, on the same reachable goals
  (``eval low`` of both, the reproduced one over the reproduced encoder), Wilson 95% intervals.
- High level: first-attempt and overall pick success pooled over the pick sets, by ``eval high`` on the same
  seeds, of the reproduced phase clone DAgger starts from (``stages/high/base.zip``), the reproduced DAgger
  policy (``stages/high/model.zip``) and the shipped ``high_level.zip``. One stage, ``high``, makes both
  reproduced ones (it fits the clone, then runs DAgger's rounds over it): their rows give its wall time.

Each row quotes both figures; whether a difference is more than the seeds' spread is read from the
intervals (and, for the assets' figures on more episodes, their READMEs).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.analysis.documents import markdown_table
from hingelab.analysis.pick_table import pick_rates
from hingelab.analysis.wilson import wilson_interval
from hingelab.paths import ASSETS_DIR
from hingelab.perception.clouds import CloudRealism, ToolGeometry
from hingelab.perception.encoder import load_encoder
from hingelab.perception.registration import CanonicalRegistration, RegistrationConfig
from hingelab.perception.synthetic_dataset import sample_clouds
from hingelab.perception.train_encoder import register_to_tool_frame
from hingelab.sweeps.reproduce_plan import STAGES_DIR, pick_stage_name

BUILDS = {  # the product, and the stages whose wall time made it
    "encoder": ("clouds", "encoder"),
    "low level": ("low_demos", "low_open", "low_closed", "low_experts"),
    # one stage makes both: the DAgger run fits the clone first (base.zip), then its rounds (model.zip)
    "high level (phase clone DAgger starts from)": ("high",),
    "high level (DAgger, high_level.zip)": ("high",),
}
HIGH_LEVEL_POLICIES = (  # the pick comparison: policy (its picks_ stages), product, checkpoint under DIR/stages
    ("clone", "high level (phase clone DAgger starts from)", "high/base.zip"),
    ("dagger", "high level (DAgger, high_level.zip)", "high/model.zip"),
)


def encoder_opening_r2(path, clouds: int, noise_m: float, seed: int) -> dict:
    """The checkpoint's opening R^2 (its calibration's reader) on ``clouds`` fresh in-hand clouds."""
    encoder = load_encoder(path)
    geometry = ToolGeometry.default()
    registration = CanonicalRegistration(geometry, RegistrationConfig(**encoder.registration_config))
    data = sample_clouds(np.random.default_rng(seed), clouds, geometry, CloudRealism(noise_m, 0.2, 0.0, 0.0),
                         np.deg2rad(30.0), 0.02)
    z = encoder.encode(register_to_tool_frame(data["points"], registration)[0])
    held_out = encoder.calibration.evaluate(z, data["hinge_angle"], geometry.tip_gap_m(data["hinge_angle"]))
    return {"r2_opening": held_out["r2_opening"], "recorded_r2_opening_val":
            (encoder.info.get("metrics") or {}).get("r2_opening_val", float("nan"))}


def rate(k: int, n: int) -> dict:
    low, high = wilson_interval(np.array([k]), np.array([n]))
    return {"value": k / n if n else float("nan"), "ci_low": float(low[0]), "ci_high": float(high[0]), "k": k, "n": n}


def _rate_text(r: dict) -> str:
    return f"{r['value']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}] ({r['k']}/{r['n']})"


def low_level_rates(folder: Path) -> dict[str, dict]:
    episodes = pd.read_csv(Path(folder) / "episodes.csv")
    settled = episodes["success"].astype(bool)
    still = settled & (episodes["tool_drift_mm_max"] < 10)
    return {"settled success": rate(int(settled.sum()), len(episodes)),
            "settled success, tool < 1 cm": rate(int(still.sum()), len(episodes))}


def pick_rates_pooled(folders: list[Path]) -> dict[str, dict]:
    episodes = pd.concat([pd.read_csv(Path(f) / "episodes.csv", dtype={"failure_reason": object}) for f in folders],
                         ignore_index=True)
    pooled = pick_rates(episodes)
    n = pooled["episodes"]
    return {"pick success, first attempt": rate(pooled["first_attempt_successes"], n),
            "pick success within 200 steps": rate(pooled["successes"], n)}


def comparison_rows(out: Path, doc: dict) -> list[dict]:
    out, c = Path(out), doc["comparison"]
    stages = {s["name"]: s for s in doc["stages"]}
    folder = lambda name: out / STAGES_DIR / name  # noqa: E731

    def wall(product: str) -> float:
        return sum(stages[n]["wall_time_s"] or 0.0 for n in BUILDS[product])

    rows = []

    def add(product, measure, reproduced: dict, shipped: dict, reproduced_path, shipped_path, text=_rate_text):
        rows.append({"product": product, "measure": measure,
                     **{f"reproduced_{k}": v for k, v in reproduced.items()},
                     **{f"shipped_{k}": v for k, v in shipped.items()},
                     "reproduced_text": text(reproduced), "shipped_text": text(shipped),
                     "reproduced_path": str(reproduced_path), "shipped_path": str(shipped_path),
                     "stages": " ".join(BUILDS[product]), "wall_time_s": round(wall(product), 1)})

    ours, theirs = folder("encoder") / "encoder.pt", ASSETS_DIR / "checkpoints" / "encoder.pt"
    r2 = {k: encoder_opening_r2(p, c["encoder_clouds"], c["encoder_noise_m"], c["encoder_seed"])
          for k, p in (("reproduced", ours), ("shipped", theirs))}
    number = lambda r: f"{r['value']:.4f}"  # noqa: E731
    add("encoder", f"opening R^2, {c['encoder_clouds']} fresh clouds at {c['encoder_noise_m'] * 1000:g} mm "
        f"(seed {c['encoder_seed']})", {"value": r2["reproduced"]["r2_opening"]},
        {"value": r2["shipped"]["r2_opening"]}, ours, theirs, number)
    add("encoder", "opening R^2 on its own held-out training clouds (the checkpoint's record)",
        {"value": r2["reproduced"]["recorded_r2_opening_val"]}, {"value": r2["shipped"]["recorded_r2_opening_val"]},
        ours, theirs, number)
    low = {k: low_level_rates(folder(f"eval_low_{k}")) for k in ("reproduced", "shipped")}
    for measure in low["reproduced"]:
        add("low level", f"{measure}, {c['low_goals']} goals (seed {c['low_seed']})", low["reproduced"][measure],
            low["shipped"][measure], folder("low_experts") / "low_level_experts.json",
            ASSETS_DIR / "checkpoints" / "low_level_experts.json")
    sets = ", ".join(f"{shape} {size * 100:g} cm" for shape, size in c["pick_sets"])
    picks = {policy: pick_rates_pooled([folder(pick_stage_name(policy, shape, size)) for shape, size in c["pick_sets"]])
             for policy in (*(p for p, _, _ in HIGH_LEVEL_POLICIES), "shipped")}
    for policy, product, checkpoint in HIGH_LEVEL_POLICIES:
        for measure in picks[policy]:
            add(product, f"{measure}, {sets}, {c['pick_episodes']} episodes each (seed {c['pick_seed']})",
                picks[policy][measure], picks["shipped"][measure], out / STAGES_DIR / checkpoint,
                ASSETS_DIR / "checkpoints" / "high_level.zip")
    return rows


def write_tables(out: Path, doc: dict) -> list[dict]:
    """``reproduce.md`` and ``reproduce.csv`` in ``out``; returns the comparison's rows."""
    out = Path(out)
    rows = comparison_rows(out, doc)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with open(out / "reproduce.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
    products = pd.DataFrame([{"product": r["product"], "measure": r["measure"], "reproduced": r["reproduced_text"],
                              "shipped": r["shipped_text"],
                              "its stages' wall time (min)": f"{r['wall_time_s'] / 60:.1f}"} for r in rows])
    stage_rows = pd.DataFrame([{"stage": s["name"], "status": s["status"], "sessions": len(s["sessions"]),
                                "wall time (min)": f"{(s['wall_time_s'] or 0) / 60:.1f}",
                                "command": f"`{s['command_line']}`"} for s in doc["stages"]])
    sessions = doc["sessions"]
    total = sum(s["wall_time_s"] or 0.0 for s in sessions)
    commits = sorted({s.get("git_commit", "?") for s in sessions})
    text = [f"# Reproduction of the shipped set (`hingelab reproduce --scale {doc['scale']}`)", "",
            f"{len(doc['stages'])} stages, {total / 60:.1f} min of wall time over {len(sessions)} session(s) "
            f"(at most {max(s['jobs'] for s in sessions)} stage(s) at a time), code {', '.join(commits)}. "
            "Reproduced and shipped are measured by the same commands on the same seeds; intervals are Wilson 95%.",
            "", "## Each product against the shipped asset", "", markdown_table(products), "",
            "The high level's rows share the `high` stage's wall time: that one DAgger run fits the phase clone "
            "(`stages/high/base.zip`) and then runs its rounds over it (`stages/high/model.zip`).", "",
            "## The stages", "", markdown_table(stage_rows), ""]
    (out / "reproduce.md").write_text("\n".join(text))
    return rows


__all__ = ["BUILDS", "HIGH_LEVEL_POLICIES", "comparison_rows", "encoder_opening_r2", "write_tables"]
