"""``hingelab report`` numbers equal a plain pandas computation over the episodes' metadata.

Two datasets with known outcomes (shapes, sizes, attempts, failure reasons) are written
through ``EpisodeWriter``; the expected rates are computed here with pandas from the
list of facts written, and the Wilson intervals with scipy's independent implementation
(``binomtest(...).proportion_ci(method="wilson")``). The report's CSV files are compared.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binomtest

from hingelab.cli.main import main
from hingelab.episodes import EpisodeWriter, create_dataset

# (source, object, size m, seed, attempt, success, failure_reason, length); one row per episode
HEURISTIC = [
    ("heuristic", "sphere", 0.020, 0, 1, True, None, 4),
    ("heuristic", "sphere", 0.020, 1, 1, True, None, 3),
    ("heuristic", "sphere", 0.020, 2, 2, True, None, 6),  # succeeded at its 2nd attempt (inside the episode)
    ("heuristic", "sphere", 0.020, 3, 3, False, "timeout", 8),
    ("heuristic", "cube", 0.015, 4, 1, False, "drop", 5),
    ("heuristic", "cube", 0.015, 4, 2, True, None, 4),  # trial 4: 2nd episode, 2nd attempt
    ("heuristic", "cube", 0.025, 5, 1, False, "collision", 2),
    ("heuristic", "cube", 0.025, 5, 2, False, "divergence", 2),
    ("heuristic", "cube", 0.025, 5, 3, True, None, 7),
    ("heuristic", "cube", 0.025, 6, 1, True, None, 3),
]
HIGH_LEVEL = [
    ("high_level", "sphere", 0.020, 10, 1, True, None, 5),
    ("high_level", "sphere", 0.020, 11, 1, False, "timeout", 9),
    ("high_level", "tetrahedron", 0.020, 12, 1, False, None, 9),  # failure without a recorded reason
    ("high_level", "tetrahedron", 0.020, 13, 1, True, None, 4),
    ("high_level", "tetrahedron", 0.020, 14, 1, False, "timeout", 9),
]
COLUMNS = ["source", "object", "object_size", "seed", "attempt", "success", "failure_reason", "length"]


def write_known_dataset(root, name, rows):
    create_dataset(root, name=name, source=rows[0][0], config={"name": name}, seed=0)
    returns = []
    for source, obj, size, seed, attempt, success, reason, length in rows:
        with EpisodeWriter(root, source=source, task="tool_pick", object=obj, seed=seed, attempt=attempt,
                           extra_metadata={"object_size": size}) as writer:
            for k in range(length):
                writer.write_step(0.05 * k, latent_z=np.array([k, -k], float),
                                  transition={"observation": np.zeros(3, np.float32), "action": np.zeros(5, np.float32),
                                              "reward": 0.5 * k + (1.0 if success else 0.0), "info": {}})
            writer.set_outcome(success=success, failure_reason=reason)
        returns.append(sum(0.5 * k + (1.0 if success else 0.0) for k in range(length)))
    return returns


def wilson(k, n):
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    return ci.low, ci.high


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    base = tmp_path_factory.mktemp("known")
    facts = []
    for name, rows in (("heur", HEURISTIC), ("high", HIGH_LEVEL)):
        returns = write_known_dataset(base / name, name, rows)
        frame = pd.DataFrame(rows, columns=COLUMNS).assign(dataset=name, **{"return": returns})
        facts.append(frame)
    out = base / "report"
    assert main(["report", str(base / "heur"), str(base / "high"), "--out", str(out)]) == 0
    return out, pd.concat(facts, ignore_index=True)


def check_rates(table, expected, prefix="success_"):
    """table rows match expected (keys, k, n) in order: rate k/n and the Wilson interval."""
    expected = list(expected)
    assert len(table) == len(expected)
    for row, (k, n) in zip(table.itertuples(index=False), expected):
        low, high = wilson(k, n)
        assert getattr(row, f"{prefix}rate") == pytest.approx(k / n, abs=1e-12)
        assert getattr(row, f"{prefix}ci_low") == pytest.approx(low, abs=1e-9)
        assert getattr(row, f"{prefix}ci_high") == pytest.approx(high, abs=1e-9)


def test_success_by_source_object_and_size(report):
    out, facts = report
    for by, csv in ((["source"], "success_by_source.csv"), (["source", "object"], "success_by_object.csv")):
        expected = facts.groupby(by).agg(n=("success", "size"), k=("success", "sum")).reset_index()
        table = pd.read_csv(out / csv)
        assert table[by].astype(str).values.tolist() == expected[by].astype(str).values.tolist()
        assert table["episodes"].tolist() == expected["n"].tolist()
        assert table["successes"].tolist() == expected["k"].tolist()
        check_rates(table, zip(expected["k"], expected["n"]))
    sizes = facts.assign(object_size=(facts["object_size"] * 1000).round(1).map(lambda mm: f"{mm:g} mm"))
    expected = sizes.groupby(["source", "object", "object_size"]).agg(
        n=("success", "size"), k=("success", "sum")).reset_index()
    table = pd.read_csv(out / "success_by_size.csv")
    assert table["object_size"].tolist() == expected["object_size"].tolist()  # e.g. "15 mm", "25 mm"
    check_rates(table, zip(expected["k"], expected["n"]))
    overall = pd.read_csv(out / "overall.csv")
    check_rates(overall, [(facts["success"].sum(), len(facts))])


def test_first_attempt_and_within_k(report):
    out, facts = report
    trials = facts.groupby(["dataset", "source", "object", "object_size", "seed"])
    expected = pd.DataFrame({
        "first": trials.apply(lambda t: bool((t.success & (t.attempt <= 1)).any()), include_groups=False),
        "within2": trials.apply(lambda t: bool((t.success & (t.attempt <= 2)).any()), include_groups=False),
        "any": trials["success"].any(),
    }).reset_index().groupby(["source", "object"]).agg(
        n=("seed", "size"), first=("first", "sum"), within2=("within2", "sum"), any=("any", "sum")).reset_index()
    table = pd.read_csv(out / "attempts.csv")
    assert table["trials"].tolist() == expected["n"].tolist() == [3, 4, 2, 3]  # cube, sphere; sphere, tetrahedron
    check_rates(table, zip(expected["first"], expected["n"]), "first_attempt_")
    check_rates(table, zip(expected["within2"], expected["n"]), "within_2_")
    check_rates(table, zip(expected["any"], expected["n"]), "any_attempt_")
    heuristic_cube = table[(table.source == "heuristic") & (table.object == "cube")].iloc[0]
    # trials 4 (fails, then succeeds at attempt 2), 5 (succeeds at attempt 3), 6 (first attempt)
    assert (heuristic_cube.first_attempt_successes, heuristic_cube.within_2_successes,
            heuristic_cube.within_3_successes, heuristic_cube.any_attempt_successes) == (1, 2, 3, 3)


def test_lengths_returns_and_failure_reasons(report):
    out, facts = report
    table = pd.read_csv(out / "lengths_returns.csv").set_index("source")
    for source, part in facts.groupby("source"):
        assert table.loc[source, "episodes"] == len(part)
        assert table.loc[source, "length_mean"] == pytest.approx(part["length"].mean())
        assert table.loc[source, "length_std"] == pytest.approx(part["length"].std())
        assert table.loc[source, "return_median"] == pytest.approx(part["return"].median())
        assert table.loc[source, "return_max"] == pytest.approx(part["return"].max())
    reasons = pd.read_csv(out / "failure_reasons.csv")
    failed = facts[~facts.success].fillna({"failure_reason": "(not recorded)"})
    expected = failed.groupby(["source", "failure_reason"]).size()
    assert dict(zip(zip(reasons.source, reasons.failure_reason), reasons.episodes)) == expected.to_dict()
    assert reasons.set_index(["source", "failure_reason"]).loc[("heuristic", "timeout"), "share_of_failures"] \
        == pytest.approx(1 / 4)


def test_episode_table_is_the_metadata(report):
    out, facts = report
    episodes = pd.read_csv(out / "episodes.csv").sort_values(["dataset", "seed", "attempt"], ignore_index=True)
    expected = facts.sort_values(["dataset", "seed", "attempt"], ignore_index=True)
    assert episodes["success"].tolist() == expected["success"].tolist()
    assert episodes["length"].tolist() == expected["length"].tolist()
    np.testing.assert_allclose(episodes["return"], expected["return"])
    np.testing.assert_allclose(episodes["object_size"], expected["object_size"])
