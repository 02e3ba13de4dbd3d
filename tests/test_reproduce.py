"""hingelab reproduce: the stage plan follows the shipped recipes; a reproduction killed during a stage
resumes that stage (with its command's --resume) and runs the later ones only; the one-line errors; and
(slow) the whole pipeline at --scale tiny with real commands."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError, HingelabError
from hingelab.paths import ASSETS_DIR
from hingelab.sweeps import reproduce_plan as P
from hingelab.sweeps.reproduce import (
    STATE_FILE,
    can_resume,
    group_alive,
    new_state,
    read_state,
    run_reproduction,
    write_state,
)

REPO = Path(__file__).resolve().parents[1]
SHIPPED_ENCODER = ASSETS_DIR / "checkpoints" / "encoder.pt"


def _value(argv, flag):
    return argv[list(argv).index(flag) + 1]


# ---------------------------------------------------------------------------- the plan (no process)
def test_the_plan_runs_the_shipped_recipes_in_dependency_order(tmp_path):
    stages = P.plan_stages(tmp_path / "r")
    names = [s.name for s in stages]
    assert names[:7] == ["clouds", "encoder", "low_demos", "low_open", "low_closed", "low_experts", "high"]
    for i, s in enumerate(stages):  # every stage after the stages it waits for
        assert all(names.index(d) < i for d in s.deps), s.name
    by = {s.name: s for s in stages}
    root = (tmp_path / "r").resolve()
    stage_dir = lambda name: str(root / "stages" / name)  # noqa: E731
    # the shipped commands' flags and seeds (assets/checkpoints/README.md, analysis/high-level/README.md)
    assert by["clouds"].argv == (*P.CLOUDS, "--out", stage_dir("clouds"))
    assert "--n 20000 --noise 0.002 --noise-max 0.006 --seed 0" in " ".join(by["clouds"].argv)
    assert "--epochs 24 --seed 0 --threads 1" in " ".join(by["encoder"].argv)
    assert _value(by["encoder"].argv, "--data") == stage_dir("clouds")
    assert "--baseline synergy --episodes 200 --seed 11" in " ".join(by["low_demos"].argv)
    for name, steps, seed in (("low_open", "50000", "2"), ("low_closed", "40000", "4")):
        argv = by[name].argv
        assert (_value(argv, "--steps"), _value(argv, "--seed")) == (steps, seed)
        assert _value(argv, "--from") == stage_dir("low_demos")
        for flag, value in (("--buffer-size", "200000"), ("--learning-starts", "1000"), ("--eval-every", "2500"),
                            ("--eval-goals", "5"), ("--bc-weight", "1"), ("--bc-pretrain", "2000"),
                            ("--drift-weight", "60"), ("--envs", "1")):
            assert _value(argv, flag) == value, (name, flag)
        assert "--bc-no-q-filter" in argv and "--in-process" in argv
    assert "--goal-openings=-1:0.10" in by["low_closed"].argv and "--goal-openings=-1:0.10" not in by["low_open"].argv
    experts = f"{stage_dir('low_experts')}/low_level_experts.json"
    assert by["low_experts"].argv == ("compose", "low", "--expert", f"{stage_dir('low_closed')}/model.zip:0.10",
                                      "--expert", f"{stage_dir('low_open')}/model.zip", "--out", experts)
    # the shipped high level: one DAgger run over the clone it fits first (assets/checkpoints/README.md)
    high = by["high"]
    assert high.argv == (*P.HIGH_DAGGER, "--low-level", experts, "--out", stage_dir("high"))
    assert shlex.join(P.HIGH_DAGGER) == (
        "train high --learner dagger --base fit "
        "--env-kwargs '{\"observe_extent\": true, \"tool_position\": \"relative\"}' --prior-objects all "
        "--prior-episodes 720 --net-arch 512 512 --clone-members 3 --rollout-objects all "
        "--dagger-rounds 4 --dagger-episodes 120 --eval-episodes 30 --seed 0 --jobs 2")
    assert (high.deps, high.resume, high.product) == (("low_experts",), "dagger", "high_level.zip")
    assert high.outputs == ("stages/high/model.zip", "stages/high/base.zip")
    assert {s.resume for s in stages} <= set(P.RESUME_KINDS)
    for s in stages:
        assert _value(s.argv, "--out").startswith(stage_dir(s.name))
    # the products perceive through the reproduced encoder; the encoder's own stages and the shipped evaluations not
    plain = {"clouds", "encoder", "eval_low_shipped"} | {n for n in names if n.startswith("picks_shipped")}
    assert {s.name for s in stages if not s.reproduced_assets} == plain
    assert P.stage_environment(by["low_open"], root) == {"HINGELAB_ASSETS": str(root / "assets")}
    assert P.stage_environment(by["encoder"], root) == {}
    # the comparisons: the same command and seeds for the reproduced and the shipped policy
    c = P.COMPARISON
    assert by["eval_low_reproduced"].argv[2] == experts and "eval_low_shipped" in by
    assert by["eval_low_reproduced"].argv[3:-2] == by["eval_low_shipped"].argv[2:-2]
    for shape, size in c["pick_sets"]:
        theirs = by[P.pick_stage_name("shipped", shape, size)]
        assert theirs.argv[:2] == ("eval", "high") and _value(theirs.argv, "--seed") == str(c["pick_seed"])
        for policy, checkpoint in (("clone", "base.zip"), ("dagger", "model.zip")):
            ours = by[P.pick_stage_name(policy, shape, size)]
            assert ours.argv[2] == f"{stage_dir('high')}/{checkpoint}" and ours.argv[3:-2] == theirs.argv[2:-2]
            assert ours.deps == ("high",) and ours.reproduced_assets


def test_tiny_scale_changes_sizes_only(tmp_path):
    shipped, tiny = P.plan_stages(tmp_path), P.plan_stages(tmp_path, "tiny")
    assert [s.name for s in shipped[:9]] == [t.name for t in tiny[:9]]  # the pick sets differ (fewer)
    for s, t in zip(shipped[:9], tiny[:9]):
        assert (s.deps, s.resume, s.outputs) == (t.deps, t.resume, t.outputs)
        for flag in ("--seed", "--learner", "--base", "--low-level", "--from", "--out", "--goal-openings",
                     "--env-kwargs", "--prior-objects", "--rollout-objects"):
            if flag in s.argv:
                assert _value(s.argv, flag) == _value(t.argv, flag), (s.name, flag)
    by = {t.name: t for t in tiny}
    assert _value(by["encoder"].argv, "--epochs") == "1" and _value(by["low_open"].argv, "--steps") == "150"
    high = by["high"].argv
    assert high[high.index("--net-arch") + 1:][:3] == ("16", "16", "--clone-members")
    assert {flag: _value(high, flag) for flag in ("--prior-episodes", "--clone-members", "--clone-updates",
                                                 "--dagger-rounds", "--dagger-episodes", "--dagger-updates",
                                                 "--eval-episodes")} == {
        "--prior-episodes": "12", "--clone-members": "2", "--clone-updates": "20", "--dagger-rounds": "1",
        "--dagger-episodes": "2", "--dagger-updates": "20", "--eval-episodes": "1"}
    assert len([t for t in tiny if t.name.startswith("picks_")]) == 3  # one set, three policies
    with pytest.raises(ConfigError, match="choose one of shipped, tiny"):
        P.plan_stages(tmp_path, "huge")


@pytest.mark.parametrize("scale", P.SCALES)
def test_train_high_dagger_takes_the_high_stage_command_and_its_resume(tmp_path, scale):
    """The stage's command parses as `train high --learner dagger` with the recipe's settings, and its
    `--resume` (what an unfinished stage is continued with) is accepted against the config.json it wrote."""
    from hingelab.cli.main import build_parser
    from hingelab.learners.dagger.config import DaggerConfig
    from hingelab.training.run_config import config_from_args, given_settings
    from hingelab.training.run_folder import RunFolder, resumed_config

    argv = list(next(s for s in P.plan_stages(tmp_path / "r", scale) if s.name == "high").argv)
    args = build_parser(argv).parse_args(argv)
    assert args.learner_class.name == "dagger"
    config = config_from_args(DaggerConfig, args)
    assert (config.base, config.env_kwargs, config.prior_objects, config.rollout_objects, config.seed) == (
        "fit", {"observe_extent": True, "tool_position": "relative"}, "all", "all", 0)
    expected = ((720, (512, 512), 3, 4, 120, 30) if scale == "shipped" else (12, (16, 16), 2, 1, 2, 1))
    assert (config.prior_episodes, config.net_arch, config.clone_members, config.dagger_rounds,
            config.dagger_episodes, config.eval_episodes) == expected
    RunFolder(args.out, config).write_run_files({"learner": "dagger"})  # what the stage leaves once it started
    assert P.RESUME_KINDS["dagger"] and can_resume({"resume": "dagger"}, args.out)
    resumed = build_parser([*argv, "--resume"]).parse_args([*argv, "--resume"])
    assert resumed.resume and resumed.learner_class.name == "dagger"
    assert resumed_config(args.out, config_from_args(DaggerConfig, resumed),
                          given_settings(DaggerConfig, resumed)) == config


def test_an_unfinished_stage_resumes_only_from_what_its_command_needs(tmp_path):
    run = tmp_path / "high"
    assert not can_resume({"resume": "dagger"}, run)  # not started: started afresh
    run.mkdir()
    (run / "prior").mkdir()
    assert not can_resume({"resume": "dagger"}, run)  # no config.json: `train high --resume` would refuse
    (run / "config.json").write_text("{}")
    assert can_resume({"resume": "dagger"}, run)  # prior, base.zip and saved rounds kept by its --resume
    assert not can_resume({"resume": "sac"}, run) and not can_resume({"resume": "none"}, run)
    (run / "checkpoints" / "step_000000000010").mkdir(parents=True)
    (run / "checkpoints" / "step_000000000010" / "state.json").write_text("{}")
    assert can_resume({"resume": "sac"}, run)


def test_with_flags_replaces_values_and_appends_missing_flags():
    argv = ("train", "high", "--net-arch", "512", "512", "--goal-openings=-1:0.10", "--in-process", "--seed", "0")
    assert P.with_flags(argv, {"--net-arch": ("16", "16"), "--goal-openings": "0:1", "--steps": "5"}) == (
        "train", "high", "--net-arch", "16", "16", "--goal-openings", "0:1", "--in-process", "--seed", "0",
        "--steps", "5")


def test_linked_assets_hold_the_reproduced_encoder_and_no_policy(tmp_path):
    root = P.link_assets(tmp_path)
    assert (root / "scenes").resolve() == (ASSETS_DIR / "scenes").resolve()
    encoder = root / "checkpoints" / "encoder.pt"
    assert encoder.is_symlink() and not encoder.exists()  # dangling until the encoder stage is done
    assert encoder.resolve() == (tmp_path / "stages" / "encoder" / "encoder.pt").resolve()
    assert sorted(p.name for p in (root / "checkpoints").iterdir()) == ["README.md", "encoder.pt"]
    assert P.link_assets(tmp_path) == root  # again: nothing to redo


# ---------------------------------------------------------------------------- stand-in stages (real processes)
FAKE_STAGE = textwrap.dedent("""
    # A stand-in for `hingelab ARGS`: writes what the command's stage must leave, logs its launch, and hangs
    # (in a train run with a checkpoint) or fails where the test says.
    import json, os, pathlib, shutil, sys, time
    argv = sys.argv[1:]
    out = pathlib.Path(argv[argv.index("--out") + 1])
    with open(os.environ["FAKE_LAUNCHES"], "a") as f:
        f.write(json.dumps({"argv": argv, "assets": os.environ.get("HINGELAB_ASSETS"), "t": time.time()}) + "\\n")
    print("fake", " ".join(argv[:2]), flush=True)
    parts = out.parts
    stage = parts[len(parts) - 1 - parts[::-1].index("stages") + 1]
    if stage == os.environ.get("FAKE_FAIL"):
        print("boom: a fake failure", flush=True)
        sys.exit(3)
    command = argv[:2]
    if command == ["train", "encoder"]:
        shutil.copy(os.environ["FAKE_ENCODER"], out)
    elif command == ["compose", "low"]:
        out.write_text("{}")
    elif command[0] == "generate":
        out.mkdir()
        (out / "dataset.json").write_text("{}")
    elif command[0] == "eval":
        out.mkdir(exist_ok=True)
        (out / "dataset.json").write_text("{}")
        columns = ("success,tool_drift_mm_max\\n1,3\\n0,12\\n" if command[1] == "low" else
                   "success,first_attempt_success,attempts,failure_reason\\n1,1,1,\\n1,0,2,\\n")
        (out / "episodes.csv").write_text(columns)
    elif "dagger" in argv:  # train high --learner dagger: config.json, its prior, base.zip, then the rounds
        if "--resume" in argv and not (out / "config.json").exists():
            print("cannot resume: no config.json", flush=True)
            sys.exit(2)
        out.mkdir(exist_ok=True)
        (out / "config.json").write_text("{}")
        (out / "prior").mkdir(exist_ok=True)
        if not (out / "base.zip").exists():  # a resumed run keeps the base it fitted
            (out / "base.zip").write_text(f"fitted {time.time()}")
        if stage == os.environ.get("FAKE_HANG") and "--resume" not in argv:
            print("hanging", flush=True)
            time.sleep(600)
        (out / "model.zip").write_text("fake")
    else:  # train low (SAC: checkpoints)
        out.mkdir(exist_ok=True)
        (out / "config.json").write_text("{}")
        checkpoint = out / "checkpoints" / "step_000000000010"
        checkpoint.mkdir(parents=True, exist_ok=True)
        (checkpoint / "state.json").write_text("{}")
        if stage == os.environ.get("FAKE_HANG") and "--resume" not in argv:
            print("hanging", flush=True)
            time.sleep(600)
        (out / "model.zip").write_text("fake")
""")


@pytest.fixture
def fake(tmp_path, monkeypatch):
    script = tmp_path / "fake_stage.py"
    script.write_text(FAKE_STAGE)
    launches = tmp_path / "launches.jsonl"
    monkeypatch.setenv("FAKE_LAUNCHES", str(launches))
    monkeypatch.setenv("FAKE_ENCODER", str(SHIPPED_ENCODER))
    for name in ("FAKE_FAIL", "FAKE_HANG"):
        monkeypatch.delenv(name, raising=False)

    def read_launches():
        lines = launches.read_text().splitlines() if launches.exists() else []
        return [json.loads(line) for line in lines]

    return [sys.executable, str(script)], read_launches


def _stage_of(launch) -> str:
    """The stage a launch was for: the folder under stages/ of its --out."""
    parts = Path(launch["argv"][launch["argv"].index("--out") + 1]).parts
    return parts[len(parts) - 1 - parts[::-1].index("stages") + 1]


def _wait_for(condition, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def _kill_during(out: Path, command: list[str], stage: str, monkeypatch) -> dict:
    """Run a tiny reproduction with stand-in stages in a process of its own, SIGKILL it (a crash, an OOM kill)
    while ``stage`` runs, wait for the stage's process to die with it; the state as the kill left it."""
    monkeypatch.setenv("FAKE_HANG", stage)
    driver = subprocess.Popen(
        [sys.executable, "-c", "import sys; from hingelab.sweeps.reproduce import run_reproduction; "
         "run_reproduction(sys.argv[1], scale='tiny', jobs=1, command=sys.argv[2:], progress=False)",
         str(out), *command], cwd=REPO)

    def hanging() -> bool:
        log = out / "logs" / f"{stage}.log"
        return log.exists() and "hanging" in log.read_text()

    try:
        _wait_for(hanging, 120, f"the {stage} stage to start")
        running = read_state(out)
        index = [s["name"] for s in running["stages"]].index(stage)
        assert [s["status"] for s in running["stages"][:index + 1]] == ["done"] * index + ["running"]
        driver.send_signal(signal.SIGKILL)
        driver.wait(timeout=30)
    finally:
        if driver.poll() is None:
            driver.kill()
    killed = read_state(out)
    pgid = killed["stages"][index]["pgid"]
    _wait_for(lambda: not group_alive(pgid), 30, "the stage's process to die with the reproduction")
    monkeypatch.delenv("FAKE_HANG")
    return killed


def test_resume_after_a_kill_continues_the_unfinished_stage_and_runs_only_the_later_ones(tmp_path, fake,
                                                                                           monkeypatch):
    command, launches = fake
    out = tmp_path / "repro"
    _kill_during(out, command, "low_open", monkeypatch)  # stage 4 of the plan
    before = launches()
    assert [_stage_of(x) for x in before] == ["clouds", "encoder", "low_demos", "low_open"]
    killed_at = time.time()

    result = run_reproduction(out, resume=True, jobs=1, command=command, progress=False)
    after = launches()[len(before):]
    names = [_stage_of(x) for x in after]
    plan = [s["name"] for s in result.state["stages"]]
    assert names[0] == "low_open" and "--resume" in after[0]["argv"]  # its own --resume: it had a checkpoint
    assert sorted(names) == sorted(plan[3:]) and len(names) == len(set(names))  # the later stages, once each
    assert all(x["t"] > killed_at for x in after)
    assert result.ran == names
    state = read_state(out)
    by = {s["name"]: s for s in state["stages"]}
    assert all(s["status"] == "done" for s in state["stages"])
    for name in ("clouds", "encoder", "low_demos"):  # not run again: one session, ended before the kill
        assert len(by[name]["sessions"]) == 1 and by[name]["ended_unix"] < killed_at
    first, second = by["low_open"]["sessions"]
    assert first["returncode"] == "killed" and not first["resumed"] and first["wall_time_s"] >= 0
    assert second["resumed"] and second["argv"][-1] == "--resume" and second["started_unix"] > killed_at
    assert by["low_open"]["wall_time_s"] == pytest.approx(first["wall_time_s"] + second["wall_time_s"], abs=1e-3)
    for name in plan[4:]:
        assert len(by[name]["sessions"]) == 1 and by[name]["started_unix"] > killed_at
    assert len(state["sessions"]) == 2 and state["sessions"][0]["killed"] and state["sessions"][1]["resume"]
    # the products perceived through the linked assets; the shipped evaluations through the checkout's
    assets = {_stage_of(x): x["assets"] for x in launches()}
    assert assets["low_open"] == str(out.resolve() / "assets") and assets["encoder"] is None
    assert assets["eval_low_shipped"] is None and assets["eval_low_reproduced"] == str(out.resolve() / "assets")
    # the table: both sides of every product, and the stages' times
    table = pd.read_csv(out / "reproduce.csv")
    high = ["high level (phase clone DAgger starts from)"] * 2 + ["high level (DAgger, high_level.zip)"] * 2
    assert list(table["product"]) == ["encoder", "encoder", "low level", "low level", *high]
    assert list(table["reproduced_path"].iloc[4:]) == [str(out.resolve() / "stages" / "high" / f)
                                                       for f in ("base.zip", "base.zip", "model.zip", "model.zip")]
    assert (table["stages"].iloc[4:] == "high").all()  # the one DAgger run makes both: its wall time for both
    assert (table["wall_time_s"].iloc[4:] == round(by["high"]["wall_time_s"], 1)).all()
    assert table["reproduced_value"].iloc[0] == pytest.approx(table["shipped_value"].iloc[0])  # the same encoder
    assert table["reproduced_k"].iloc[2] == 1 and table["reproduced_n"].iloc[2] == 2
    md = (out / "reproduce.md").read_text()
    assert "## The stages" in md and "low_open" in md and result.summary.startswith("Reproduced the shipped set")
    assert "share the `high` stage's wall time" in md
    # everything done: a resume runs nothing and writes the table again
    again = run_reproduction(out, resume=True, jobs=1, command=command, progress=False)
    assert again.ran == [] and len(launches()) == len(before) + len(after)


def test_a_dagger_stage_killed_part_way_resumes_keeping_its_fitted_base(tmp_path, fake, monkeypatch):
    command, launches = fake
    out = tmp_path / "repro"
    killed = _kill_during(out, command, "high", monkeypatch)
    base = out / "stages" / "high" / "base.zip"
    fitted = base.read_text()  # fitted in the killed session
    before = len(launches())
    result = run_reproduction(out, resume=True, jobs=1, command=command, progress=False)
    after = launches()[before:]
    assert _stage_of(after[0]) == "high" and after[0]["argv"][-1] == "--resume"  # DAgger's own --resume
    assert after[0]["argv"][:-1] == list(P.plan_stages(out, "tiny")[6].argv)  # the recorded command, resumed
    assert base.read_text() == fitted  # its folder kept: the prior and base.zip were not made again
    by = {s["name"]: s for s in result.state["stages"]}
    assert [x["resumed"] for x in by["high"]["sessions"]] == [False, True] and by["high"]["status"] == "done"
    # then the stages not done at the kill, once each, in plan order (jobs=1)
    assert [_stage_of(x) for x in after] == [x["name"] for x in killed["stages"] if x["status"] != "done"]


def test_a_failed_stage_names_its_log_and_stops_the_stages_after_it(tmp_path, fake, monkeypatch):
    command, launches = fake
    out = tmp_path / "repro"
    monkeypatch.setenv("FAKE_FAIL", "encoder")
    with pytest.raises(HingelabError) as error:
        run_reproduction(out, scale="tiny", jobs=2, command=command, progress=False)
    message = str(error.value)
    assert "stage encoder failed (exit 3: boom: a fake failure)" in message
    assert str(out.resolve() / "logs" / "encoder.log") in message and "--resume" in message
    assert "\n" not in message
    by = {s["name"]: s for s in read_state(out)["stages"]}
    assert by["encoder"]["status"] == "failed" and by["low_demos"]["status"] == "pending"
    assert "encoder" in [_stage_of(x) for x in launches()] and "low_demos" not in [_stage_of(x) for x in launches()]
    assert not (out / "reproduce.md").exists()


def test_the_one_line_errors(tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "something").write_text("x")
    assert main(["reproduce", "--out", str(taken), "--scale", "tiny"]) == 1
    assert capsys.readouterr().err.strip() == (f"hingelab: error: --out {taken} exists and is not empty: it holds "
                                               "something, which is not a reproduction; give a new or empty folder "
                                               "for the reproduction")
    assert main(["reproduce", "--out", str(tmp_path / "none"), "--resume"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("hingelab: error: --resume: ") and "holds no reproduction (reproduce.json is missing)" in err
    assert main(["reproduce", "--out", str(tmp_path / "x"), "--jobs", "0"]) == 1
    assert "--jobs must be at least 1" in capsys.readouterr().err
    assert not (tmp_path / "none").exists() and not (tmp_path / "x").exists()
    started = tmp_path / "started"
    started.mkdir()
    (started / STATE_FILE).write_text(json.dumps({"format": "hingelab reproduce", "format_version": 1,
                                                  "scale": "tiny", "stages": [], "sessions": []}))
    assert main(["reproduce", "--out", str(started), "--resume", "--scale", "shipped"]) == 1
    assert "was started with --scale tiny, not shipped" in capsys.readouterr().err
    assert main(["reproduce", "--out", str(started)]) == 1
    assert "holds a reproduction; continue it with --resume" in capsys.readouterr().err
    old = tmp_path / "old"  # planned by an older hingelab: the phase clone, then RL over it
    old.mkdir()
    doc = new_state(old, "tiny")
    high = next(s for s in doc["stages"] if s["name"] == "high")
    doc["stages"][doc["stages"].index(high):doc["stages"].index(high) + 1] = [{**high, "name": "high_clone"},
                                                                              {**high, "name": "high_rl"}]
    write_state(old, doc)
    assert main(["reproduce", "--out", str(old), "--resume"]) == 1
    err = capsys.readouterr().err.strip()
    assert f"--resume: {old} was planned by another version of hingelab reproduce (stages this one no longer has: " \
           "high_clone, high_rl; none of this one's high); this one cannot finish it or make its table: start a new " \
           "--out" in err and "\n" not in err
    assert not (old / "logs").exists()  # refused before anything ran
    assert main(["reproduce", "--out", str(tmp_path / "p"), "--plan"]) == 0
    printed = capsys.readouterr().out
    assert "hingelab train encoder --epochs 24" in printed and not (tmp_path / "p").exists()


# ---------------------------------------------------------------------------- the real pipeline, tiny
@pytest.mark.slow
def test_tiny_reproduction_end_to_end(tmp_path):
    from hingelab.perception.encoder import load_encoder, shipped_encoder_fingerprint
    from hingelab.policies.sb3_zip import read_plain_data

    out = tmp_path / "repro"
    started = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "hingelab.cli.main", "reproduce", "--out", str(out), "--scale", "tiny",
                          "--no-progress"], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    assert run.returncode == 0, run.stderr[-3000:]
    print(f"tiny reproduction: {time.monotonic() - started:.0f} s")
    state = read_state(out)
    assert all(s["status"] == "done" and len(s["sessions"]) == 1 for s in state["stages"])
    table = pd.read_csv(out / "reproduce.csv")
    assert len(table) == 8 and table["shipped_value"].notna().all() and table["reproduced_value"].notna().all()
    assert "Reproduced the shipped set at --scale tiny" in run.stdout
    # the later stages learned on the reproduced encoder's latents, not the shipped one's
    reproduced = load_encoder(out / "stages" / "encoder" / "encoder.pt").fingerprint
    assert reproduced != shipped_encoder_fingerprint()
    for name in ("low_open", "low_closed"):
        plain, _ = read_plain_data(out / "stages" / name / "model.zip")
        assert plain["hingelab_provenance"]["encoder_fingerprint"] == reproduced
    # the high level: one DAgger run over the reproduced low level, its base clone fitted in the run, both kept
    high = out.resolve() / "stages" / "high"
    provenance = {}
    for name in ("base.zip", "model.zip"):
        with zipfile.ZipFile(high / name) as clone:
            provenance[name] = json.loads(clone.read("phase_clone.json"))["hingelab_provenance"]
        assert provenance[name]["encoder_fingerprint"] == reproduced
        assert provenance[name]["low_level"] == str(out.resolve() / "stages" / "low_experts" / "low_level_experts.json")
        assert provenance[name]["env_kwargs"]["tool_position"] == "relative"
    assert provenance["base.zip"]["fitted_by"] == "train high --learner dagger --base fit"
    assert provenance["model.zip"]["learner"] == "dagger" and provenance["model.zip"]["dagger"]["round"] == 1
    assert provenance["model.zip"]["dagger"]["base"]["path"] == str(high / "base.zip")
