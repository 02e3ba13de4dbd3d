"""``hingelab bench reliability``: many hands on one folder, tried as an adversarial user would.

Each probe runs real ``hingelab`` processes in a fresh temporary folder (``probe_runner``) and records
their exit codes, any Python traceback, any write outside their ``--out``, and for the probes that
write episodes the episodes expected against those found, duplicated and lost. The probes:

- a crafted dataset whose episode id is a path (``../../x``, an absolute one) given to
  ``datasets export --format ros2`` and ``datasets verify``;
- two ``generate heuristic --out SAME`` started together; ``generate --resume`` while a generate writes
  the same folder;
- ``train low`` killed (SIGKILL, after a checkpoint and a few episodes past it) and resumed, against an
  uninterrupted run of the same settings, episode for episode;
- seeds -1, 2**32 and 10**14 on the commands that take one;
- ``--out`` as an existing file, under ``/proc`` and a folder of someone else's files, on every kind of
  command that writes;
- a 1 GB sparse mesh file as ``--object mesh:PATH``;
- a dangling ``.mcap`` symlink and a symlink loop inside a dataset (``datasets verify``, ``info``,
  ``index``, ``report``);
- the same ROS 2 bag (``hingelab.ros2.rig_bag``'s synthetic rig bag) imported twice into one ``--out``.

The table has no baseline and no ratios: what counts is the totals line (probes run, tracebacks, writes
outside ``--out``, duplicated and lost episodes), all zero when every probe passes. A probe that cannot
run here is listed as not run with the reason, never as passed.
"""

from __future__ import annotations

import functools
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hingelab.bench.probe_runner import KILLED, NotRun, ProbeResult, ProbeRun
from hingelab.bench.table import BenchTable
from hingelab.episodes.card import INDEX_FILE, create_dataset
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag

# what the probes try: the commands' guards (the CLI, --out, locks, names from data, bounded reads, seeds),
# the dataset and run folders they write, the ROS 2 import and the training's resume
MEASURES = ("platform/hingelab/cli", "platform/hingelab/folder_lock.py", "platform/hingelab/safe_names.py",
            "platform/hingelab/bounded_reads.py", "platform/hingelab/arguments.py", "platform/hingelab/out_dir.py",
            "platform/hingelab/seeds.py", "platform/hingelab/json_text.py", "platform/hingelab/episodes",
            "platform/hingelab/ros2", "platform/hingelab/training", "platform/hingelab/learners/sac",
            "platform/hingelab/rollouts/heuristic_demos.py", "platform/hingelab/sim/mesh_objects.py")

BAG_TRIALS = 2
RESUMED_EPISODES = 24  # about 30 s of generating: the --resume's start-up (seconds, loaded) ends well inside
SYNTHETIC_EPISODES = 2
# train low at toy scale: one env in-process, 10-step episodes, a checkpoint every 30 env steps, evaluations at
# the start and the end only
EPISODE_STEPS, CHECKPOINT_EVERY = 10, 30
TINY_TRAIN_LOW = ("train", "low", "--steps", "80", "--envs", "1", "--in-process", "--max-episode-steps",
                  str(EPISODE_STEPS), "--learning-starts", "30", "--batch-size", "16", "--buffer-size", "2000",
                  "--eval-every", "10000", "--eval-goals", "1", "--checkpoint-every", str(CHECKPOINT_EVERY),
                  "--keep-checkpoints", "10", "--algorithm", "sac", "--net-arch", "16", "--no-progress")


@dataclass(frozen=True)
class Probe:
    name: str
    play: Callable[[ProbeRun], None]  # sets up its inputs, runs its commands, names what to check
    quick: bool = False  # in ``--quick``'s short run


# ---------------------------------------------------------------------------------------- names from data
def _export_crafted_id(s: ProbeRun, absolute: bool) -> None:
    nest = s.work / "a" / "b" / "c"  # deep enough that ../.. from its out stays inside the probe's folder
    crafted = nest / "crafted"
    value = str(s.work / "abs_target") if absolute else "../../x"
    create_dataset(crafted, name="crafted", source="synthetic", seed=0, config={})
    write_synthetic_episode(crafted, 0, n_steps=3, extra_metadata={"episode_id": value})
    s.allow(crafted / INDEX_FILE)
    out = s.out_at(nest / "out")
    s.hingelab("datasets", "export", s.rel(crafted), "--format", "ros2", "--out", s.rel(out), expect=(1,))
    s.hingelab("datasets", "verify", s.rel(crafted), expect=(1,))


# ---------------------------------------------------------------------------------------- one writer per folder
def _generate(episodes: int, *more: str) -> tuple[str, ...]:
    return ("generate", "heuristic", "--episodes", str(episodes), "--out", "out", "--no-progress", *more)


def _two_generates_together(s: ProbeRun) -> None:
    first, second = s.start(*_generate(2), expect=(0, 1)), s.start(*_generate(2), expect=(0, 1))
    s.wait(first)
    s.wait(second)
    if sorted((first.returncode, second.returncode)) != [0, 1]:
        s.problem(f"exits {first.returncode} and {second.returncode}: one writer, one refusal is right")
    s.expect_episodes(s.out, expected=2)


def _resume_while_generating(s: ProbeRun) -> None:
    first = s.start(*_generate(RESUMED_EPISODES))  # long enough to outlast the --resume's start-up
    episodes = s.out / "episodes"
    s.wait_until(lambda: not first.running or (episodes.is_dir() and any(episodes.glob("*.partial"))), 600)
    if not first.running:
        s.give_up("the generate ended before an episode was under way")
    done = len(list(episodes.glob("*.mcap")))
    resume = s.hingelab(*_generate(RESUMED_EPISODES, "--resume"), expect=(1,))
    if not first.running and "being written" not in resume.last_error_line:
        s.give_up("the generate ended before --resume looked at the folder: the two did not meet")
    s.note(f"--resume started while the generate wrote episode {done + 1} of {RESUMED_EPISODES} (.partial)")
    s.wait(first)
    s.expect_episodes(s.out, expected=RESUMED_EPISODES)


# ---------------------------------------------------------------------------------------- kill and resume
def _kill_and_resume_train_low(s: ProbeRun) -> None:
    reference = s.work / "uninterrupted"
    s.allow(reference)
    s.hingelab(*TINY_TRAIN_LOW, "--out", s.rel(reference))
    run = s.start(*TINY_TRAIN_LOW, "--out", "out", expect=(KILLED,))
    episodes, checkpoints = s.out / "dataset" / "episodes", s.out / "checkpoints"

    def past_a_checkpoint() -> bool:  # the first checkpoint, and an episode finished after those it covers
        return ((checkpoints / f"step_{CHECKPOINT_EVERY:012d}").is_dir()
                and len(list(episodes.glob("*.mcap"))) > CHECKPOINT_EVERY // EPISODE_STEPS)

    s.wait_until(lambda: not run.running or past_a_checkpoint(), 600)
    if not run.running:
        s.wait(run)
        s.give_up(f"train low ended (exit {run.returncode}) before it could be killed past a checkpoint")
    s.kill(run)
    on_disk = len(list(episodes.glob("*.mcap")))
    newest = max(p.name for p in checkpoints.iterdir() if p.name.startswith("step_"))
    s.note(f"killed with {on_disk} episodes on disk, newest checkpoint {newest}")
    s.hingelab("train", "low", "--out", "out", "--resume", "--no-progress")
    s.expect_episodes(s.out / "dataset", like=reference / "dataset")


# ---------------------------------------------------------------------------------------- numbers at the door
SEEDED = {
    "generate heuristic": ("generate", "heuristic", "--episodes", "1", "--no-progress"),
    "train low": ("train", "low", "--steps", "10", "--no-progress"),
    "eval low": ("eval", "low", "--episodes", "1", "--no-progress"),
}


def _seed(s: ProbeRun, command: str, seed: int) -> None:
    s.hingelab(*SEEDED[command], f"--seed={seed}", "--out", "out", expect=(2,))


# ---------------------------------------------------------------------------------------- unusable --out
def _writers(s: ProbeRun, out: str) -> dict[str, Callable[[], tuple[str, ...]]]:
    """Each kind of writing command with ``out`` where its output goes (inputs made only when used)."""
    return {
        "generate heuristic": lambda: ("generate", "heuristic", "--episodes", "1", "--out", out, "--no-progress"),
        "generate clouds": lambda: ("generate", "clouds", "--n", "2", "--per-episode", "1", "--out", out,
                                    "--no-progress"),
        "datasets import-ros2": lambda: ("datasets", "import-ros2", s.rel(s.input("bag")), "--out", out,
                                         "--no-progress"),
        "datasets export lerobot": lambda: ("datasets", "export", s.rel(s.input("dataset")), "--format", "lerobot",
                                            "--out", out),
        "datasets export ros2": lambda: ("datasets", "export", s.rel(s.input("dataset")), "--format", "ros2",
                                         "--out", out),
        "eval high": lambda: ("eval", "high", "--baseline", "heuristic", "--episodes", "1", "--out", out,
                              "--no-progress"),
        "train low": lambda: ("train", "low", "--steps", "10", "--out", out, "--no-progress"),
        "report": lambda: ("report", s.rel(s.input("dataset")), "--out", out),
        "view --save": lambda: ("view", s.rel(s.input("dataset")), "--save", f"{out}/recording.rrd"),
    }


WRITERS = ("generate heuristic", "generate clouds", "datasets import-ros2", "datasets export lerobot",
           "datasets export ros2", "eval high", "train low", "report", "view --save")
PROC_OUT = Path("/proc/hingelab_out/x")


def _out_is_a_file(s: ProbeRun, command: str) -> None:
    s.out.write_text("a file where a folder goes: it must stay as it is\n")
    s.hingelab(*_writers(s, "out")[command](), expect=(1,))


def _out_under_proc(s: ProbeRun, command: str) -> None:
    if not Path("/proc").is_dir():
        s.give_up("no /proc on this machine")
    s.out_at(PROC_OUT)
    s.hingelab(*_writers(s, str(PROC_OUT))[command](), expect=(1,))


def _out_holds_other_files(s: ProbeRun, command: str) -> None:
    s.out.mkdir()
    thesis = s.out / "thesis.docx"
    thesis.write_bytes(b"somebody's work: it must stay as it is")
    s.hingelab(*_writers(s, "out")[command](), expect=(1,))
    held = sorted(p.name for p in s.out.iterdir())
    if held != ["thesis.docx"] or thesis.read_bytes() != b"somebody's work: it must stay as it is":
        s.problem(f"--out now holds {held}")


# ---------------------------------------------------------------------------------------- bounded inputs
def _huge_mesh(s: ProbeRun) -> None:
    mesh = s.input_dir / "huge.stl"
    with open(mesh, "wb") as f:
        f.truncate(1 << 30)
    if mesh.stat().st_blocks * 512 > 1 << 20:
        mesh.unlink()
        s.give_up("this file system does not keep sparse files (a 1 GB mesh would take 1 GB of disk)")
    command = s.hingelab("generate", "heuristic", "--object", f"mesh:{s.rel(mesh)}", "--episodes", "1", "--out", "out",
                         "--no-progress", expect=(1,))
    s.note(f"refused after {command.seconds:.1f} s, the process's start-up included")


def _dangling_symlinks(s: ProbeRun) -> None:
    data = s.input("dataset", "linked")
    (data / "episodes" / "gone.mcap").symlink_to(s.input_dir / "moved_away.mcap")
    (data / "episodes" / "loop.mcap").symlink_to(data / "episodes" / "loop.mcap")
    for verb in ("verify", "info", "index"):
        s.hingelab("datasets", verb, s.rel(data), expect=(1,))
    s.hingelab("report", s.rel(data), "--out", "out", expect=(1,))


# ---------------------------------------------------------------------------------------- idempotent imports
def _import_twice(s: ProbeRun) -> None:
    bag = s.input("bag")
    for _ in range(2):
        again = s.hingelab("datasets", "import-ros2", s.rel(bag), "--out", "out", "--no-progress")
    said = [line for line in again.stdout.splitlines() if "already in" in line]
    s.note("the second import: " + (said[0] if said else "(no line about trials already in --out)"))
    s.expect_episodes(s.out, expected=BAG_TRIALS)


P = functools.partial
PROBES: list[Probe] = [
    Probe("crafted episode id ../../x: export ros2, verify", P(_export_crafted_id, absolute=False), quick=True),
    Probe("crafted episode id, an absolute path: export ros2, verify", P(_export_crafted_id, absolute=True)),
    Probe("two generate heuristic --out SAME started together", _two_generates_together),
    Probe("generate --resume while a generate writes the folder", _resume_while_generating),
    Probe("train low killed past a checkpoint, then --resume", _kill_and_resume_train_low),
    *(Probe(f"--seed {seed}: {command}", P(_seed, command=command, seed=seed), quick=command == "train low")
      for seed in (-1, 2**32, 10**14) for command in SEEDED),
    *(Probe(f"--out a file: {command}", P(_out_is_a_file, command=command), quick=command == "generate clouds")
      for command in WRITERS),
    *(Probe(f"--out under /proc: {command}", P(_out_under_proc, command=command), quick=command == "report")
      for command in WRITERS),
    *(Probe(f"--out a folder of other files: {command}", P(_out_holds_other_files, command=command),
            quick=command == "train low")
      for command in WRITERS if command != "view --save"),
    Probe("1 GB sparse mesh as --object mesh:PATH", _huge_mesh, quick=True),
    Probe("dangling .mcap symlink and a symlink loop: verify, info, index, report", _dangling_symlinks),
    Probe("the same ROS 2 bag imported twice into one --out", _import_twice),
]


# ---------------------------------------------------------------------------------------- running and the table
class SharedInputs:
    """Inputs made once per bench run under ``folder`` (a probe works on its own copy): ``dataset``, two
    synthetic episodes; ``bag``, a rig's ROS 2 bag of ``BAG_TRIALS`` short trials."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.made: dict[str, Path] = {}

    def __call__(self, kind: str) -> Path:
        if kind not in self.made:
            path = self.folder / kind
            if kind == "dataset":
                create_dataset(path, name="dataset", source="synthetic", seed=0, config={})
                for seed in range(SYNTHETIC_EPISODES):
                    write_synthetic_episode(path, seed, n_steps=4)
            elif kind == "bag":
                write_rig_bag(path, RigBagSpec(trials=[RigTrial(duration_s=0.3)] * BAG_TRIALS, gap_s=0.2))
            else:
                raise KeyError(f"no shared input {kind!r}")
            self.made[kind] = path
        return self.made[kind]


def run_probe(probe: Probe, number: int, base: Path, inputs: SharedInputs) -> ProbeResult:
    """One probe in its own folder under ``base``; never raises (a probe's own failure is its result)."""
    folder = f"p{number:02d}"
    s = ProbeRun(base / folder, base, base / "logs" / folder, inputs)
    started, not_run = time.perf_counter(), None
    try:
        probe.play(s)
    except NotRun as exc:
        not_run = str(exc)
    except Exception as exc:  # noqa: BLE001 - the bench's own mistake: said in the table, the other probes still run
        reason = f"the probe itself failed ({type(exc).__name__}: {exc})"
        if s.commands:
            s.problem(reason)
        else:
            not_run = reason
    return s.finish(probe.name, started, not_run)


def run(quick: bool = False, probes: list[Probe] | None = None, progress: bool = True) -> BenchTable:
    """Every probe (``quick``: the short list; ``probes``: these), one after another, into one table."""
    chosen = probes if probes is not None else [p for p in PROBES if p.quick or not quick]
    base = Path(tempfile.mkdtemp(prefix="hingelab_bench_reliability_"))
    results = []
    try:
        inputs = SharedInputs(base / "shared")
        for k, probe in enumerate(chosen):
            results.append(run_probe(probe, k, base, inputs))
            if progress:
                r = results[-1]
                print(f"[{k + 1}/{len(chosen)}] {r.status}: {r.name} ({r.seconds:.1f} s)", flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    return table(results, quick=quick and probes is None)


def totals(results: list[ProbeResult]) -> dict[str, int]:
    ran = [r for r in results if r.status != "not run"]
    return {
        "probes": len(results),
        "probes run": len(ran),
        "not run": len(results) - len(ran),
        "failed": sum(r.status == "FAIL" for r in results),
        "commands": sum(len(r.commands) for r in results),
        "tracebacks": sum(r.tracebacks for r in results),
        "writes outside --out": sum(len(r.outside_writes) for r in results),
        "duplicated episodes": sum(r.duplicated for r in results),
        "lost episodes": sum(r.lost for r in results),
    }


def verdict(table: BenchTable) -> str | None:
    """None when no probe failed, else one line saying how many and what they found."""
    t = table.totals
    if not t.get("failed"):
        return None
    return (f"{t['failed']} of {t['probes run']} reliability probes failed (tracebacks {t['tracebacks']}, writes "
            f"outside --out {t['writes outside --out']}, duplicated episodes {t['duplicated episodes']}, lost "
            f"episodes {t['lost episodes']}); each failed probe's detail says what")


COLUMNS = ["probe", "commands", "exit", "tracebacks", "writes outside --out", "episodes expected", "episodes found",
           "duplicated", "lost", "s", "outcome", "detail"]


def table(results: list[ProbeResult], quick: bool = False) -> BenchTable:
    rows = []
    for r in results:
        checked = r.episodes_expected is not None
        rows.append({
            "probe": r.name, "commands": " ; ".join(r.commands),
            "exit": ", ".join("killed" if e == KILLED else str(e) for e in r.exits),
            "tracebacks": r.tracebacks, "writes outside --out": len(r.outside_writes),
            "episodes expected": r.episodes_expected if checked else "", "episodes found":
                r.episodes_found if checked else "", "duplicated": r.duplicated if checked else "",
            "lost": r.lost if checked else "", "s": round(r.seconds, 1), "outcome": r.status, "detail": r.detail,
            "outside_write_paths": r.outside_writes,
        })
    notes = [
        "Each probe runs real `hingelab` processes (python -m hingelab.cli.main) in a fresh temporary folder: "
        "their working directory is its `work/` (the commands' relative paths are from there), their TMPDIR is "
        "inside it, and `work/decoy/` beside `work/out` holds a witness file.",
        "Writes outside --out: every file, link or folder added, changed or removed from a probe's first command "
        "until its last ended, anywhere under the bench's temporary root (every probe's folder, the shared "
        "inputs, the temporary directories) and among the entries of the repository's runs/ and datasets/, other "
        "than under the probe's --out and an input dataset's index cache; a probe whose commands are all meant "
        "to be refused must also leave its --out as it was.",
        "Episodes are read with hingelab.episodes.dataset.Dataset: duplicated = episodes whose seed another "
        "episode of the dataset has; lost = expected seeds not found (the kill probe: the uninterrupted run's "
        "seeds, by the same settings).",
        "A refusal passes when it exits with the right code (1; 2 for the parser's) and its last stderr line is "
        "`hingelab...error:` (quoted in detail); 'killed' is SIGKILL to the command's process group.",
    ]
    if quick:
        notes.append("--quick: the short list of probes, for tests")
    return BenchTable(
        name="reliability",
        title="Reliability: concurrent writers, crafted data, out-of-range numbers, unusable --out, unbounded inputs",
        columns=COLUMNS, rows=rows, notes=notes, totals=totals(results),
        config={"probes": [r.name for r in results], "quick": quick,
                "tiny_train_low": " ".join(TINY_TRAIN_LOW), "bag_trials": BAG_TRIALS},
    )

