"""The pick table (paper Fig. 7, in simulation): ``hingelab report --picks DIR... --out OUT``.

Each DIR is what ``hingelab eval high --out DIR`` writes: its ``episodes.csv`` (one row per
episode: ``success`` within the 200 steps, ``first_attempt_success``, ``attempts``,
``failure_reason``) and its dataset card (policy, low level, object, size, seed). One row per
folder (a policy on one shape and size) with the first-attempt and overall success and their
Wilson 95% intervals, the mean attempts and the failure reasons; then, per policy and low level,
a pooled row over its folders and the lowest set. Writes ``picks.md`` and ``picks.csv``;
``picks.md`` names the command and the code version.

Where two or more policies ran the same episodes (the same object, size and episode seed: ``eval high`` at
the same ``--seed``), the episodes pair: ``paired.csv`` and a section of ``picks.md`` count, for every two
policies, the shared episodes each picked at the first attempt and the other did not, with the exact
two-sided sign test on those (the episodes both or neither picked say nothing about which is better).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.analysis.documents import markdown_table
from hingelab.analysis.wilson import wilson_interval
from hingelab.errors import ConfigError
from hingelab.provenance import code_version

# the failure reasons of ToolPick-v0 episodes (hingelab.rollouts.high_level.FailureReasonWrapper)
FAILURE_REASONS = ("divergence", "no_camera_cloud", "no_object_estimate", "tool_drop", "slip", "table_collision",
                   "missed_grasp", "timeout")


def pick_rates(episodes: pd.DataFrame) -> dict:
    """Episodes of ToolPick-v0 (``success``, ``first_attempt_success``, ``attempts``, ``failure_reason``):
    success and first-attempt success with Wilson 95% intervals, mean attempts, each failure reason's count."""
    n = len(episodes)
    row: dict = {"episodes": n}
    for verdict, prefix in (("success", ""), ("first_attempt_success", "first_attempt_")):
        k = int(episodes[verdict].sum())
        low, high = wilson_interval(np.array([k]), np.array([n]))
        row |= {f"{prefix}successes": k, f"{prefix}success_rate": k / n if n else float("nan"),
                f"{prefix}ci_low": float(low[0]), f"{prefix}ci_high": float(high[0])}
    row["mean_attempts"] = float(episodes["attempts"].mean()) if n else float("nan")
    for reason in FAILURE_REASONS:
        row[f"failures_{reason}"] = int((episodes["failure_reason"].astype(object).fillna("") == reason).sum())
    return row


def policy_label(config: dict) -> str:
    """A baseline's name, or a checkpoint's file name (with its run folder)."""
    policy = str(config.get("policy", "?"))
    if policy in ("heuristic", "scripted", "random"):
        return policy
    path = Path(policy)
    return f"{path.parent.name}/{path.name}" if path.parent.name else path.name


def read_folder(folder) -> tuple[dict, pd.DataFrame]:
    """(the card's config, episodes.csv) of one ``eval high`` folder; a clear error if it is not one."""
    folder = Path(folder)
    card, episodes = folder / "dataset.json", folder / "episodes.csv"
    if not card.is_file() or not episodes.is_file():
        raise ConfigError(f"{folder} is not a `hingelab eval high --out` folder (it needs dataset.json and "
                          "episodes.csv)")
    config = json.loads(card.read_text()).get("config", {})
    frame = pd.read_csv(episodes)
    missing = {"success", "first_attempt_success", "attempts", "failure_reason"} - set(frame.columns)
    if missing or "object" not in config or "size" not in config:
        raise ConfigError(f"{episodes} lacks {sorted(missing) or 'the object and size in its card'}; is it from "
                          "`hingelab eval high`?")
    return config, frame


def perception_label(config: dict) -> str:
    """Where the tool clouds came from, and the tool position the policy observed where it was not the tracked one
    (``eval high --tool-position anchored``): "synthesized", "camera, anchored tool position", ..."""
    label = str(config.get("perception", "synthesized"))
    position = config.get("tool_position", "observed")
    return label if position == "observed" else f"{label}, {position} tool position"


def _read_all(folders) -> list[tuple[dict, pd.DataFrame, object]]:
    """(config, episodes, the card's seed) of each folder, read once for both tables."""
    read = []
    for folder in folders:
        config, frame = read_folder(folder)
        read.append((config, frame, json.loads((Path(folder) / "dataset.json").read_text()).get("seed")))
    return read


def pick_table(folders) -> pd.DataFrame:
    """One row per folder, then per (policy, low level, perception) a pooled row (``object`` = "all")."""
    return _pick_table(_read_all(folders))


def _pick_table(read) -> pd.DataFrame:
    rows, frames = [], []
    for config, frame, seed in read:
        key = {"policy": policy_label(config), "low_level": str(config.get("low_level", "?")),
               "perception": perception_label(config)}
        rows.append({**key, "object": str(config["object"]), "size_cm": round(100 * float(config["size"]), 3),
                     "episodes": len(frame), "seed": seed, **pick_rates(frame)})
        frames.append(frame.assign(**key, _set_rate=rows[-1]["success_rate"],
                                   _set_first=rows[-1]["first_attempt_success_rate"]))
    if not rows:
        raise ConfigError("give at least one `hingelab eval high` folder to --picks")
    # each policy's sets together, in the order its first folder came (the folders' names sort otherwise:
    # learned_cube, learned_privileged_cube, learned_sphere)
    keys = ("policy", "low_level", "perception")
    order = {key: i for i, key in reversed(list(enumerate(tuple(r[k] for k in keys) for r in rows)))}
    rows.sort(key=lambda r: (order[tuple(r[k] for k in keys)], r["object"], r["size_cm"]))
    pooled = []
    for (policy, low_level, perception), part in pd.concat(frames).groupby(list(keys), sort=False):
        pooled.append({"policy": policy, "low_level": low_level, "perception": perception, "object": "all",
                       "size_cm": float("nan"),
                       "episodes": len(part), "seed": None, **pick_rates(part),
                       "lowest_set_success_rate": float(part["_set_rate"].min()),
                       "lowest_set_first_attempt_success_rate": float(part["_set_first"].min())})
    return pd.concat([pd.DataFrame(rows), pd.DataFrame(pooled)], ignore_index=True)


def sign_test_p(wins: int, losses: int) -> float:
    """Exact two-sided sign test: the chance of a split at least this uneven among ``wins + losses`` fair coins."""
    n, k = wins + losses, min(wins, losses)
    if n == 0:
        return 1.0
    return min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n)


def paired_table(folders) -> pd.DataFrame:
    """For every two policies (in the order their first folders came), their shared episodes (object, size and
    episode seed) at the first attempt: both picked, only the first, only the second, neither, and the sign
    test's p on the discordant ones. Empty when fewer than two policies share an episode."""
    return _paired_table(_read_all(folders))


def _paired_table(read) -> pd.DataFrame:
    outcomes: dict[str, dict] = {}
    for config, frame, _ in read:
        label = " / ".join((policy_label(config), str(config.get("low_level", "?")), perception_label(config)))
        if "seed" not in frame.columns:
            continue
        episodes = outcomes.setdefault(label, {})
        for seed, success in zip(frame["seed"], frame["first_attempt_success"]):
            episodes[(str(config["object"]), round(float(config["size"]), 6), int(seed))] = bool(success)
    rows = []
    labels = list(outcomes)
    for i, a in enumerate(labels):
        for b in labels[i + 1:]:
            shared = outcomes[a].keys() & outcomes[b].keys()
            if not shared:
                continue
            pairs = [(outcomes[a][k], outcomes[b][k]) for k in shared]
            a_only = sum(x and not y for x, y in pairs)
            b_only = sum(y and not x for x, y in pairs)
            rows.append({"policy_a": a, "policy_b": b, "shared_episodes": len(pairs),
                         "both": sum(x and y for x, y in pairs), "a_only": a_only, "b_only": b_only,
                         "neither": sum(not x and not y for x, y in pairs),
                         "sign_test_p": sign_test_p(a_only, b_only)})
    return pd.DataFrame(rows, columns=["policy_a", "policy_b", "shared_episodes", "both", "a_only", "b_only",
                                       "neither", "sign_test_p"])


def write_picks(folders, out, command: str) -> pd.DataFrame:
    read = _read_all(folders)
    table, paired = _pick_table(read), _paired_table(read)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "picks.csv", index=False)
    shown = table[["policy", "low_level", "perception", "object", "size_cm", "episodes", "first_attempt_successes",
                   "first_attempt_success_rate", "first_attempt_ci_low", "first_attempt_ci_high", "successes",
                   "success_rate", "ci_low", "ci_high", "mean_attempts"]]
    failures = table[["policy", "low_level", "perception", "object", "size_cm",
                      *[f"failures_{r}" for r in FAILURE_REASONS]]]
    version = code_version()
    paired_text = ""
    if len(paired):
        paired.to_csv(out / "paired.csv", index=False)
        paired_text = ("\n\n## Paired\n\nEvery two policies on the episodes they share (object, size, episode "
                       "seed), at the first attempt: picked by both, by a only, by b only, by neither; the exact "
                       "two-sided sign test on a only against b only.\n\n"
                       + markdown_table(paired.round({"sign_test_p": 4})))
    elif (out / "paired.csv").exists():
        (out / "paired.csv").unlink()  # left by an earlier report of other folders
    (out / "picks.md").write_text(
        "# Pick table\n\nPer policy (and the low level under it, and where its tool clouds came from, with the tool "
        "position it observed where that was not the tracked one), shape and size: "
        "success at the first attempt and within the 200 steps (object within 1 cm of the target), Wilson 95% "
        "intervals; `all` pools the policy's sets.\n\n" + markdown_table(shown.round(3)) + "\n\n## Failure reasons\n\n"
        + markdown_table(failures) + paired_text + f"\n\nMade by: `{command}` (hingelab {version['hingelab_version']}, "
        f"commit {version['git_commit']}).\n")
    return table


__all__ = ["FAILURE_REASONS", "paired_table", "pick_rates", "pick_table", "policy_label", "read_folder", "sign_test_p",
           "write_picks"]
