"""hingelab report --picks: the pick table over `eval high` folders, Wilson intervals, pooled rows."""

from __future__ import annotations

import pandas as pd
import pytest

from hingelab.analysis.pick_table import pick_table
from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.errors import ConfigError


def eval_folder(root, policy, obj, size, outcomes, low_level="policy", perception=None, tool_position=None):
    """An `eval high --out` folder: its card and episodes.csv (outcomes: (success, first, attempts, reason))."""
    config = {"policy": policy, "object": obj, "size": size, "low_level": low_level}
    if perception:  # as `eval high --perception camera` records it (synthesized: not recorded)
        config["perception"] = perception
    if tool_position:  # as `eval high --tool-position anchored` records it (observed: not recorded)
        config["tool_position"] = tool_position
    create_dataset(root, name=root.name, source="high_level_evaluation", seed=1000, config=config)
    pd.DataFrame([{"episode": i, "success": s, "first_attempt_success": f, "attempts": a, "failure_reason": r}
                  for i, (s, f, a, r) in enumerate(outcomes)]).to_csv(root / "episodes.csv", index=False)
    return root


def test_rows_pooled_rows_and_intervals(tmp_path, capsys):
    a = eval_folder(tmp_path / "a", "runs/x/model.zip", "sphere", 0.02,
                    [(True, True, 1, "")] * 8 + [(True, False, 2, ""), (False, False, 1, "slip")])
    b = eval_folder(tmp_path / "b", "runs/x/model.zip", "cube", 0.015,
                    [(True, True, 1, "")] * 5 + [(False, False, 1, "missed_grasp")] * 5)
    c = eval_folder(tmp_path / "c", "scripted", "cube", 0.015, [(True, True, 1, "")] * 4)
    table = pick_table([a, b, c])
    sphere = table[(table.policy == "x/model.zip") & (table.object == "sphere")].iloc[0]
    assert (sphere.successes, sphere.first_attempt_successes, sphere.failures_slip) == (9, 8, 1)
    assert sphere.ci_low == pytest.approx(0.5958, abs=1e-3) and sphere.ci_high == pytest.approx(0.9821, abs=1e-3)
    pooled = table[(table.policy == "x/model.zip") & (table.object == "all")].iloc[0]
    assert (pooled.episodes, pooled.successes, pooled.first_attempt_successes) == (20, 14, 13)
    assert pooled.lowest_set_success_rate == 0.5 and pooled.failures_missed_grasp == 5
    assert table[(table.policy == "scripted") & (table.object == "all")].iloc[0].success_rate == 1.0
    assert main(["report", "--picks", str(a), str(b), str(c), "--out", str(tmp_path / "out"), "--allow-dirty"]) == 0
    page = (tmp_path / "out" / "picks.md").read_text()
    assert "| x/model.zip | policy | synthesized | sphere | 2.000 | 10 | 8 | 0.800 |" in page
    assert "hingelab report --picks" in page
    assert len(pd.read_csv(tmp_path / "out" / "picks.csv")) == 5


def test_camera_perception_is_a_row_of_its_own(tmp_path):
    synthesized = eval_folder(tmp_path / "s", "runs/x/model.zip", "sphere", 0.02, [(True, True, 1, "")] * 4)
    camera = eval_folder(tmp_path / "c", "runs/x/model.zip", "sphere", 0.02,
                         [(True, True, 1, "")] * 2 + [(False, False, 1, "no_camera_cloud")] * 2, perception="camera")
    table = pick_table([synthesized, camera])
    pooled = table[table.object == "all"].set_index("perception")
    assert pooled.loc["synthesized", "success_rate"] == 1.0 and pooled.loc["camera", "success_rate"] == 0.5
    assert pooled.loc["camera", "failures_no_camera_cloud"] == 2


def test_the_anchored_tool_position_is_a_row_of_its_own(tmp_path):
    observed = eval_folder(tmp_path / "o", "runs/x/model.zip", "sphere", 0.02, [(False, False, 1, "slip")] * 4)
    anchored = eval_folder(tmp_path / "a", "runs/x/model.zip", "sphere", 0.02, [(True, True, 1, "")] * 4,
                           tool_position="anchored")
    pooled = pick_table([observed, anchored]).query("object == 'all'").set_index("perception")
    assert pooled.loc["synthesized", "success_rate"] == 0.0
    assert pooled.loc["synthesized, anchored tool position", "success_rate"] == 1.0


def test_a_folder_that_is_not_an_eval_high_one_is_refused(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="is not a `hingelab eval high --out` folder"):
        pick_table([tmp_path / "empty"])
    assert main(["report", "--picks", str(tmp_path / "empty"), "--out", str(tmp_path / "o"), "--allow-dirty"]) != 0
    assert "hingelab: error:" in capsys.readouterr().err


def test_the_sign_test_is_exact_and_two_sided():
    from hingelab.analysis.pick_table import sign_test_p

    assert sign_test_p(19, 6) == pytest.approx(0.01463, abs=1e-5)  # 2 * P(X <= 6), X ~ Binomial(25, 1/2)
    assert sign_test_p(6, 19) == sign_test_p(19, 6)
    assert sign_test_p(3, 3) == 1.0 and sign_test_p(0, 0) == 1.0
    assert sign_test_p(5, 0) == pytest.approx(2 / 32)


def test_policies_on_the_same_episodes_pair(tmp_path):
    from hingelab.analysis.pick_table import paired_table

    def with_seeds(folder, firsts, seeds):
        frame = pd.read_csv(folder / "episodes.csv")
        frame["seed"], frame["first_attempt_success"] = seeds, firsts
        frame.to_csv(folder / "episodes.csv", index=False)
        return folder

    ok, miss = (True, True, 1, ""), (False, False, 1, "slip")
    a = with_seeds(eval_folder(tmp_path / "a", "runs/a/model.zip", "sphere", 0.02, [ok] * 4),
                   [True, True, False, False], [10, 11, 12, 13])
    # b ran episodes 11-14 of the same set: three shared; on 11 both picked, on 12 only b, on 13 neither
    b = with_seeds(eval_folder(tmp_path / "b", "runs/b/model.zip", "sphere", 0.02, [miss] * 4),
                   [True, True, False, True], [11, 12, 13, 14])
    other_set = with_seeds(eval_folder(tmp_path / "c", "runs/b/model.zip", "cube", 0.02, [ok] * 2),
                           [True, True], [10, 11])  # a never ran the cube: nothing to pair
    paired = paired_table([a, b, other_set])
    assert len(paired) == 1
    row = paired.iloc[0]
    assert row.policy_a.startswith("a/model.zip") and row.policy_b.startswith("b/model.zip")
    assert (row.shared_episodes, row.both, row.a_only, row.b_only, row.neither) == (3, 1, 0, 1, 1)
    assert row.sign_test_p == 1.0
    assert main(["report", "--picks", str(a), str(b), "--out", str(tmp_path / "out"), "--allow-dirty"]) == 0
    assert "## Paired" in (tmp_path / "out" / "picks.md").read_text()
    assert len(pd.read_csv(tmp_path / "out" / "paired.csv")) == 1
