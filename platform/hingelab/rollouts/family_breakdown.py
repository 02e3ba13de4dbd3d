"""Which objects of a family a policy misses: first-attempt picks by kind and drawn size, and the failures' reasons.

A check that can fail, on ``hingelab eval high`` / ``eval picks`` datasets of ``--object family:NAME`` episodes
(each records its draw: kind, size, mass and the kind's parameters, ``schemas.KEY_OBJECT_DRAW``). The pooled
rate of a family hides where it fails; this table splits it by kind and by the drawn size (``--size-bins``,
mm: the pick table's sets span 15 to 25 mm, the families 8 to 30), with Wilson 95% intervals, and counts
each kind's first-attempt failures by reason. The verdict names the size bin and the kind with the lowest
rate and says whether either lies outside the others' intervals, or that no split stands out.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hingelab.analysis.pick_table import policy_label
from hingelab.analysis.wilson import wilson_interval
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import open_dataset
from hingelab.errors import ConfigError
from hingelab.rollouts.grasp_offsets import failure_reason
from hingelab.rollouts.reward_diagnostic import write_tables

SIZE_BINS_MM = (14.0, 20.0, 26.0)  # below, within and above the pick table's 15-25 mm sets
MIN_EPISODES = 10  # a split with fewer episodes is shown, never named by the verdict


def episode_rows(root) -> list[dict]:
    """One row per episode of the dataset ``root``: policy, the drawn object (kind, size, mass, the kind's
    scalar parameters), first-attempt success and the failure reason."""
    dataset = open_dataset(root)
    index = dataset.index
    rows = []
    for i in range(len(dataset)):
        meta = dataset.read(i, topics=[]).metadata
        draw = meta.get(S.KEY_OBJECT_DRAW)
        if not draw:
            raise ConfigError(f"{dataset.paths()[i]}: no object draw; diagnose families reads episodes of "
                              "--object family:NAME (eval high, eval picks with family: sets)")
        record = json.loads(draw)
        params = {f"param_{k}": v for k, v in sorted((record.get("params") or {}).items())
                  if isinstance(v, (int, float, str)) and k not in ("size", "yaw")}
        rows.append({"dataset": Path(root).name, "policy": policy_label(meta), "kind": record["kind"],
                     "size_mm": 1000 * float(record["size_m"]), "mass_g": 1000 * float(record["mass_kg"]),
                     "episode": i, "seed": int(meta.get("seed", -1)),
                     "first_attempt_success": str(meta.get("first_attempt_success")) == "True",
                     "failure_reason": failure_reason(index, i), **params})
    if not rows:
        raise ConfigError(f"{root} holds no episodes")
    return rows


def size_bin(size_mm: float, edges) -> str:
    """The label of the bin ``size_mm`` falls in: "<14", "14-20", ..., ">=26"."""
    edges = list(edges)
    for k, edge in enumerate(edges):
        if size_mm < edge:
            return f"<{edges[0]:g}" if k == 0 else f"{edges[k - 1]:g}-{edge:g}"
    return f">={edges[-1]:g}"


def _rate(group: list[dict]) -> dict:
    k, n = sum(r["first_attempt_success"] for r in group), len(group)
    low, high = wilson_interval(np.array([k]), np.array([n]))
    return {"episodes": n, "first_attempt_successes": k, "first_attempt_success_rate": k / n,
            "ci_low": float(low[0]), "ci_high": float(high[0])}


def summarize(rows: list[dict], edges=SIZE_BINS_MM) -> list[dict]:
    """Per policy: each (kind, size bin), each kind, each size bin and all, with their first-attempt rates."""
    edges = tuple(float(e) for e in edges)
    if not edges or list(edges) != sorted(set(edges)) or edges[0] <= 0:
        raise ConfigError(f"--size-bins takes increasing positive edges in mm, not {list(edges)}")
    bins = [size_bin(0.0, edges)] + [size_bin(e, edges) for e in edges]
    out = []
    for policy in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == policy]
        kinds = sorted(dict.fromkeys(r["kind"] for r in mine))
        for kind in kinds + ["all"]:
            for label in bins + ["all"]:
                group = [r for r in mine if kind in ("all", r["kind"])
                         and label in ("all", size_bin(r["size_mm"], edges))]
                if group:
                    out.append({"policy": policy, "kind": kind, "size_bin_mm": label, **_rate(group)})
    return out


def failure_counts(rows: list[dict]) -> list[dict]:
    """Per policy and kind: the first-attempt failures by reason (a failure whose episode later picked counts
    under ``later_picked``)."""
    out = []
    for policy in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == policy]
        for kind in sorted(dict.fromkeys(r["kind"] for r in mine)):
            failed = [r for r in mine if r["kind"] == kind and not r["first_attempt_success"]]
            reasons: dict[str, int] = {}
            for r in failed:
                reason = r["failure_reason"] or "later_picked"
                reasons[reason] = reasons.get(reason, 0) + 1
            out.append({"policy": policy, "kind": kind, "failures": len(failed),
                        "reasons": "; ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))})
    return out


def verdict(summary: list[dict], policy: str) -> str:
    """The size bin and the kind with the lowest rate, and whether each lies below the rest's interval."""
    mine = [s for s in summary if s["policy"] == policy]
    pooled = next(s for s in mine if s["kind"] == "all" and s["size_bin_mm"] == "all")
    parts = [f"{policy}: {pooled['first_attempt_successes']}/{pooled['episodes']} at the first attempt"]
    for axis, fixed, name in (("size_bin_mm", "kind", "size"), ("kind", "size_bin_mm", "kind")):
        splits = [s for s in mine if s[fixed] == "all" and s[axis] != "all" and s["episodes"] >= MIN_EPISODES]
        if len(splits) < 2:
            continue
        worst = min(splits, key=lambda s: s["first_attempt_success_rate"])
        rest = [s for s in splits if s is not worst]
        k = sum(s["first_attempt_successes"] for s in rest)
        n = sum(s["episodes"] for s in rest)
        low, _ = wilson_interval(np.array([k]), np.array([n]))
        stands_out = worst["ci_high"] < float(low[0])
        parts.append(f"lowest {name} {worst[axis]}: {worst['first_attempt_successes']}/{worst['episodes']} "
                     f"({worst['first_attempt_success_rate']:.2f}) against {k}/{n} ({k / n:.2f}) for the others, "
                     + ("below their interval" if stands_out else "within the noise"))
    return "; ".join(parts)


def write_report(rows: list[dict], summary: list[dict], out, command: str) -> Path:
    """``episodes.csv``, ``summary.csv``, ``failures.csv`` and ``families.md`` under ``out``; the markdown's path."""
    failures = failure_counts(rows)
    fields = sorted({k for r in rows for k in r})  # kinds differ in their parameters: one header for all
    base = [k for k in rows[0] if not k.startswith("param_")]
    header = base + [k for k in fields if k.startswith("param_")]
    out = write_tables(out, {"episodes.csv": [{k: r.get(k, "") for k in header} for r in rows],
                             "summary.csv": summary, "failures.csv": failures})
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    bins = list(dict.fromkeys(s["size_bin_mm"] for s in summary))
    lines = ["# Which objects of a family are missed: first attempt by kind and drawn size", "",
             f"Made by `{command}` (`hingelab.rollouts.family_breakdown`). First-attempt picks per kind and per "
             "bin of the drawn size (mm; the pick table's sets are 15 to 25 mm), k/n and the rate; the Wilson 95% "
             "intervals are in `summary.csv`, each episode's draw in `episodes.csv`.", ""]
    for policy in policies:
        mine = {(s["kind"], s["size_bin_mm"]): s for s in summary if s["policy"] == policy}
        kinds = list(dict.fromkeys(k for k, _ in mine))
        lines += [f"## {policy}", "", "| kind | " + " | ".join(bins) + " |", "|---" * (len(bins) + 1) + "|"]
        for kind in kinds:
            cells = [f"{s['first_attempt_successes']}/{s['episodes']} = {s['first_attempt_success_rate']:.2f}"
                     if (s := mine.get((kind, b))) else "" for b in bins]
            lines.append(f"| {kind} | " + " | ".join(cells) + " |")
        lines += ["", "First-attempt failures by reason:", "", "| kind | failures | reasons |", "|---|---|---|"]
        lines += [f"| {f['kind']} | {f['failures']} | {f['reasons'] or '-'} |" for f in failures
                  if f["policy"] == policy]
        lines += ["", f"Verdict: {verdict(summary, policy)}.", ""]
    path = Path(out) / "families.md"
    path.write_text("\n".join(lines))
    return path


__all__ = ["episode_rows", "summarize", "failure_counts", "verdict", "write_report", "size_bin", "SIZE_BINS_MM"]
