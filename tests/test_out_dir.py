"""Every command that writes checks its output path first (``hingelab.out_dir``): a file where a folder goes,
or a place nothing can be written (``/proc``), is one error line, and nothing is written."""

from pathlib import Path

import pytest

from hingelab import out_dir
from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.out_dir import DATASET, REPORT, RUN, check_out, check_out_file

# each command with OUT where its output goes; the inputs need not exist: the output is checked first
WRITERS = {
    "generate heuristic": ["generate", "heuristic", "--episodes", "1", "--out", "OUT"],
    "generate clouds": ["generate", "clouds", "--n", "2", "--out", "OUT"],
    "datasets import-ros2": ["datasets", "import-ros2", "no_such_bag", "--out", "OUT"],
    "datasets export lerobot": ["datasets", "export", "no_such_dataset", "--format", "lerobot", "--out", "OUT"],
    "datasets export ros2": ["datasets", "export", "no_such_dataset", "--format", "ros2", "--out", "OUT"],
    "datasets export minari": ["datasets", "export", "no_such_dataset", "--format", "minari", "--out", "OUT"],
    "eval low": ["eval", "low", "--episodes", "1", "--out", "OUT"],
    "eval high": ["eval", "high", "--baseline", "heuristic", "--episodes", "1", "--out", "OUT"],
    "eval picks": ["eval", "picks", "--baseline", "scripted", "--episodes", "1", "--out", "OUT"],
    "eval perception": ["eval", "perception", "--episodes", "1", "--out", "OUT"],
    "trial": ["trial", "--trials", "1", "--out", "OUT"],
    "train low": ["train", "low", "--steps", "10", "--out", "OUT"],
    "train high": ["train", "high", "--steps", "10", "--out", "OUT"],
    "report": ["report", "no_such_dataset", "--out", "OUT"],
    "diagnose noise": ["diagnose", "noise", "--episodes", "1", "--out", "OUT"],
    "sweep": ["sweep", "no_such_sweep.toml", "--out", "OUT"],
    "reproduce": ["reproduce", "--out", "OUT"],
    "bench": ["bench", "sim", "--allow-dirty", "--out", "OUT"],
}
FILE_WRITERS = {  # outputs that are files: a folder there is refused, and a path under a file
    "view --save": ["view", "no_such_dataset", "--save", "OUT"],
    "train encoder": ["train", "encoder", "--data", "no_such_dataset", "--out", "OUT"],
    "compose low": ["compose", "low", "--expert", "a.zip:0.1", "--expert", "b.zip", "--out", "OUT"],
}


def _one_line_error(argv, capsys) -> str:
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("hingelab: error:"), err
    return err


@pytest.mark.parametrize("command", list(WRITERS))
def test_out_as_a_file_is_one_line(tmp_path, capsys, command):
    out = tmp_path / "a_file"
    out.write_text("keep me\n")
    err = _one_line_error([str(out) if w == "OUT" else w for w in WRITERS[command]], capsys)
    assert "is a file" in err and str(out) in err
    assert out.read_text() == "keep me\n" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


@pytest.mark.parametrize("command", list(WRITERS) + list(FILE_WRITERS))
def test_out_under_proc_is_one_line(capsys, command):
    if not Path("/proc").is_dir():
        pytest.skip("no /proc here")
    out = "/proc/hingelab_out/x"
    argv = {**WRITERS, **FILE_WRITERS}[command]
    err = _one_line_error([out if w == "OUT" else w for w in argv], capsys)
    assert "/proc" in err and "cannot write" in err


@pytest.mark.parametrize("command", list(FILE_WRITERS))
def test_file_outputs_refuse_a_folder_and_a_path_under_a_file(tmp_path, capsys, command):
    err = _one_line_error([str(tmp_path) if w == "OUT" else w for w in FILE_WRITERS[command]], capsys)
    assert "is a folder" in err
    (tmp_path / "f").write_text("")
    err = _one_line_error([str(tmp_path / "f" / "x.out") if w == "OUT" else w for w in FILE_WRITERS[command]],
                          capsys)
    assert "is a file" in err
    assert [p.name for p in tmp_path.iterdir()] == ["f"]


def test_check_out_accepts_new_and_existing_folders_and_leaves_nothing(tmp_path):
    assert check_out(tmp_path / "new" / "deeper", DATASET) == tmp_path / "new" / "deeper"
    assert check_out(tmp_path, RUN) == tmp_path
    assert check_out_file(tmp_path / "x.rrd") == tmp_path / "x.rrd"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match="is a file"):
        check_out(tmp_path / "f" / "sub", REPORT)


@pytest.mark.parametrize("command", list(WRITERS))
def test_a_folder_of_other_files_is_one_line_and_untouched(tmp_path, capsys, command):
    """The one rule for a non-empty --out: only the command's own kind of folder; a thesis is nobody's."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.docx").write_bytes(b"keep me")
    err = _one_line_error([str(out) if w == "OUT" else w for w in WRITERS[command]], capsys)
    assert "is not empty" in err and "thesis.docx" in err and str(out) in err, err
    assert [p.name for p in out.iterdir()] == ["thesis.docx"]
    assert (out / "thesis.docx").read_bytes() == b"keep me"


@pytest.mark.parametrize("command", ["report", "train high", "generate heuristic", "sweep"])
def test_another_commands_folder_is_refused_by_name(tmp_path, capsys, command):
    out = tmp_path / "a_run"
    out.mkdir()
    (out / "run.json").write_text("{}")  # a run folder, even one whose files a report could hold
    argv = [str(out) if w == "OUT" else w for w in WRITERS[command]]
    if command == "train high":
        (out / "run.json").unlink()
        (out / "dataset.json").write_text("{}")
        assert "holds a dataset" in _one_line_error(argv, capsys)
    else:
        assert "holds a run (run.json)" in _one_line_error(argv, capsys)


def test_own_kinds_pass_the_check(tmp_path):
    (tmp_path / "dataset" / "episodes").mkdir(parents=True)
    (tmp_path / "dataset" / "notes.txt").write_text("")
    check_out(tmp_path / "dataset", DATASET)  # the command's own policy decides (e.g. --resume) from here
    (tmp_path / "report" / "sub").mkdir(parents=True)
    for name in ("picks.md", "picks.csv", "README.md", "frame.png", ".hingelab.lock"):
        (tmp_path / "report" / name).write_text("")
    check_out(tmp_path / "report", REPORT)
    (tmp_path / "report" / "model.zip").write_text("")
    with pytest.raises(ConfigError, match="model.zip, which is not a report"):
        check_out(tmp_path / "report", REPORT)
    (tmp_path / "empty_but_locked").mkdir()
    (tmp_path / "empty_but_locked" / ".hingelab.lock").write_text("")
    check_out(tmp_path / "empty_but_locked", out_dir.NEW)


def test_the_markers_are_the_writers_file_names():
    from hingelab.episodes.card import CARD_FILE
    from hingelab.rollouts.pick_sets import PICKS_FILE
    from hingelab.sweeps.reproduce import STATE_FILE
    from hingelab.sweeps.runner import SWEEP_TOML
    from hingelab.training.run_folder import CONFIG_FILE, RUN_FILE

    assert out_dir.DATASET.markers == (CARD_FILE, "episodes")
    assert out_dir.RUN.markers == (CONFIG_FILE, RUN_FILE)
    assert out_dir.SWEEP.markers == (SWEEP_TOML,)
    assert out_dir.REPRODUCTION.markers == (STATE_FILE,)
    assert out_dir.PICKS.markers == (PICKS_FILE,)
