"""Every command that writes checks its output path first (``hingelab.out_dir``): a file where a folder goes,
or a place nothing can be written (``/proc``), is one error line, and nothing is written."""

from pathlib import Path

import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.out_dir import check_out, check_out_file

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
    "eval perception": ["eval", "perception", "--episodes", "1", "--out", "OUT"],
    "trial": ["trial", "--trials", "1", "--out", "OUT"],
    "train low": ["train", "low", "--steps", "10", "--out", "OUT"],
    "train high": ["train", "high", "--steps", "10", "--out", "OUT"],
    "report": ["report", "no_such_dataset", "--out", "OUT"],
    "diagnose noise": ["diagnose", "noise", "--episodes", "1", "--out", "OUT"],
    "sweep": ["sweep", "no_such_sweep.toml", "--out", "OUT"],
    "reproduce": ["reproduce", "--out", "OUT"],
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
    assert check_out(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert check_out(tmp_path) == tmp_path
    assert check_out_file(tmp_path / "x.rrd") == tmp_path / "x.rrd"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match="is a file"):
        check_out(tmp_path / "f" / "sub")
