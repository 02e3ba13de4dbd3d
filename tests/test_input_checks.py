"""Numbers are checked at the door: out-of-range seeds, non-finite floats and too many processes are refused
in one error line before anything runs, and nothing is written (a rerun finds no folder in its way)."""

import json
import math

import pytest

from hingelab import seeds
from hingelab.arguments import available_cores
from hingelab.cli.main import main
from hingelab.errors import ConfigError

# the commands with a --seed, each writing into --out (OUT is replaced by a fresh path)
SEEDED = {
    "generate heuristic": ["generate", "heuristic", "--episodes", "1", "--out", "OUT"],
    "generate clouds": ["generate", "clouds", "--n", "2", "--out", "OUT"],
    "train low": ["train", "low", "--steps", "10", "--out", "OUT"],
    "train encoder": ["train", "encoder", "--data", "OUT", "--out", "OUT/encoder.pt"],
    "eval low": ["eval", "low", "--episodes", "1", "--out", "OUT"],
    "eval high": ["eval", "high", "--baseline", "heuristic", "--episodes", "1", "--out", "OUT"],
    "eval perception": ["eval", "perception", "--episodes", "1", "--out", "OUT"],
    "trial": ["trial", "--trials", "1", "--out", "OUT"],
    "diagnose noise": ["diagnose", "noise", "--episodes", "1", "--out", "OUT"],
}


def _refused(argv, capsys, words: tuple[str, ...]):
    """``main(argv)`` stops at the parser (exit 2) with an error line that names ``words``."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("hingelab") and "error:" in last and all(w in last for w in words), last


@pytest.mark.parametrize("seed", [-1, 2**32, 10**14])
@pytest.mark.parametrize("command", list(SEEDED))
def test_seeds_out_of_range_are_refused_and_nothing_is_written(tmp_path, capsys, command, seed):
    out = tmp_path / "out"
    argv = [str(out) if word == "OUT" else word.replace("OUT", str(out)) for word in SEEDED[command]]
    _refused([*argv, "--seed", str(seed)], capsys, ("--seed", "[0, 2**32)" if seed >= -1 else ""))
    assert not out.exists()


def test_the_largest_seed_parses_and_every_stream_fits_int64():
    from hingelab.cli.main import build_parser

    top = seeds.SEED_BOUND - 1
    args = build_parser(["train", "low"]).parse_args(["train", "low", "--seed", str(top)])
    assert args.seed == top
    k = seeds.EPISODE_LIMIT
    derived = [seeds.demo_seed(top, k), seeds.trial_seed(top, k), seeds.eval_high_seed(top, k),
               seeds.demo_seed(seeds.prior_block(top, 3), k), seeds.training_episode_seed(top, 15, 10**6),
               seeds.sampled_goal_seed(top, k), seeds.ensemble_member_seed(top, 10)]
    assert all(0 <= s < 2**63 for s in derived)


@pytest.mark.parametrize("argv, words", [
    (["generate", "clouds", "--noise", "nan"], ("--noise", "finite")),
    (["generate", "clouds", "--noise-max", "inf"], ("--noise-max", "finite")),
    (["generate", "heuristic", "--size", "nan"], ("--size", "finite")),
    (["eval", "high", "--size=-inf"], ("--size", "finite")),
    (["train", "low", "--learning-rate", "nan"], ("--learning-rate", "finite")),
    (["sweep", "sweep.toml", "--cpus", "0"], ("--cpus", "at least 1")),
    (["generate", "heuristic", "--workers", "0"], ("--workers", "at least 1")),
    (["train", "low", "--envs", "0"], ("--envs", "at least 1")),
])
def test_non_finite_floats_and_zero_counts_are_refused(tmp_path, capsys, argv, words):
    out = tmp_path / "out"
    _refused([*argv, "--out", str(out)], capsys, words)
    assert not out.exists()


def test_cloud_config_refuses_nan_noise():
    from hingelab.perception.cloud_dataset_config import CloudDatasetConfig

    with pytest.raises(ConfigError, match="noise_std_m"):
        CloudDatasetConfig(noise_std_m=math.nan)


@pytest.mark.parametrize("argv, flag", [
    (["generate", "heuristic", "--episodes", "50", "--workers", "{n}"], "--workers"),
    (["train", "low", "--steps", "10", "--envs", "{n}"], "--envs"),
])
def test_more_processes_than_cores_is_one_line(tmp_path, capsys, argv, flag):
    out = tmp_path / "out"
    n = str(available_cores() + 1)
    assert main([*(n if w == "{n}" else w for w in argv), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and flag in err and "--allow-oversubscribe" in err
    assert not out.exists()


def test_workers_never_outnumber_the_episodes(tmp_path, monkeypatch, capsys):
    """8 workers for 1 episode start 1 process (each loads a simulator of about 0.5 GB)."""
    from hingelab.rollouts import heuristic_demos

    seen = {}

    def fake(out, config, **kwargs):
        seen["workers"] = config.workers
        return []

    monkeypatch.setattr(heuristic_demos, "generate_heuristic_dataset", fake)
    assert main(["generate", "heuristic", "--episodes", "1", "--workers", "8", "--allow-oversubscribe",
                 "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert seen["workers"] == 1


def test_json_files_refuse_nan_naming_the_field(tmp_path):
    from hingelab.json_text import strict_dumps

    assert json.loads(strict_dumps({"a": [1.0, 2]}, tmp_path / "x.json")) == {"a": [1.0, 2]}
    with pytest.raises(ConfigError, match=r"x\.json: config\.noise_std_m is not a finite number"):
        strict_dumps({"config": {"noise_std_m": math.nan}}, tmp_path / "x.json")


def test_journal_rows_and_reproduce_state_write_nan_as_null_so_any_json_reader_parses_them(tmp_path):
    import numpy as np

    from hingelab.rollouts.journal import EpisodeJournal
    from hingelab.sweeps.reproduce import write_state

    journal = EpisodeJournal(tmp_path / "eval")
    (tmp_path / "eval").mkdir()
    journal.append({"seed": 3, "distance": math.nan, "returns": [1.0, np.float32("inf")], "ok": True})
    line = journal.path.read_text().strip()
    assert "NaN" not in line and "Infinity" not in line
    assert json.loads(line) == {"seed": 3, "distance": None, "returns": [1.0, None], "ok": True}
    assert EpisodeJournal(tmp_path / "eval").load() == [json.loads(line)]
    write_state(tmp_path, {"stages": {"encoder": {"r2": math.nan, "done": True}}})
    text = (tmp_path / "reproduce.json").read_text()
    assert json.loads(text)["stages"]["encoder"] == {"r2": None, "done": True} and "NaN" not in text


def test_exported_episode_metadata_is_strict_json_even_from_an_episode_holding_nan():
    # Episodes written before JSON was strict can hold NaN in their metadata; the ROS 2 String and the
    # LeRobot/Minari attributes carry it as null.
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    from hingelab.episodes.export_source import metadata_json
    from hingelab.ros2.episode_messages import episode_message

    def strict(text):
        return json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in {text}"))

    metadata = {"seed": 4, "final_distance": math.nan, "returns": [1.0, np.float64("inf")], "object": "sphere"}
    expected = {"seed": 4, "final_distance": None, "returns": [1.0, None], "object": "sphere"}
    assert strict(metadata_json(metadata)) == expected
    assert strict(episode_message(get_typestore(Stores.ROS2_HUMBLE), metadata).data) == expected
