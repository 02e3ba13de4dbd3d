"""``hingelab sweep``: a grid of training runs (``sweep_file.SweepSpec``), one Ray task per trial.

Plain Ray tasks, not Ray Tune: every trial is already a complete, resumable hingelab run folder
(config, metrics, checkpoints with the replay buffer, rollouts), so Tune's trial directories,
checkpoint syncing and experiment state would be a second copy of what the run folder holds; a grid
needs no search algorithm or scheduler; and the core ``ray`` package is all it takes.

The sweep folder::

    DIR/sweep.toml              the sweep file as it was started
    DIR/sweep.json              what ran it: code version, Ray address, one entry per session
    DIR/sweep.csv               one row per trial: condition, seed, state, steps, wall time, final metrics
    DIR/logs/<trial>.log        the trial's output (every session appended)
    DIR/<condition>_seed<S>/    the trial's run folder, as `hingelab <command> --out` writes it

``sweep.csv`` is rewritten (atomically) whenever a trial starts or ends. ``--resume``: finished
trials are kept; a trial with a checkpoint continues from it (``hingelab <command> --resume``,
which refuses any change of the run's settings); a trial that stopped before its first checkpoint
starts again (nothing of it could be kept).
"""

from __future__ import annotations

import csv
import json
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError, HingelabError
from hingelab.folder_lock import is_empty, refuse_if_locked
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version
from hingelab.sweeps.spec import SweepSpec
from hingelab.sweeps.trial_task import run_trial
from hingelab.training import checkpoints as ckpt
from hingelab.training.run_folder import MetricsLog
from hingelab.workers.ray_runtime import LOCAL, cluster_cpus, describe, ray_session

SWEEP_CSV, SWEEP_JSON, SWEEP_TOML, LOGS_DIR = "sweep.csv", "sweep.json", "sweep.toml", "logs"
REFRESH_S = 5.0  # how often the live table looks at the run folders
COLUMNS = ["trial", "condition", "seed", "state", "env_steps", "steps", "wall_time_s", "sessions",
           "resumed_from_step", "returncode", "node", "run_dir"]


@dataclass
class TrialRecord:
    trial: str
    condition: str
    seed: int
    state: str = "pending"  # pending, queued, running, finished, failed, stopped
    env_steps: int = 0
    steps: int = 0
    wall_time_s: float = 0.0
    sessions: int = 0
    resumed_from_step: int | str = ""
    returncode: int | str = ""
    node: str = ""
    run_dir: str = ""
    final: dict = field(default_factory=dict)  # the last metrics.csv row (final_<column>)

    def row(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k != "final"}
        out["wall_time_s"] = round(self.wall_time_s, 1)
        return {**out, **{f"final_{k}": v for k, v in self.final.items()}}


# ---------------------------------------------------------------------------- the folder
def _metrics_rows(run_dir: Path) -> list[dict]:

    return MetricsLog(run_dir / "metrics.csv").rows()


def _progress(record: TrialRecord, run_dir: Path) -> None:
    """Steps done and planned, from the run folder (readable from any node: shared storage)."""

    config = run_dir / "config.json"
    if config.exists() and not record.steps:
        try:
            record.steps = int(json.loads(config.read_text())["config"]["steps"])
        except (OSError, ValueError, KeyError):
            pass
    rows = _metrics_rows(run_dir)
    steps = [int(float(rows[-1]["env_steps"]))] if rows else []
    latest = ckpt.latest_checkpoint(run_dir) if run_dir.is_dir() else None
    if latest is not None:
        steps.append(int(latest.name.split("_")[-1]))
    record.env_steps = max(steps, default=record.env_steps)
    if rows:
        record.final = {k: v for k, v in rows[-1].items() if k not in ("env_steps", "seed") and v != ""}


def write_sweep_csv(out: Path, records: list[TrialRecord]) -> Path:
    rows = [r.row() for r in records]
    columns = list(dict.fromkeys([*COLUMNS, *(k for r in rows for k in r)]))
    path = out / SWEEP_CSV
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)
    return path


def read_sweep_csv(out: Path) -> dict[str, dict]:
    path = out / SWEEP_CSV
    if not path.exists():
        return {}
    with open(path, newline="") as f:
        return {r["trial"]: r for r in csv.DictReader(f)}


def _start_folder(spec: SweepSpec, out: Path, resume: bool, address: str | None) -> None:
    record = out / SWEEP_TOML
    if resume:
        if not record.exists():
            raise ConfigError(f"--resume: {out} holds no sweep ({SWEEP_TOML} is missing); leave --resume out to "
                              "start one")
        if record.read_text() != spec.text:
            raise ConfigError(f"--resume: {spec.path} differs from {record}, the file this sweep was started with; "
                              f"resume with `hingelab sweep {record} --out {out} --resume`, or start a new --out")
    elif record.exists() or not is_empty(out):
        raise ConfigError(f"{out} is not empty; continue the sweep there with --resume, or give a new --out")
    out.mkdir(parents=True, exist_ok=True)
    (out / LOGS_DIR).mkdir(exist_ok=True)
    if not resume:
        record.write_text(spec.text)
    doc = json.loads((out / SWEEP_JSON).read_text()) if resume and (out / SWEEP_JSON).exists() else {
        "sweep_file": str(spec.path.resolve()), "command": spec.command, "seeds": list(spec.seeds),
        "conditions": {k: list(v) for k, v in spec.conditions.items()}, "cpus_per_trial": spec.cpus_per_trial,
        "trials": [t.name for t in spec.trials()], "sessions": []}
    doc["sessions"].append({**code_version(), "ray": address or LOCAL, "resume": resume,
                            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
    (out / SWEEP_JSON).write_text(strict_dumps(doc, out / SWEEP_JSON, indent=2) + "\n")


def _plan(spec: SweepSpec, out: Path, resume: bool) -> tuple[list[TrialRecord], dict[str, list[str]]]:
    """The trials' records (the previous session's kept) and the command line of every trial to run."""

    previous = read_sweep_csv(out) if resume else {}
    records, to_run = [], {}
    for trial in spec.trials():
        run_dir = out / trial.name
        old = previous.get(trial.name, {})
        record = TrialRecord(trial.name, trial.condition, trial.seed, run_dir=str(run_dir),
                             wall_time_s=float(old.get("wall_time_s") or 0), sessions=int(old.get("sessions") or 0),
                             node=old.get("node", ""))
        _progress(record, run_dir)
        records.append(record)
        if old.get("state") == "finished" and (run_dir / "model.zip").exists():
            record.state, record.returncode = "finished", old.get("returncode", 0)
            continue
        refuse_if_locked(run_dir)  # its train still runs (a sweep's whose driver died, or one started by hand)
        argv = [*trial.argv, "--out", str(run_dir.resolve())]
        latest = ckpt.latest_checkpoint(run_dir) if run_dir.is_dir() else None
        if latest is not None:
            argv.append("--resume")
            record.resumed_from_step = int(latest.name.split("_")[-1])
        elif run_dir.exists():  # stopped before its first checkpoint: nothing to continue from
            shutil.rmtree(run_dir)
            record.env_steps, record.final = 0, {}
        to_run[trial.name] = argv
    return records, to_run


# ---------------------------------------------------------------------------- the live table
def progress_table(records: list[TrialRecord]) -> str:
    lines = [f"{'trial':<28} {'state':<9} {'steps':>15} {'wall':>8} {'success':>8}"]
    for r in records:
        steps = f"{r.env_steps}/{r.steps}" if r.steps else str(r.env_steps)
        success = r.final.get("success_rate", "")
        success = f"{float(success):.2f}" if success != "" else "-"
        lines.append(f"{r.trial:<28} {r.state:<9} {steps:>15} {r.wall_time_s / 60:>7.1f}m {success:>8}")
    counts = {s: sum(r.state == s for r in records) for s in ("finished", "running", "queued", "failed")}
    lines.append(", ".join(f"{n} {s}" for s, n in counts.items() if n) or "nothing to run")
    return "\n".join(lines)


class LiveTable:
    """The progress table, printed when a trial's state changes (and, on a terminal, its steps)."""

    def __init__(self, records: list[TrialRecord], enabled: bool = True):
        self.records, self.enabled = records, enabled
        self.tty = sys.stdout.isatty()
        self.last = ""

    def show(self, force: bool = False) -> None:
        if not self.enabled:
            return
        text = progress_table(self.records)
        states = [r.state for r in self.records]
        if force or self.tty or states != getattr(self, "_states", None):
            if text != self.last:
                print(("\x1b[H\x1b[J" if self.tty else "") + text + "\n", flush=True)
                self.last = text
        self._states = states


# ---------------------------------------------------------------------------- the run
def run_sweep(spec: SweepSpec, out: Path, address: str | None = None, resume: bool = False,
              num_cpus: int | None = None, progress: bool = True) -> list[TrialRecord]:
    """Run (or resume) the sweep into ``out``; returns the trials' records. Raises ``HingelabError`` if a
    trial failed (the others ran to their end)."""

    out = Path(out)
    _start_folder(spec, out, resume, address)
    records, to_run = _plan(spec, out, resume)
    by_name = {r.trial: r for r in records}
    table = LiveTable(records, progress)
    write_sweep_csv(out, records)
    if not to_run:
        table.show(force=True)
        return records
    with ray_session(address, num_cpus) as ray:
        cpus = cluster_cpus(ray)
        if cpus < spec.cpus_per_trial:
            raise ConfigError(f"{spec.path}: cpus_per_trial = {spec.cpus_per_trial}, but {describe(address)} has "
                              f"{cpus} CPU(s); lower it or give the sweep more CPUs")
        task = ray.remote(num_cpus=spec.cpus_per_trial, max_retries=0)(run_trial)
        refs, log_sizes = {}, {}
        for name, argv in to_run.items():
            log = (out / LOGS_DIR / f"{name}.log").resolve()
            log_sizes[name] = log.stat().st_size if log.exists() else 0
            refs[task.remote(argv, str(log), spec.cpus_per_trial)] = name
            by_name[name].state = "queued"
        print(f"Sweep {out}: {len(to_run)} of {len(records)} trials to run on {describe(address)} with "
              f"{cpus} CPU(s), {spec.cpus_per_trial} per trial.", flush=True)
        write_sweep_csv(out, records)
        table.show(force=True)
        try:
            _wait(ray, refs, by_name, log_sizes, out, records, table)
        except BaseException:
            for ref, name in refs.items():
                ray.cancel(ref, force=True)
                if by_name[name].state in ("queued", "running"):
                    by_name[name].state = "stopped"
                _progress(by_name[name], out / name)
            write_sweep_csv(out, records)
            raise
    table.show(force=True)
    failed = [r for r in records if r.state == "failed"]
    if failed:
        first = failed[0]
        raise HingelabError(f"{len(failed)} of {len(records)} trials failed ({', '.join(r.trial for r in failed)}); "
                            f"see {out / LOGS_DIR / (first.trial + '.log')}: {_last_line(out, first.trial)}; "
                            f"the others are in {out / SWEEP_CSV}; fix it and run the sweep again with --resume")
    return records


def _wait(ray, refs: dict, by_name: dict, log_sizes: dict, out: Path, records: list, table: LiveTable) -> None:
    pending = list(refs)
    while pending:
        done, pending = ray.wait(pending, num_returns=1, timeout=REFRESH_S)
        for ref in done:
            record = by_name[refs[ref]]
            try:
                result = ray.get(ref)
            except Exception as exc:  # the worker died (node lost, killed): the trial can be resumed
                result = {"returncode": f"lost: {exc.__class__.__name__}", "wall_time_s": 0.0, "node": record.node}
            record.sessions += 1
            record.wall_time_s += float(result["wall_time_s"])
            record.returncode, record.node = result["returncode"], result["node"]
            record.state = "finished" if result["returncode"] == 0 else "failed"
            _progress(record, out / record.trial)
        for ref in pending:
            name = refs[ref]
            log = out / LOGS_DIR / f"{name}.log"
            if by_name[name].state == "queued" and log.exists() and log.stat().st_size > log_sizes[name]:
                by_name[name].state = "running"
            if by_name[name].state == "running":
                _progress(by_name[name], out / name)
        write_sweep_csv(out, records)
        table.show()


def _last_line(out: Path, trial: str) -> str:
    log = out / LOGS_DIR / f"{trial}.log"
    lines = [line for line in log.read_text(errors="replace").splitlines() if line.strip()] if log.exists() else []
    return lines[-1].strip() if lines else "no output"


def summary(spec: SweepSpec, out: Path, records: list[TrialRecord], seconds: float, address: str | None) -> str:

    per_condition = []
    for condition in spec.conditions:
        values = [float(r.final["success_rate"]) for r in records
                  if r.condition == condition and r.final.get("success_rate", "") != ""]
        if values:
            per_condition.append(f"{condition} {np.mean(values):.2f} over {len(values)} seed(s)")
    finished = sum(r.state == "finished" for r in records)
    return (f"Sweep {out}: {finished} of {len(records)} trials of `hingelab {spec.command}` finished "
            f"({len(spec.conditions)} condition(s) x {len(spec.seeds)} seed(s)) on {describe(address)} in "
            f"{seconds / 60:.1f} min of wall time ({sum(r.wall_time_s for r in records) / 60:.1f} min summed over "
            f"trials). Last evaluation's success: {'; '.join(per_condition) or 'none yet'}. Table: {out / SWEEP_CSV}; "
            f"curves by condition: hingelab report --runs {out} --out REPORTDIR.")


__all__ = ["run_sweep", "summary", "progress_table", "read_sweep_csv", "write_sweep_csv", "TrialRecord",
           "SWEEP_CSV", "SWEEP_JSON", "SWEEP_TOML", "LOGS_DIR"]
