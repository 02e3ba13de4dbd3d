"""One probe of ``hingelab bench reliability``: real ``hingelab`` processes in a fresh folder, and what they left.

A probe's commands run as subprocesses (``python -m hingelab.cli.main ARGS``, the hingelab this process
imports) in their own process group, with the probe's ``work/`` folder as their working directory and
their temporary directory (``TMPDIR``) inside the probe's folder. ``ProbeRun`` records:

- per command: its exit code against the ones that are right, whether its stdout or stderr holds a
  Python traceback, and, for a refusal, that it ends in one ``hingelab ... error:`` line;
- writes outside ``--out``: every file, link or folder added, changed or removed, from the probe's first
  command until its last ended, anywhere under the bench's temporary root (every probe's folder, the
  shared inputs, the temporary directories) and among the entries of the repository's ``runs/`` and
  ``datasets/`` (where commands write by default), other than under the probe's ``--out`` folders and
  the paths it allows (an input dataset's index cache, which reading a dataset may rebuild); a
  ``decoy/`` folder beside ``--out`` holds a witness file. Torch's own cache folder in the temporary
  directory (``torchinductor_USER``: ``import torch._dynamo``, which every torch optimizer does, makes it,
  one per user, reused by every run) is named in the probe's detail, not counted;
- a probe whose every command is meant to be refused must leave its ``--out`` as it was;
- per dataset the probe names: the episodes expected (a count, or an uninterrupted run's episodes)
  against those found with the project's reader (``hingelab.episodes.dataset.Dataset``), the
  duplicated ones (the same seed twice) and the lost ones.

A probe that cannot run here raises ``NotRun`` with the reason: it is listed as not run, never as passed.
"""

from __future__ import annotations

import fnmatch
import os
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

import hingelab
from hingelab.episodes.card import CARD_FILE, INDEX_FILE
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.paths import REPO_ROOT
from hingelab.sim.mesh_objects import MAX_MESH_MB_ENV

TRACEBACK = "Traceback (most recent call last)"
KILLED = -signal.SIGKILL  # the exit code of a command the probe killed
COMMAND_TIMEOUT_S = 900.0
PLATFORM_DIR = Path(hingelab.__file__).resolve().parent.parent
REPO_WITNESSES = (REPO_ROOT / "runs", REPO_ROOT / "datasets")  # where commands write when not told where
DETAIL_CHARS = 220
# third-party caches in TMPDIR, one per user and reused (not a run's leftovers): named, not counted
TEMP_CACHES = ("torchinductor_*",)


class NotRun(Exception):
    """The probe cannot be tried on this machine, or its timing did not give the case it tries (the reason)."""


@dataclass
class Command:
    """One ``hingelab`` process of a probe."""

    shown: str  # as the table gives it: paths relative to the probe's work folder, its working directory
    expect: tuple[int, ...]  # the exit codes that are right
    process: subprocess.Popen
    stdout_path: Path
    stderr_path: Path
    started: float
    seconds: float | None = None
    returncode: int | None = None
    timed_out: bool = False
    stdout: str = ""
    stderr: str = ""

    @property
    def traceback(self) -> bool:
        return TRACEBACK in self.stdout or TRACEBACK in self.stderr

    @property
    def last_error_line(self) -> str:
        lines = [line.strip() for line in self.stderr.splitlines() if line.strip()]
        return lines[-1] if lines else ""

    @property
    def running(self) -> bool:
        return self.process.poll() is None


@dataclass
class EpisodeCheck:
    dataset: Path
    expected: int | None = None  # a count of distinct episodes, or
    like: Path | None = None  # a dataset whose episodes (by key) these must be, each once
    key: str = "seed"


@dataclass
class ProbeResult:
    """What one probe found; ``status`` is "pass", "FAIL" or "not run"."""

    name: str
    status: str
    commands: list[str] = field(default_factory=list)
    exits: list[int | None] = field(default_factory=list)
    tracebacks: int = 0
    outside_writes: list[str] = field(default_factory=list)
    episodes_expected: int | None = None
    episodes_found: int | None = None
    duplicated: int = 0
    lost: int = 0
    seconds: float = 0.0
    detail: str = ""


def snapshot(base: Path, skip: Path | None = None) -> dict[Path, tuple]:
    """Every entry under ``base`` (symlinks not followed, ``skip`` left out): path -> (kind, size, mtime_ns) for
    files, (kind, target) for links, (kind,) for folders (whose times change with their entries); and the
    names in the repository's ``runs/`` and ``datasets/``."""
    found: dict[Path, tuple] = {}
    for folder, dirs, files in os.walk(base):
        here = Path(folder)
        dirs[:] = [d for d in dirs if here / d != skip]
        for name in dirs + files:
            path = here / name
            if path == skip:
                continue
            try:
                info = path.lstat()
            except FileNotFoundError:  # gone while walked
                continue
            if stat.S_ISLNK(info.st_mode):
                found[path] = ("link", os.readlink(path))
            elif stat.S_ISDIR(info.st_mode):
                found[path] = ("folder",)
            else:
                found[path] = ("file", info.st_size, info.st_mtime_ns)
    for witness in REPO_WITNESSES:
        if witness.is_dir():
            found.update({entry: ("entry",) for entry in witness.iterdir()})
    return found


def changed_paths(before: dict[Path, tuple], after: dict[Path, tuple]) -> list[Path]:
    """The outermost paths added, changed or removed (a new folder, not every file in it)."""
    changed = sorted(p for p in before.keys() | after.keys() if before.get(p) != after.get(p))
    outermost: list[Path] = []
    for path in changed:
        if not any(path.is_relative_to(kept) for kept in outermost):
            outermost.append(path)
    return outermost


class ProbeRun:
    """The folder and the commands of one probe: ``root/work`` (the commands' working directory, with
    ``out`` and ``decoy/``), ``root/inputs``, ``root/tmp`` (their ``TMPDIR``)."""

    def __init__(self, root: Path, base: Path, logs: Path, inputs: Callable[[str], Path]):
        self.root, self.base, self.logs, self._inputs = root, base, logs, inputs
        self.work, self.tmp, self.input_dir = root / "work", root / "tmp", root / "inputs"
        for folder in (self.work / "decoy", self.tmp, self.input_dir, logs):
            folder.mkdir(parents=True, exist_ok=True)
        (self.work / "decoy" / "witness.txt").write_text("a file beside --out that no command may touch\n")
        self.out = self.work / "out"
        self.outs: list[Path] = [self.out]
        self.allowed: list[Path] = []
        self.commands: list[Command] = []
        self.checks: list[EpisodeCheck] = []
        self.notes: list[str] = []
        self.problems: list[str] = []
        self.before: dict[Path, tuple] | None = None
        python_path = [str(PLATFORM_DIR)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
        self.env = {**{k: v for k, v in os.environ.items() if k != MAX_MESH_MB_ENV},  # the default limit
                    "PYTHONPATH": os.pathsep.join(python_path), "TMPDIR": str(self.tmp),
                    "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}

    # ------------------------------------------------------------------------------ paths and inputs
    def rel(self, path) -> str:
        """``path`` as the commands are given it: relative to their working directory when inside the probe."""
        path = Path(path)
        return os.path.relpath(path, self.work) if path.is_relative_to(self.root) else str(path)

    def out_at(self, path) -> Path:
        """Make ``path`` the probe's ``--out`` (instead of ``work/out``)."""
        self.out = Path(path)
        self.outs = [self.out]
        return self.out

    def allow(self, *paths) -> None:
        """Paths (files or folders) beside ``--out`` that the probe's commands may write."""
        self.allowed += [Path(p) for p in paths]

    def input(self, kind: str, name: str | None = None) -> Path:
        """A copy in ``inputs/`` of a shared input (``dataset``: two synthetic episodes; ``bag``: a rig's ROS 2
        bag of two trials); a dataset's index cache may be written."""
        target = self.input_dir / (name or kind)
        shutil.copytree(self._inputs(kind), target, symlinks=True)
        if (target / CARD_FILE).exists():
            self.allow(target / INDEX_FILE)
        return target

    # ------------------------------------------------------------------------------ commands
    def hingelab(self, *args, expect: tuple[int, ...] = (0,), timeout: float = COMMAND_TIMEOUT_S) -> Command:
        """Run ``hingelab ARGS`` to its end."""
        return self.wait(self.start(*args, expect=expect), timeout)

    def start(self, *args, expect: tuple[int, ...] = (0,)) -> Command:
        """Start ``hingelab ARGS`` and return at once."""
        args = [str(a) for a in args]
        return self.start_process([sys.executable, "-m", "hingelab.cli.main", *args], "hingelab " + shlex.join(args),
                                  expect)

    def start_process(self, argv: list[str], shown: str, expect: tuple[int, ...] = (0,)) -> Command:
        """Start any command as a probe's command (a test's deliberately broken probe)."""
        if self.before is None:  # the probe's set-up (its inputs) is done: from here on, writes count
            self.before = snapshot(self.base, self.logs)
        k = len(self.commands)
        stdout_path, stderr_path = self.logs / f"{k}.stdout", self.logs / f"{k}.stderr"
        with open(stdout_path, "wb") as stdout, open(stderr_path, "wb") as stderr:
            process = subprocess.Popen(argv, cwd=self.work, env=self.env, stdin=subprocess.DEVNULL, stdout=stdout,
                                       stderr=stderr, start_new_session=True)
        command = Command(shown, tuple(expect), process, stdout_path, stderr_path, time.perf_counter())
        self.commands.append(command)
        return command

    def wait(self, command: Command, timeout: float = COMMAND_TIMEOUT_S) -> Command:
        try:
            command.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            command.timed_out = True
            self._kill_group(command)
            command.process.wait()
        return self._finished(command)

    def kill(self, command: Command) -> Command:
        """SIGKILL to the command's process group (its own): as a crash, the OOM killer or a lost node would."""
        self._kill_group(command)
        command.process.wait()
        return self._finished(command)

    def wait_until(self, condition: Callable[[], bool], timeout: float, poll_s: float = 0.02) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if condition():
                return True
            time.sleep(poll_s)
        return condition()

    @staticmethod
    def _kill_group(command: Command) -> None:
        try:
            os.killpg(command.process.pid, signal.SIGKILL)  # the group it leads (start_new_session)
        except (ProcessLookupError, PermissionError):
            pass

    @staticmethod
    def _finished(command: Command) -> Command:
        if command.returncode is None:
            command.returncode = command.process.returncode
            command.seconds = time.perf_counter() - command.started
            command.stdout = command.stdout_path.read_text(errors="replace")
            command.stderr = command.stderr_path.read_text(errors="replace")
        return command

    # ------------------------------------------------------------------------------ what to check at the end
    def expect_episodes(self, dataset, expected: int | None = None, like=None, key: str = "seed") -> None:
        """At the end, ``dataset`` must hold ``expected`` episodes (or ``like``'s, by ``key``), each once."""
        self.checks.append(EpisodeCheck(Path(dataset), expected, None if like is None else Path(like), key))

    def note(self, text: str) -> None:
        self.notes.append(self.shorten(text))

    def problem(self, text: str) -> None:
        self.problems.append(self.shorten(text))

    def give_up(self, reason: str):
        raise NotRun(reason)

    def shorten(self, text: str) -> str:
        """``text`` on one line, at most ``DETAIL_CHARS``, the probe's folder as PROBE, the bench's root as TMP."""
        text = " ".join(text.replace(str(self.root), "PROBE").replace(str(self.base), "TMP").split())
        return text if len(text) <= DETAIL_CHARS else text[:DETAIL_CHARS - 3] + "..."

    def finish(self, name: str, started: float, not_run: str | None = None) -> ProbeResult:
        """Wait for what still runs, then compare the folders and count the episodes."""
        for command in self.commands:
            if command.returncode is None:
                self.wait(command)
        for command in self.commands:  # a child a command left behind (a worker) goes with its group
            self._kill_group(command)
        result = ProbeResult(name, "not run" if not_run else "pass", [c.shown for c in self.commands],
                             [c.returncode for c in self.commands])
        if self.before is not None:
            changed = changed_paths(self.before, snapshot(self.base, self.logs))
            inside = [p for p in changed if any(p.is_relative_to(o) for o in self.outs)]
            strays = [p for p in changed if p not in inside and not any(p.is_relative_to(a) for a in self.allowed)]
            caches = [p for p in strays if self._temp_cache(p)]
            if caches:
                strays = [p for p in strays if p not in caches]
                self.note("not counted: torch's cache folder " + ", ".join(self.shorten(str(p)) for p in caches)
                          + " in TMPDIR")
            result.outside_writes = [self.shorten(str(p)) for p in strays]
            if result.outside_writes:
                self.problem("wrote outside --out: " + ", ".join(result.outside_writes[:5]))
            if inside and all(0 not in c.expect for c in self.commands):  # every command refused: --out as it was
                self.problem("refused, yet --out changed: " + ", ".join(self.shorten(str(p)) for p in inside[:3]))
        self._check_commands(result)
        for check in self.checks:
            self._count_episodes(check, result)
        result.seconds = time.perf_counter() - started
        if not_run:
            result.detail = "; ".join([f"not run: {self.shorten(not_run)}", *self.problems, *self.notes])
        else:
            result.status = "FAIL" if self.problems or result.duplicated or result.lost else "pass"
            result.detail = "; ".join([*self.problems, *self.notes])
        return result

    def _temp_cache(self, path: Path) -> bool:
        if not path.is_relative_to(self.tmp) or path == self.tmp:
            return False
        top = path.relative_to(self.tmp).parts[0]
        return any(fnmatch.fnmatch(top, pattern) for pattern in TEMP_CACHES)

    def _check_commands(self, result: ProbeResult) -> None:
        for command in self.commands:
            result.tracebacks += command.traceback
            code = command.returncode
            if command.timed_out:
                self.problem(f"`{command.shown}` timed out (killed)")
            elif code not in command.expect:
                expected = " or ".join(str(e) for e in command.expect)
                self.problem(f"exit {code} where {expected} is right: {command.last_error_line}")
            if command.traceback:
                self.problem(f"a traceback from `{command.shown}`")
            elif code not in (0, KILLED) and not command.timed_out:
                line = command.last_error_line
                if line.startswith("hingelab") and "error:" in line:
                    self.note(f"exit {code}: {line}")
                else:
                    self.problem(f"exit {code} without a one-line error: {line or '(nothing)'}")

    def _count_episodes(self, check: EpisodeCheck, result: ProbeResult) -> None:
        try:
            found = _keys(check.dataset, check.key)
            wanted = None if check.like is None else _keys(check.like, check.key)
        except DatasetError as exc:
            self.problem(f"cannot read the episodes: {exc}")
            return
        distinct = set(found)
        result.episodes_found = (result.episodes_found or 0) + len(found)
        result.duplicated += len(found) - len(distinct)
        if wanted is None:
            result.episodes_expected = (result.episodes_expected or 0) + check.expected
            result.lost += max(0, check.expected - len(distinct))
            extra = max(0, len(distinct) - check.expected)
        else:
            result.episodes_expected = (result.episodes_expected or 0) + len(wanted)
            result.lost += len(set(wanted) - distinct)
            extra = len(distinct - set(wanted))
            if len(wanted) != len(set(wanted)):
                self.problem(f"the reference {self.rel(check.like)} holds a {check.key} twice")
        if extra:
            self.problem(f"{extra} episode(s) in {self.rel(check.dataset)} that should not be there")
        if (check.dataset / "episodes").is_dir():
            partial = len(Dataset(check.dataset).partial_files())
            if partial:
                self.problem(f"{partial} .partial file(s) left in {self.rel(check.dataset)}")


def _keys(dataset: Path, key: str) -> list:
    """Each episode's ``key`` (its seed) in ``dataset``, read with the project's reader (an episode without one:
    its file name); none if there is no dataset."""
    if not (dataset / CARD_FILE).exists():
        return []
    index = Dataset(dataset).index
    return [f"file {name}" if pd.isna(value) else value for value, name in zip(index[key], index["file"])]
