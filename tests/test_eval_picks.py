"""hingelab eval picks: one policy on each pick set (real ToolPick-v0 episodes), the pooled table, resume,
pairing with another policy's table, and bad input."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.rollouts.journal import JOURNAL_FILE
from hingelab.rollouts.pick_sets import parse_sets, set_folder

SETS = ["sphere:0.02", "cube:0.015"]


def test_a_baseline_on_two_sets_then_resume_and_pair(tmp_path, capsys):
    out = tmp_path / "scripted"
    argv = ["eval", "picks", "--baseline", "scripted", "--sets", *SETS, "--episodes", "2", "--seed", "7",
            "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "over 2 sets, 4 episodes: first attempt" in printed
    table = pd.read_csv(out / "picks.csv")
    assert list(table.object) == ["cube", "sphere", "all"] and table.episodes.tolist() == [2, 2, 4]
    for shape, size in parse_sets(SETS):
        episodes = pd.read_csv(set_folder(out, shape, size) / "episodes.csv")
        card = json.loads((set_folder(out, shape, size) / "dataset.json").read_text())
        assert len(episodes) == 2 and card["seed"] == 7 and card["config"]["object"] == shape
    assert json.loads((out / "picks.json").read_text())["sets"] == SETS
    assert "hingelab eval picks" in (out / "picks.md").read_text()

    # a set cut off after its first episode, as a kill leaves it (the journal lists the finished episode; the
    # tables come at the end): --resume keeps that episode and the finished set and runs only what is missing
    sphere = set_folder(out, "sphere", 0.02)
    first = pd.read_csv(sphere / "episodes.csv").iloc[0].to_dict()
    (sphere / JOURNAL_FILE).write_text(json.dumps({k: (None if pd.isna(v) else v) for k, v in first.items()}) + "\n")
    for name in ("episodes.csv", "table.csv", "report.md"):
        (sphere / name).unlink()
    before = sorted(p.name for p in (set_folder(out, "cube", 0.015) / "episodes").iterdir())
    assert main([*argv, "--resume"]) == 0
    assert "cube_15mm: done before, kept" in capsys.readouterr().out
    assert sorted(p.name for p in (set_folder(out, "cube", 0.015) / "episodes").iterdir()) == before
    assert (sphere / "table.csv").is_file() and not (sphere / JOURNAL_FILE).exists()
    assert pd.read_csv(sphere / "episodes.csv").seed.tolist()[0] == first["seed"]

    # without --resume, or with other settings, the folder is refused and nothing is changed
    assert main(argv) != 0
    assert "add --resume" in capsys.readouterr().err
    assert main([*argv[:-2], "--episodes", "3", "--out", str(out), "--resume"]) != 0
    assert "episodes differ" in capsys.readouterr().err

    # another policy at the same seed runs the same episodes: the report pairs them
    other = tmp_path / "random"
    assert main(["eval", "picks", "--baseline", "random", "--sets", "cube:0.015", "--episodes", "2", "--seed", "7",
                 "--no-progress", "--out", str(other)]) == 0
    report = tmp_path / "report"
    assert main(["report", "--picks", str(set_folder(out, "cube", 0.015)), str(set_folder(other, "cube", 0.015)),
                 "--out", str(report), "--allow-dirty"]) == 0
    paired = pd.read_csv(report / "paired.csv")
    assert paired.shared_episodes.tolist() == [2]


def test_sets_run_in_worker_processes_as_in_one(tmp_path):
    frames = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}"
        assert main(["eval", "picks", "--baseline", "scripted", "--sets", *SETS, "--episodes", "1", "--seed", "7",
                     "--jobs", jobs, "--no-progress", "--out", str(out)]) == 0
        assert pd.read_csv(out / "picks.csv").episodes.tolist() == [1, 1, 2]
        frames[jobs] = pd.concat([pd.read_csv(set_folder(out, *s) / "episodes.csv") for s in parse_sets(SETS)])
    columns = ["seed", "success", "length", "return"]
    pd.testing.assert_frame_equal(frames["1"][columns], frames["2"][columns])


def test_families_are_sets_with_a_size_cap(tmp_path):
    assert parse_sets(["family:prism3:0.03", "family:torus:7:0.02"]) == (("family:prism3", 0.03),
                                                                          ("family:torus:7", 0.02))
    assert set_folder(tmp_path, "family:torus:7", 0.02) == tmp_path / "family_torus_7_20mm"
    out = tmp_path / "families"
    assert main(["eval", "picks", "--baseline", "scripted", "--sets", "family:prism3:0.03", "--episodes", "1",
                 "--seed", "7", "--no-progress", "--out", str(out)]) == 0
    row = pd.read_csv(out / "picks.csv").iloc[0]
    assert row.object == "family:prism3" and row.episodes == 1


@pytest.mark.parametrize("sets, message", [(["ball:0.02"], "give SHAPE:SIZE"), (["sphere:2"], "give SHAPE:SIZE"),
                                           (["sphere"], "give SHAPE:SIZE"),
                                           (["family:nope:0.03"], "nope"), (["family:prism3:0.5"], "out of range"),
                                           (["cube:0.02", "cube:0.02"], "names a set twice")])
def test_bad_sets_are_one_line(sets, message):
    with pytest.raises(ConfigError, match=message):
        parse_sets(sets)


def test_bad_input_on_the_command_line(tmp_path, capsys):
    assert main(["eval", "picks", "--baseline", "nope", "--out", str(tmp_path / "o")]) != 0
    assert "not a high-level baseline" in capsys.readouterr().err
    (tmp_path / "dataset").mkdir()
    (tmp_path / "dataset" / "dataset.json").write_text("{}")
    assert main(["eval", "picks", "--baseline", "scripted", "--out", str(tmp_path / "dataset")]) != 0
    assert "holds a dataset" in capsys.readouterr().err
