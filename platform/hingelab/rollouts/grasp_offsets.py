"""Where the tips hold the object when the lift begins, and whether that separates picks from slips.

A check that can fail, on datasets ``hingelab eval high`` wrote (``/sim/privileged`` and ``/step``): for
each episode, the step the lift begins (the first step whose commanded hand velocity along the hand's x
axis, ToolPick-v0's action[2], exceeds ``LIFT_COMMAND`` after one below ``-LIFT_COMMAND``: the descent,
then the lift), and there the tips' midpoint minus the object's centre in the hand_base frame (mm; the
frame ``/sim/privileged`` records). The hand's y axis is the tips' closing direction (checked per episode:
the larger component of tip_a - tip_b), x the lift, so z is across both: how far off the object's middle
the jaws close along their width.

The verdict compares them with a reference, the demonstrator's first-attempt picks (e.g. ``eval high
--baseline scripted-observed`` on the same seeds): per axis, the episodes whose offset lies inside the range
at which the reference picked and those outside it, and how often each group failed. The grasp pose
explains the failures when those outside fail at least twice as often as those inside (and account for at
least as many failures); if the failures sit inside the reference's range, it does not, and the table says so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.episodes.dataset import open_dataset
from hingelab.errors import ConfigError
from hingelab.rollouts.reward_diagnostic import write_tables

LIFT_COMMAND = 0.3  # action units of the hand's x velocity: the scripted lift commands 0.5, its descent -0.5 to -1
MIN_REFERENCE_PICKS = 5
MIN_FAILURES = 3  # lifted failures below which a verdict would rest on one or two episodes
AXES = ("x", "y", "z")
TOPICS = ["/sim/privileged", "/step"]


def lift_step(actions: np.ndarray) -> int | None:
    """The first step whose action[2] exceeds ``LIFT_COMMAND`` after a step below ``-LIFT_COMMAND``; None
    when the episode never descended and lifted."""
    x = np.asarray(actions, float)[:, 2]
    descending = np.flatnonzero(x < -LIFT_COMMAND)
    if not len(descending):
        return None
    after = np.flatnonzero(x[descending[0]:] > LIFT_COMMAND)
    return int(descending[0] + after[0]) if len(after) else None


def read_episodes(root, command: str):
    """(index, episode, lift step or None) for each episode of the dataset ``root``; one line naming
    ``command`` for an episode without the simulator's state."""
    dataset = open_dataset(root)
    for i, path in enumerate(dataset.paths()):
        episode = dataset.read(i, topics=TOPICS)
        if not {"/sim/privileged", "/step"} <= set(episode.topics):
            raise ConfigError(f"{path}: no /sim/privileged or /step topic; {command} reads ToolPick-v0 episodes "
                              "with the simulator's state (eval high, training rollouts)")
        yield i, episode, lift_step(episode.topics["/step"]["action"])


def grasp_at(privileged: dict, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tips and the object's centre at step ``t`` (hand_base frame, m)."""
    return tuple(np.asarray(privileged[key][t], float) for key in ("tip_a", "tip_b", "object_position"))


def episode_rows(root) -> list[dict]:
    """One row per episode of the dataset ``root``: its set, outcome and the grasp offset at the lift."""
    index = open_dataset(root).index
    rows = []
    for i, episode, t in read_episodes(root, "diagnose grasp"):
        meta, privileged = episode.metadata, episode.topics["/sim/privileged"]
        row = {"dataset": Path(root).name, "policy": meta.get("policy", ""), "object": meta.get("object", ""),
               "size_m": float(meta.get("object_size", "nan")), "episode": i, "seed": int(meta.get("seed", -1)),
               "first_attempt_success": str(meta.get("first_attempt_success")) == "True",
               "failure_reason": failure_reason(index, i),
               "lift_step": -1 if t is None else t}
        if t is None:
            row.update({f"offset_{a}_mm": float("nan") for a in AXES} | {"closing_axis": "", "hinge_rad": float("nan")})
        else:
            a, b, obj = grasp_at(privileged, t)
            offset = 1000 * ((a + b) / 2 - obj)
            row.update({f"offset_{ax}_mm": float(v) for ax, v in zip(AXES, offset)})
            row["closing_axis"] = AXES[int(np.argmax(np.abs(a - b)))]
            row["hinge_rad"] = float(privileged["hinge_angle"][t])
        rows.append(row)
    return rows


def failure_reason(index, i: int) -> str:
    """The i-th episode's failure reason in a dataset's index; "" for none (a success, or not recorded)."""
    value = index["failure_reason"].iloc[i] if "failure_reason" in index else None
    return "" if value is None or pd.isna(value) else str(value)  # None, NaN or pd.NA (a "string" column)


def reference_ranges(reference_rows: list[dict]) -> dict[str, tuple[float, float]]:
    """Per axis, the range of the offsets at which the reference (the demonstrator) picked at its first attempt."""
    picked = [r for r in reference_rows if r["first_attempt_success"] and r["lift_step"] >= 0]
    if len(picked) < MIN_REFERENCE_PICKS:
        raise ConfigError(f"the reference dataset has {len(picked)} first-attempt picks that reached the lift; give "
                          f"one with at least {MIN_REFERENCE_PICKS} (e.g. eval high --baseline scripted-observed)")
    return {ax: (min(r[f"offset_{ax}_mm"] for r in picked), max(r[f"offset_{ax}_mm"] for r in picked))
            for ax in AXES}


def summarize(rows: list[dict], ranges: dict[str, tuple[float, float]]) -> list[dict]:
    """Per dataset and axis: the lifted episodes inside and outside the reference's range of offsets, and how
    many of each failed at the first attempt (the grasp pose explains the failures when those outside fail far
    more often than those inside)."""
    out = []
    for name in dict.fromkeys(r["dataset"] for r in rows):
        mine = [r for r in rows if r["dataset"] == name]
        lifted = [r for r in mine if r["lift_step"] >= 0]
        for ax in AXES:
            low, high = ranges[ax]
            values = np.array([r[f"offset_{ax}_mm"] for r in lifted])
            inside = [low <= r[f"offset_{ax}_mm"] <= high for r in lifted]
            failed = [not r["first_attempt_success"] for r in lifted]
            n_in = sum(inside)
            out.append({"dataset": name, "policy": mine[0]["policy"], "object": mine[0]["object"],
                        "size_m": mine[0]["size_m"], "episodes": len(mine),
                        "first_attempt_successes": sum(r["first_attempt_success"] for r in mine),
                        "not_lifted": len(mine) - len(lifted), "axis": ax,
                        "offset_mean_mm": float(values.mean()) if len(values) else float("nan"),
                        "offset_sd_mm": float(values.std()) if len(values) else float("nan"),
                        "reference_low_mm": low, "reference_high_mm": high,
                        "inside": n_in, "failed_inside": sum(f for f, i in zip(failed, inside) if i),
                        "outside": len(lifted) - n_in,
                        "failed_outside": sum(f for f, i in zip(failed, inside) if not i)})
    return out


def verdict(summary: list[dict], dataset: str) -> str:
    """For one dataset: the axis whose outside episodes fail most often against its inside ones, and whether
    that explains its failures."""
    rows = [s for s in summary if s["dataset"] == dataset]
    if not any(s["failed_inside"] + s["failed_outside"] for s in rows):
        failures = rows[0]["episodes"] - rows[0]["first_attempt_successes"]
        return f"{dataset}: no lifted episode failed ({failures} failed at the first attempt before any lift)"

    lifted_failures = rows[0]["failed_inside"] + rows[0]["failed_outside"]
    if lifted_failures < MIN_FAILURES:
        return f"{dataset}: {lifted_failures} lifted failures, too few to tell (at least {MIN_FAILURES})"

    def rate(failed, n):
        return failed / n if n else 0.0

    best = max(rows, key=lambda s: rate(s["failed_outside"], s["outside"]) - rate(s["failed_inside"], s["inside"]))
    rate_in, rate_out = rate(best["failed_inside"], best["inside"]), rate(best["failed_outside"], best["outside"])
    failed_out = best["failed_outside"]
    explains = failed_out > 0 and rate_out >= 2 * rate_in and failed_out >= best["failed_inside"]
    side = "explains its failures" if explains else "does not explain its failures"
    return (f"{dataset}: along {best['axis']}, the lifted episodes outside the reference's range failed "
            f"{best['failed_outside']} of {best['outside']}, those inside {best['failed_inside']} of {best['inside']}: "
            f"the grasp pose {side}")


def write_report(rows: list[dict], summary: list[dict], out, command: str, reference: str) -> Path:
    """``episodes.csv``, ``summary.csv`` and ``grasp_offsets.md`` under ``out``; the markdown's path."""
    out = write_tables(out, {"episodes.csv": rows, "summary.csv": summary})
    lines = ["# Where the tips hold the object when the lift begins", "",
             f"Made by `{command}` (`hingelab.rollouts.grasp_offsets`). The tips' midpoint minus the object's "
             "centre at the first lift command, in the hand_base frame (mm): y is the tips' closing direction, x "
             "the lift, z across both (how far off the object's middle the jaws close along their width). The "
             f"reference range is where `{reference}` picked at its first attempt; per axis, the lifted episodes "
             "inside and outside it and their first-attempt failures.", "",
             "| dataset | policy | object | size (cm) | first-attempt picks | not lifted | axis | offset, mean ± sd "
             "(mm) | reference range (mm) | failed inside | failed outside |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        lines.append(f"| {s['dataset']} | {s['policy']} | {s['object']} | {100 * s['size_m']:g} | "
                     f"{s['first_attempt_successes']}/{s['episodes']} | {s['not_lifted']} | {s['axis']} | "
                     f"{s['offset_mean_mm']:.2f} ± {s['offset_sd_mm']:.2f} | {s['reference_low_mm']:.2f} to "
                     f"{s['reference_high_mm']:.2f} | {s['failed_inside']} of {s['inside']} | "
                     f"{s['failed_outside']} of {s['outside']} |")
    failures = [r for r in rows if not r["first_attempt_success"]]
    if failures:
        lines += ["", "Failures:", "", "| dataset | episode | seed | reason | lift step | offset x, y, z (mm) |",
                  "|---|---|---|---|---|---|"]
        for r in failures:
            offsets = ", ".join(f"{r[f'offset_{ax}_mm']:.2f}" for ax in AXES) if r["lift_step"] >= 0 else "no lift"
            lines.append(f"| {r['dataset']} | {r['episode']} | {r['seed']} | {r['failure_reason'] or '-'} | "
                         f"{r['lift_step'] if r['lift_step'] >= 0 else '-'} | {offsets} |")
    names = dict.fromkeys(r["dataset"] for r in rows)
    lines += ["", "Verdicts:", ""] + [f"- {verdict(summary, name)}." for name in names]
    lines.append("")
    path = Path(out) / "grasp_offsets.md"
    path.write_text("\n".join(lines))
    return path
