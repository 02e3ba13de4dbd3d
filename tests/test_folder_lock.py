"""One writer per folder (``hingelab.folder_lock``): every command that writes a dataset, run or sweep
folder refuses, in one line naming the holder, a folder another command is writing (``--resume``
included), and leaves it as it was; a killed writer's lock is taken over."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import hingelab
from hingelab.cli.main import main
from hingelab.episodes.card import create_dataset
from hingelab.errors import FolderBusyError
from hingelab.folder_lock import LOCK_FILE, folder_lock, holder, is_empty
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag

PLATFORM = str(Path(hingelab.__file__).parent.parent)
HOLDER = ["generate", "heuristic", "--out", "SAME"]  # the command the test's own lock names


def _snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (the lock file left out) with its size."""
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != LOCK_FILE}


def _one_line_refusal(capsys, folder: Path) -> str:
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.strip()]
    assert err and "Traceback" not in "\n".join(err), err
    line = err[-1]
    assert line.startswith("hingelab: error: ") and str(folder) in line, line
    assert f"pid {os.getpid()}" in line and "hingelab generate heuristic --out SAME" in line, line
    return line


def _hold_in_child(folder: Path) -> subprocess.Popen:
    """A child process holding ``folder``'s lock (as ``train low``) until it is killed."""
    code = ("import sys, time\nfrom hingelab.folder_lock import folder_lock\n"
            "with folder_lock(sys.argv[1], ['train', 'low', '--out', sys.argv[1]]):\n"
            "    print('held', flush=True)\n    time.sleep(120)\n")
    child = subprocess.Popen([sys.executable, "-c", code, str(folder)], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": PLATFORM})
    assert child.stdout.readline().strip() == "held"
    return child


# ---------------------------------------------------------------------------- the lock itself
def test_a_second_writer_is_refused_naming_the_holder_and_the_lock_goes_with_the_block(tmp_path):
    folder = tmp_path / "data"
    with folder_lock(folder, HOLDER) as path:
        doc = json.loads(path.read_text())
        assert doc["pid"] == os.getpid() and doc["command"] == "hingelab generate heuristic --out SAME"
        assert holder(folder).startswith(f"pid {os.getpid()}: hingelab generate heuristic --out SAME, since ")
        assert is_empty(folder)  # the lock file alone: still a new, empty --out
        with pytest.raises(FolderBusyError, match=f"pid {os.getpid()}: hingelab generate heuristic"):
            with folder_lock(folder, ["generate", "heuristic", "--resume"]):
                pass
    assert holder(folder) is None and not (folder / LOCK_FILE).exists()
    assert not folder.exists()  # the lock made it and nothing was written into it
    (tmp_path / "kept").mkdir()
    with folder_lock(tmp_path / "kept"):
        (tmp_path / "kept" / "file").write_text("x")
    assert (tmp_path / "kept").is_dir() and not (tmp_path / "kept" / LOCK_FILE).exists()


def test_a_killed_writers_stale_lock_is_taken_over_and_its_holder_rewritten(tmp_path):
    folder = tmp_path / "run"
    child = _hold_in_child(folder)
    try:
        with pytest.raises(FolderBusyError, match=f"pid {child.pid}: hingelab train low --out {folder}"):
            with folder_lock(folder):
                pass
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert json.loads((folder / LOCK_FILE).read_text())["pid"] == child.pid  # stale: named, but not held
    assert holder(folder) is None
    with folder_lock(folder, ["train", "low", "--resume"]) as path:
        doc = json.loads(path.read_text())
        assert doc["pid"] == os.getpid() and doc["command"] == "hingelab train low --resume"


def test_a_stale_lock_file_does_not_make_a_new_out_look_used(tmp_path, capsys):
    out = tmp_path / "eval"
    out.mkdir()
    (out / LOCK_FILE).write_text(json.dumps({"pid": 999999, "command": "hingelab eval low", "started": "then"}))
    assert main(["eval", "low", "--baseline", "hold-still", "--episodes", "1", "--out", str(out), "--no-progress"]) == 0
    assert len(list((out / "episodes").glob("*.mcap"))) == 1 and not (out / LOCK_FILE).exists()


# ---------------------------------------------------------------------------- every writing command
@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    root = tmp_path_factory.mktemp("bag")
    write_rig_bag(root / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.3)], gap_s=0.2))
    return root / "bag"


def _dataset_with_a_write_under_way(folder: Path) -> None:
    create_dataset(folder, name="busy", source="heuristic", config={})
    (folder / "episodes" / "heuristic-20260101T000000-0123456789ab.mcap.partial").write_bytes(b"being written")


def _sweep_folder(folder: Path) -> Path:
    folder.mkdir()
    spec = folder / "sweep.toml"
    spec.write_text('[sweep]\ncommand = "train low"\nseeds = [0]\nargs = ["--steps", "20"]\ncpus_per_trial = 1\n\n'
                    "[conditions]\nplain = []\n")
    (folder / "plain_seed0").mkdir()  # a trial that has not reached its first checkpoint
    (folder / "plain_seed0" / "config.json").write_text("{}")
    return spec


COMMANDS = {
    "generate heuristic": (None, lambda d, bag: ["generate", "heuristic", "--episodes", "1", "--out", str(d),
                                                 "--no-progress"]),
    "generate clouds": (None, lambda d, bag: ["generate", "clouds", "--n", "2", "--per-episode", "1", "--out", str(d),
                                              "--no-progress"]),
    "datasets import-ros2": (None, lambda d, bag: ["datasets", "import-ros2", str(bag), "--out", str(d),
                                                   "--no-progress"]),
    "datasets recover": (_dataset_with_a_write_under_way, lambda d, bag: ["datasets", "recover", str(d),
                                                                          "--discard"]),
    "train low": (None, lambda d, bag: ["train", "low", "--out", str(d), "--steps", "20", "--no-progress"]),
    "train low --resume": (None, lambda d, bag: ["train", "low", "--out", str(d), "--resume", "--no-progress"]),
    "checkpoints convert": (None, lambda d, bag: ["checkpoints", "convert", str(d)]),
    "eval low": (None, lambda d, bag: ["eval", "low", "--baseline", "hold-still", "--episodes", "1", "--out", str(d),
                                       "--no-progress"]),
    "eval high": (None, lambda d, bag: ["eval", "high", "--baseline", "heuristic", "--episodes", "1", "--out", str(d),
                                        "--no-progress"]),
    "trial": (None, lambda d, bag: ["trial", "--trials", "1", "--out", str(d), "--no-progress"]),
    "sweep --resume": (_sweep_folder, lambda d, bag: ["sweep", str(d / "sweep.toml"), "--out", str(d), "--resume",
                                                      "--cpus", "1", "--no-progress"]),
    "reproduce --resume": (None, lambda d, bag: ["reproduce", "--out", str(d), "--resume", "--no-progress"]),
}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_command_refuses_a_folder_another_command_is_writing(name, tmp_path, small_bag, capsys):
    folder = tmp_path / "busy"
    prepare, argv = COMMANDS[name]
    if prepare is not None:
        prepare(folder)
    before = _snapshot(folder) if folder.exists() else {}
    with folder_lock(folder, HOLDER):
        assert main(argv(folder, small_bag)) == 1
        _one_line_refusal(capsys, folder)
        assert _snapshot(folder) == before  # nothing written, nothing deleted


def test_generate_resume_leaves_a_running_generates_episode_alone(tmp_path, capsys):
    """The issue's case: ``generate --resume`` beside a running generate deleted its in-flight .partial."""
    out = tmp_path / "demos"
    assert main(["generate", "heuristic", "--episodes", "1", "--out", str(out), "--no-progress"]) == 0
    in_flight = out / "episodes" / "heuristic-20260101T000000-0123456789ab.mcap.partial"
    in_flight.write_bytes(b"the running generate's episode")
    before = _snapshot(out)
    with folder_lock(out, HOLDER):
        assert main(["generate", "heuristic", "--episodes", "2", "--out", str(out), "--resume", "--no-progress"]) == 1
        _one_line_refusal(capsys, out)
    assert _snapshot(out) == before and in_flight.exists()


def test_sweep_resume_leaves_a_trial_someone_is_training_alone(tmp_path, capsys):
    """A trial folder whose ``train`` still runs (its own lock) is not deleted to start it again."""
    out = tmp_path / "sweep"
    spec = _sweep_folder(out)
    child = _hold_in_child(out / "plain_seed0")
    try:
        assert main(["sweep", str(spec), "--out", str(out), "--resume", "--cpus", "1", "--no-progress"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("hingelab: error: ") and f"pid {child.pid}: hingelab train low" in err[-1]
        assert str(out / "plain_seed0") in err[-1]
        assert (out / "plain_seed0" / "config.json").exists()
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()


def test_an_out_that_is_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("not a folder")
    assert main(["generate", "clouds", "--n", "2", "--out", str(tmp_path / "file"), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / 'file'} is a file" in err[0] and "give a folder" in err[0]
