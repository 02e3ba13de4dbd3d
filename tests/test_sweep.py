"""hingelab sweep on a local one-node Ray: a 2-condition x 2-seed grid of tiny `train low` runs, a sweep
stopped mid-way and resumed, bad sweep files, and `hingelab report --runs` grouping the trials."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.training import checkpoints as ckpt

TINY_ARGS = ["--max-episode-steps", "10", "--learning-starts", "30", "--batch-size", "16", "--buffer-size", "2000",
             "--eval-goals", "1", "--algorithm", "sac", "--keep-checkpoints", "10"]


def sweep_file(path, steps: int, eval_every: int, checkpoint_every: int, seeds=(0, 1)):
    args = ["--steps", str(steps), *TINY_ARGS, "--eval-every", str(eval_every), "--checkpoint-every",
            str(checkpoint_every)]
    path.write_text(
        "[sweep]\n"
        'command = "train low"\n'
        f"seeds = {list(seeds)}\n"
        f"args = {json.dumps(args)}\n"
        "cpus_per_trial = 1\n\n"
        "[conditions]\n"
        "effort = []\n"
        'no_effort = ["--no-effort"]\n')
    return path


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray of 2 CPUs for the sweeps this module runs in process (``ray_session`` uses a Ray already
    initialized as it is): one Ray start instead of one per sweep command. A sweep that starts its own local
    Ray and stops it: the stopped sweep's driver process below, and ``hingelab demo``'s sweep in test_cli."""
    from hingelab.workers.ray_runtime import ray_session

    with ray_session(num_cpus=2):
        yield


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, local_ray):
    root = tmp_path_factory.mktemp("sweep")
    spec = sweep_file(root / "grid.toml", steps=120, eval_every=60, checkpoint_every=60)
    out = root / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--cpus", "2", "--no-progress"]) == 0
    return spec, out


def test_a_two_by_two_sweep_runs_every_trial_as_a_normal_run_folder(sweep):
    spec, out = sweep
    table = pd.read_csv(out / "sweep.csv")
    assert sorted(table["trial"]) == ["effort_seed0", "effort_seed1", "no_effort_seed0", "no_effort_seed1"]
    assert (table["state"] == "finished").all() and (table["returncode"] == 0).all()
    assert (table["env_steps"] == 120).all() and (table["steps"] == 120).all()
    assert (table["wall_time_s"] > 0).all() and (table["sessions"] == 1).all()
    assert table["final_success_rate"].between(0, 1).all()  # the last metrics.csv row
    for row in table.itertuples():
        run = out / row.trial
        config = json.loads((run / "config.json").read_text())
        assert config["config"]["seed"] == row.seed and config["config"]["steps"] == 120
        assert config["config"]["use_effort"] == (row.condition == "effort")
        assert config["config"]["n_envs"] == 1 and config["config"]["torch_threads"] == 1  # cpus_per_trial
        assert json.loads((run / "run.json").read_text())["name"] == row.condition
        metrics = pd.read_csv(run / "metrics.csv")
        assert list(metrics["env_steps"]) == [0, 60, 120]
        assert row.final_success_rate == pytest.approx(metrics["success_rate"].iloc[-1])
        assert (run / "model.zip").exists() and len(Dataset(run / "dataset")) >= 12
    # what ran it is recorded: the file itself and the code version
    assert (out / "sweep.toml").read_text() == spec.read_text()
    record = json.loads((out / "sweep.json").read_text())
    assert record["command"] == "train low" and len(record["sessions"]) == 1
    assert record["sessions"][0]["git_commit"] and record["sessions"][0]["ray"] == "local"


def test_report_runs_groups_a_sweep_by_condition(sweep, tmp_path, capsys):
    _, out = sweep
    assert main(["report", "--runs", str(out), "--out", str(tmp_path / "report")]) == 0
    curves = pd.read_csv(tmp_path / "report" / "learning_curves.csv")
    assert sorted(curves["run"].unique()) == ["effort", "no_effort"]
    assert (curves["seeds"] == 2).all() and sorted(curves["env_steps"].unique()) == [0, 60, 120]
    per_seed = pd.read_csv(tmp_path / "report" / "learning_curves_by_seed.csv")
    assert per_seed.groupby("run")["seed"].nunique().to_dict() == {"effort": 2, "no_effort": 2}
    final = pd.read_csv(tmp_path / "report" / "final_success.csv").set_index("run")
    sweep_table = pd.read_csv(out / "sweep.csv")
    for condition in ("effort", "no_effort"):
        values = sweep_table.loc[sweep_table["condition"] == condition, "final_success_rate"]
        assert final.loc[condition, "seeds"] == 2
        assert final.loc[condition, "success_rate_mean"] == pytest.approx(values.mean())
        assert (final.loc[condition, "success_rate_ci_low"] <= values.mean()
                <= final.loc[condition, "success_rate_ci_high"])
    assert "Success at the end, across seeds" in (tmp_path / "report" / "report.md").read_text()
    assert "effort" in capsys.readouterr().out


def test_a_finished_sweep_resumed_runs_nothing_again(sweep, capsys):
    spec, out = sweep
    before = {p: p.stat().st_mtime_ns for p in out.glob("*/model.zip")}
    assert main(["sweep", str(spec), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/model.zip")} == before
    assert "4 of 4 trials" in capsys.readouterr().out


def _training_processes(out) -> list[str]:
    import psutil

    found = []
    for proc in psutil.process_iter(["cmdline"]):
        cmdline = " ".join(proc.info["cmdline"] or [])
        if str(out) in cmdline and "train" in cmdline:
            found.append(cmdline)
    return found


def test_a_sweep_stopped_mid_way_resumes_each_trial_from_its_checkpoint(tmp_path, local_ray):
    steps = 400
    spec = sweep_file(tmp_path / "grid.toml", steps=steps, eval_every=100, checkpoint_every=30, seeds=(0,))
    out = tmp_path / "out"
    driver = subprocess.Popen([sys.executable, "-m", "hingelab.cli.main", "sweep", str(spec), "--out", str(out),
                               "--cpus", "2", "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True)
    runs = [out / "effort_seed0", out / "no_effort_seed0"]
    deadline = time.time() + 300
    while time.time() < deadline and driver.poll() is None:
        if all(ckpt.latest_checkpoint(r) is not None for r in runs if r.exists()) and all(r.exists() for r in runs):
            break
        time.sleep(0.2)
    assert driver.poll() is None, driver.communicate()[0]
    assert not any((r / "model.zip").exists() for r in runs), "a trial finished before the stop: raise steps"
    driver.send_signal(signal.SIGTERM)  # a stop (Ctrl-C, a scheduler's kill)
    output = driver.communicate(timeout=120)[0]
    assert driver.returncode == 130, output
    assert "--resume" in output
    time.sleep(2)
    assert _training_processes(out) == []  # the trials stopped with the sweep
    stopped = pd.read_csv(out / "sweep.csv").set_index("trial")
    assert (stopped["state"] == "stopped").all()
    checkpointed = {r.name: int(ckpt.latest_checkpoint(r).name.split("_")[-1]) for r in runs}
    assert all(0 < step < steps for step in checkpointed.values())

    assert main(["sweep", str(spec), "--out", str(out), "--resume", "--no-progress"]) == 0
    table = pd.read_csv(out / "sweep.csv").set_index("trial")
    assert (table["state"] == "finished").all() and (table["env_steps"] == steps).all()
    assert (table["sessions"] == 1).all()  # the stopped session did not finish them
    for run in runs:
        # continued from its checkpoint, not from the start: one fresh start and one --resume in its log
        assert table.loc[run.name, "resumed_from_step"] >= checkpointed[run.name]
        log = (out / "logs" / f"{run.name}.log").read_text().splitlines()
        starts = [line for line in log if line.startswith("== ")]
        assert len(starts) == 2 and "--resume" not in starts[0] and starts[1].endswith("--resume")
        metrics = pd.read_csv(run / "metrics.csv")
        assert list(metrics["env_steps"]) == [0, 100, 200, 300, 400]  # every evaluation once
        from stable_baselines3 import SAC

        assert SAC.load(run / "model.zip", device="cpu").num_timesteps == steps
        # every training episode (seeded by its count) is in the dataset; none was started twice from zero
        index = Dataset(run / "dataset").index
        assert index["seed"].nunique() >= steps // 10
        assert json.loads((run / "config.json").read_text())["config"]["seed"] == 0


@pytest.mark.parametrize("body, expected", [
    ('[sweep]\ncommand = "train fast"\nseeds = [0]\n[conditions]\na = []\n', "command 'train fast' is not"),
    ('[sweep]\ncommand = "train low"\nargs = []\n[conditions]\na = []\n', "seeds must be a non-empty list"),
    ('[sweep]\ncommand = "train flat"\nseeds = [0]\n[conditions]\na = ["--no-effort"]\n',
     "gives --no-effort, which `hingelab train flat` does not have"),
    ('[sweep]\ncommand = "train low"\nseeds = [0]\nargs = ["--steps", "lots"]\n[conditions]\na = []\n',
     "invalid int value: 'lots'"),
    ('[sweep]\ncommand = "train low"\nseeds = [0]\n[conditions]\na = ["--seed", "3"]\n',
     "which the sweep sets for every trial"),
    ('[sweep]\ncommand = "train low"\nseeds = [0, 0]\n[conditions]\na = []\n', "repeat a seed"),
    ('[sweep]\ncommand = "train low"\nseeds = [0]\n', "no [conditions] table"),
    ('[sweep\ncommand = "train low"\n', "is not TOML"),
])
def test_a_bad_sweep_file_is_one_line_before_anything_starts(tmp_path, capsys, body, expected):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("hingelab: error: ")
    assert str(path) in err and expected in err
    assert not out.exists()


def test_resume_refuses_another_sweep_file_and_a_new_sweep_refuses_a_used_folder(sweep, tmp_path, capsys):
    spec, out = sweep
    other = sweep_file(tmp_path / "other.toml", steps=240, eval_every=60, checkpoint_every=60)
    assert main(["sweep", str(other), "--out", str(out), "--resume"]) == 1
    assert "differs from" in capsys.readouterr().err
    assert main(["sweep", str(spec), "--out", str(out)]) == 1
    assert "is not empty; continue the sweep there with --resume" in capsys.readouterr().err
