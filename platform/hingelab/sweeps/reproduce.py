"""``hingelab reproduce``: the whole shipped set made again from scratch, stage by stage, resumable.

The stages (``hingelab.sweeps.reproduce_plan``) are the recipes of the shipped assets, each the
``hingelab`` command a user would type, run as a child process in dependency order, at most ``jobs`` at a
time: the tool clouds and the encoder, the low level's demonstrations, its two experts and their manifest,
the high level (one DAgger run, which fits its phase clone first); then the evaluations that compare each
product with the shipped asset (``eval low`` and ``eval high`` on the same seeds for both). The final table
(``hingelab.sweeps.reproduce_table``) is written when every stage is done.

The reproduction folder::

    DIR/reproduce.json     the state: per stage its command line, status (pending, running, done, failed),
                           start and end times, wall time, sessions, outputs; rewritten atomically
    DIR/stages/NAME/       each stage's own folder, as its command writes it (run folder, dataset, checkpoint)
    DIR/logs/NAME.log      each stage's output, every session appended under a header with its command line
    DIR/assets/            links to the checkout's assets, but checkpoints/encoder.pt: the reproduced encoder
    DIR/reproduce.md, .csv the table: each product against the shipped asset, and the wall time per stage

``resume``: a done stage is kept when its outputs exist (a missing output makes it, and every stage after
it, run again); an unfinished one (running when the process was killed, or failed) goes on with its
command's own ``--resume`` where the folder holds what that needs (``RESUME_KINDS``), else starts again in
an emptied folder; the stages after it then run. The commands recorded in ``reproduce.json`` are the ones
resumed: a reproduction goes on as it was started (one planned with other stages, by another version, is refused).

A stage's process dies with this one (``PR_SET_PDEATHSIG``) and is stopped with it (Ctrl-C, SIGTERM); a
stage still running from a killed reproduction is refused on resume until it has stopped.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from hingelab.errors import ConfigError, HingelabError
from hingelab.folder_lock import folder_lock, is_empty
from hingelab.json_text import finite_or_null
from hingelab.provenance import code_version
from hingelab.rollouts.journal import JOURNAL_FILE
from hingelab.sweeps.reproduce_plan import (
    LOGS_DIR,
    STAGES_DIR,
    comparison,
    link_assets,
    plan_stages,
    stage_environment,
)
from hingelab.sweeps.reproduce_table import write_tables
from hingelab.sweeps.trial_task import _die_with_parent
from hingelab.training.checkpoints import latest_checkpoint
from hingelab.training.run_folder import CONFIG_FILE

STATE_FILE = "reproduce.json"
FORMAT, FORMAT_VERSION = "hingelab reproduce", 1
STATUSES = ("pending", "running", "done", "failed")
POLL_S = 0.5
STOP_GRACE_S = 30.0  # a stopped stage's SIGTERM, then its SIGKILL


def hingelab_command() -> list[str]:
    """How a stage's command is run: this interpreter's ``hingelab``."""
    return [sys.executable, "-m", "hingelab.cli.main"]


def stamp(t: float) -> str:
    return datetime.fromtimestamp(t).astimezone().isoformat(timespec="seconds")


def now() -> tuple[str, float]:
    t = time.time()
    return stamp(t), t


def shell_line(env: dict, argv) -> str:
    """The command as a shell would take it: ``VAR=value ... hingelab ARGS``."""
    return "".join(f"{k}={shlex.quote(v)} " for k, v in env.items()) + "hingelab " + shlex.join(argv)


def last_sign_of_life(out: Path, paths) -> float:
    """When a killed process last wrote: the newest modification time of ``paths`` (logs, the state file)."""
    times = [p.stat().st_mtime for p in (Path(out) / q for q in paths) if p.exists()]
    return max(times, default=time.time())


# ---------------------------------------------------------------------------- the state file
def write_state(out: Path, doc: dict) -> None:
    """``reproduce.json``, atomically: a kill leaves the previous or the new file, never half of one."""
    path = Path(out) / STATE_FILE
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(json.dumps(finite_or_null(doc), indent=2, allow_nan=False) + "\n")  # a NaN figure: null
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)


def read_state(out: Path) -> dict:
    path = Path(out) / STATE_FILE
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read {path}: {exc}") from exc
    if doc.get("format") != FORMAT or doc.get("format_version") != FORMAT_VERSION:
        raise ConfigError(f"{path} is not a {FORMAT} state file of version {FORMAT_VERSION}")
    return doc


def new_state(out: Path, scale: str) -> dict:
    stages = []
    for stage in plan_stages(out, scale):
        env = stage_environment(stage, out)
        stages.append({**stage.to_dict(), "env": env, "status": "pending",
                       "command_line": shell_line(env, stage.argv),
                       "log": f"{LOGS_DIR}/{stage.name}.log", "started": None, "ended": None, "started_unix": None,
                       "ended_unix": None, "wall_time_s": 0.0, "sessions": [], "pgid": None, "error": None})
    created, _ = now()
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "scale": scale, "created": created,
            "comparison": comparison(scale), "sessions": [], "stages": stages, "table": None}


def open_folder(out: Path, scale: str | None, resume: bool) -> dict:
    """The state of a new reproduction in ``out`` (which must be new or empty), or of the one to resume."""
    out = Path(out)
    if resume:
        if not (out / STATE_FILE).exists():
            raise ConfigError(f"--resume: {out} holds no reproduction ({STATE_FILE} is missing); leave --resume out "
                              "to start one")
        doc = read_state(out)
        if scale is not None and scale != doc["scale"]:
            raise ConfigError(f"--resume: {out} was started with --scale {doc['scale']}, not {scale}; resume it "
                              f"without --scale, or start a new --out")
        recorded, planned = [s["name"] for s in doc["stages"]], [s.name for s in plan_stages(out, doc["scale"])]
        if recorded != planned:  # planned by another hingelab (the shipped recipes changed): its table is not ours
            gone, new = [n for n in recorded if n not in planned], [n for n in planned if n not in recorded]
            differ = "; ".join([*([f"stages this one no longer has: {', '.join(gone)}"] if gone else []),
                                *([f"none of this one's {', '.join(new)}"] if new else [])])
            raise ConfigError(f"--resume: {out} was planned by another version of hingelab reproduce "
                              f"({differ or 'its stages in another order'}); this one cannot finish it or make its "
                              "table: start a new --out")
        return doc
    if (out / STATE_FILE).exists():
        raise ConfigError(f"{out} holds a reproduction; continue it with --resume, or give a new --out")
    if out.exists() and (not out.is_dir() or not is_empty(out)):
        raise ConfigError(f"{out} is not empty; give a new or empty --out (or --resume a reproduction there)")
    return new_state(out, scale or "shipped")


# ---------------------------------------------------------------------------- a stage's launch
def can_resume(stage: dict, stage_dir: Path) -> bool:
    """Whether the stage's folder holds what its command's ``--resume`` continues from."""
    if not stage_dir.is_dir():
        return False
    kind = stage["resume"]
    if kind == "eval":
        return (stage_dir / "dataset.json").exists() and (stage_dir / JOURNAL_FILE).exists()
    if kind == "sac":
        return latest_checkpoint(stage_dir) is not None
    if kind == "dagger":  # its run folder: the rounds saved, the prior and base.zip (each made again if cut off)
        return (stage_dir / CONFIG_FILE).exists()
    return False


def _out_argument(argv: list[str]) -> str | None:
    return next((argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--out"), None)


def launch(stage: dict, out: Path, command: list[str]) -> subprocess.Popen:
    """Start the stage's command: resumed (``--resume``) where it can be, else afresh in an emptied folder."""
    stage_dir = out / STAGES_DIR / stage["name"]
    resumed = can_resume(stage, stage_dir)
    if not resumed and stage_dir.exists():
        shutil.rmtree(stage_dir)  # nothing of a stopped run to keep: the command starts it again
    if not resumed and _out_argument(stage["argv"]) != str(stage_dir):
        stage_dir.mkdir(parents=True)  # the command writes a file in the folder (train encoder, compose low)
    argv = [*stage["argv"], *(["--resume"] if resumed else [])]
    log = out / stage["log"]
    log.parent.mkdir(parents=True, exist_ok=True)
    started, started_unix = now()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", **stage["env"]}
    header = f"== {started}: {shell_line(stage['env'], argv)}\n"
    with open(log, "a+b") as f:
        if f.tell():  # a killed session's last line may be cut off (a progress bar): the header on a line of its own
            f.seek(-1, os.SEEK_END)
            header = ("" if f.read(1) == b"\n" else "\n") + header
        f.write(header.encode())
        f.flush()
        child = subprocess.Popen([*command, *argv], stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 env=env, start_new_session=True,
                                 preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
    if stage["started"] is None:
        stage["started"], stage["started_unix"] = started, started_unix
    stage.update(status="running", pgid=child.pid, error=None, ended=None, ended_unix=None)
    stage["sessions"].append({"started": started, "started_unix": started_unix, "ended": None, "wall_time_s": None,
                              "returncode": None, "resumed": resumed, "argv": argv})
    return child


def finish(stage: dict, out: Path, returncode, ended_unix: float | None = None) -> None:
    """Record the end of the stage's session (now, or at ``ended_unix``): done when it exited 0 and left its
    outputs."""
    ended, ended_unix = now() if ended_unix is None else (stamp(ended_unix), ended_unix)
    session = stage["sessions"][-1]
    session.update(ended=ended, wall_time_s=round(ended_unix - session["started_unix"], 3), returncode=returncode)
    stage.update(ended=ended, ended_unix=ended_unix, pgid=None,
                 wall_time_s=round(sum(s["wall_time_s"] or 0.0 for s in stage["sessions"]), 3))
    missing = [o for o in stage["outputs"] if not (out / o).exists()]
    if returncode == 0 and not missing:
        stage.update(status="done", error=None)
        return
    stage["status"] = "failed"
    if returncode == 0:
        stage["error"] = f"exited 0 but left no {missing[0]}"
    elif returncode == "interrupted":
        stage["error"] = "stopped with the reproduction"
    else:
        stage["error"] = f"exit {returncode}: {last_line(out / stage['log'])}"


def last_line(log: Path) -> str:
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return "no output"
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


def stop(children: dict, grace_s: float = STOP_GRACE_S) -> None:
    """SIGTERM to every running stage's process group, SIGKILL to any still there after ``grace_s``."""
    for child in children.values():
        try:
            os.killpg(child.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + grace_s
    for child in children.values():
        try:
            child.wait(timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(child.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.wait()


def group_alive(pgid) -> bool:
    if not pgid:
        return False
    try:
        os.killpg(int(pgid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# ---------------------------------------------------------------------------- resuming
def prepare_resume(doc: dict, out: Path, say) -> None:
    """Check the stages of a stopped reproduction and reset what must run again."""
    stages = {s["name"]: s for s in doc["stages"]}
    for s in doc["stages"]:
        if s["status"] == "running" and group_alive(s.get("pgid")):
            raise ConfigError(f"stage {s['name']} of a stopped reproduction is still running (process group "
                              f"{s['pgid']}); wait for it to end or stop it (kill -- -{s['pgid']}), then --resume")
        if s["status"] == "running":  # the reproduction was killed while it ran: its log says until when
            finish(s, out, "killed", max(last_sign_of_life(out, [s["log"]]), s["sessions"][-1]["started_unix"]))
            s["error"] = "the reproduction was killed while it ran"
    for session in doc["sessions"]:
        if session["ended"] is None:  # a killed session ended when its state file or a log was last written
            ended_unix = max(last_sign_of_life(out, [STATE_FILE, *(s["log"] for s in doc["stages"])]),
                             session["started_unix"])
            session.update(ended=stamp(ended_unix), wall_time_s=round(ended_unix - session["started_unix"], 3),
                           killed=True)
    for s in doc["stages"]:
        missing = [o for o in s["outputs"] if not (out / o).exists()]
        if s["status"] == "done" and missing:
            say(f"{s['name']}: done, but {missing[0]} is missing: it runs again, and every stage after it")
            for name in [s["name"], *dependents(doc["stages"], s["name"])]:
                if stages[name]["status"] == "done":  # made from what is gone: made again from scratch
                    shutil.rmtree(out / STAGES_DIR / name, ignore_errors=True)
                stages[name]["status"] = "pending"


def dependents(stages: list[dict], name: str) -> list[str]:
    """The stages that need ``name``'s outputs, directly or through others."""
    found, changed = set(), True
    while changed:
        changed = False
        for s in stages:
            if s["name"] not in found and any(d == name or d in found for d in s["deps"]):
                found.add(s["name"])
                changed = True
    return [s["name"] for s in stages if s["name"] in found]


# ---------------------------------------------------------------------------- the run
@dataclass
class Reproduction:
    out: Path
    state: dict
    table: list[dict]
    summary: str
    ran: list[str]


@contextmanager
def sigterm_as_interrupt():
    """SIGTERM stops the reproduction as Ctrl-C does (its stages are stopped with it)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_reproduction(out, scale: str | None = None, resume: bool = False, jobs: int = 2, progress: bool = True,
                     command: list[str] | None = None, table: bool = True) -> Reproduction:
    """Run (or resume) the reproduction into ``out``; ``command``: what runs a stage's ``hingelab`` arguments
    (default ``hingelab_command()``; a test gives a stand-in). Raises ``HingelabError`` naming the log of a
    failed stage (no stage starts after a failure; those already running end first)."""
    if jobs < 1:
        raise ConfigError("--jobs must be at least 1")
    out = Path(out).resolve()
    with folder_lock(out):  # one reproduction per folder (hingelab.folder_lock), before its state is read
        return _run_locked(out, scale, resume, jobs, progress, command, table)


def _run_locked(out: Path, scale: str | None, resume: bool, jobs: int, progress: bool, command: list[str] | None,
                table: bool) -> Reproduction:
    doc = open_folder(out, scale, resume)
    command = list(command or hingelab_command())

    def say(message: str) -> None:
        if progress:
            print(f"[{datetime.now().strftime('%H:%M:%S')}] {message}", flush=True)

    with sigterm_as_interrupt():
        if resume:
            prepare_resume(doc, out, say)
        (out / LOGS_DIR).mkdir(exist_ok=True)
        (out / STAGES_DIR).mkdir(exist_ok=True)
        link_assets(out)
        started, started_unix = now()
        session = {"started": started, "started_unix": started_unix, "ended": None, "wall_time_s": None,
                   "resume": resume, "jobs": jobs, "command": " ".join(command), **code_version()}
        doc["sessions"].append(session)
        write_state(out, doc)
        ran = []
        try:
            _run_stages(doc, out, command, jobs, say, ran)
        finally:
            ended, ended_unix = now()
            session.update(ended=ended, wall_time_s=round(ended_unix - started_unix, 3))
            write_state(out, doc)
        failed = [s for s in doc["stages"] if s["status"] == "failed"]
        if failed:
            first = failed[0]
            raise HingelabError(f"stage {first['name']} failed ({first['error']}); its log: {out / first['log']}; "
                                f"fix it and continue with `hingelab reproduce --out {out} --resume`")
        rows = []
        if table:
            rows = write_tables(out, doc)
            doc["table"] = {"written": now()[0], "files": ["reproduce.md", "reproduce.csv"]}
            write_state(out, doc)
    return Reproduction(out, doc, rows, summary(doc, out, rows, ran), ran)


def _run_stages(doc: dict, out: Path, command: list[str], jobs: int, say, ran: list[str]) -> None:
    stages = doc["stages"]
    by_name = {s["name"]: s for s in stages}
    children: dict[str, subprocess.Popen] = {}
    stopping = False
    try:
        while True:
            for s in stages:  # start what is ready, in plan order
                if stopping or len(children) >= jobs:
                    break
                if s["status"] in ("pending", "failed") and s["name"] not in children and \
                        all(by_name[d]["status"] == "done" for d in s["deps"]):
                    children[s["name"]] = launch(s, out, command)
                    ran.append(s["name"])
                    how = "resumed" if s["sessions"][-1]["resumed"] else "started"
                    say(f"{s['name']}: {how} ({out / s['log']})")
                    write_state(out, doc)
            if not children:
                return
            time.sleep(POLL_S)
            for name, child in list(children.items()):
                code = child.poll()
                if code is None:
                    continue
                del children[name]
                s = by_name[name]
                finish(s, out, code)
                write_state(out, doc)
                if s["status"] == "done":
                    say(f"{name}: done in {s['sessions'][-1]['wall_time_s'] / 60:.1f} min")
                else:
                    stopping = True
                    say(f"{name}: FAILED ({s['error']}); log {out / s['log']}"
                        + ("; waiting for the running stages" if children else ""))
    except BaseException:
        if children:
            say(f"stopping {', '.join(children)}")
            stop(children)
            for name in children:
                finish(by_name[name], out, "interrupted")
            write_state(out, doc)
        raise


def summary(doc: dict, out: Path, rows: list[dict], ran: list[str]) -> str:
    stages = doc["stages"]
    wall = sum(s["wall_time_s"] or 0.0 for s in doc["sessions"])
    per_stage = ", ".join(f"{s['name']} {s['wall_time_s'] / 60:.1f}" for s in stages)
    kept = len(stages) - len(ran)
    first = {}  # the first measure of each product (the rest are in the table)
    for r in rows:
        first.setdefault(r["product"], r)
    compared = "; ".join(f"{r['product']}, {r['measure']}: {r['reproduced_text']} against the shipped "
                         f"{r['shipped_text']}" for r in first.values())
    return (f"Reproduced the shipped set at --scale {doc['scale']} in {out}: {len(stages)} stages, {len(ran)} run "
            f"in this session{f' and {kept} kept from before' if kept else ''}, {wall / 60:.1f} min of wall time "
            f"over {len(doc['sessions'])} session(s) (per stage, min: {per_stage}). "
            + (f"{compared}. " if compared else "")
            + f"Table: {out / 'reproduce.md'} (and .csv); state: {out / STATE_FILE}; products in {out / STAGES_DIR}.")


__all__ = ["run_reproduction", "read_state", "write_state", "can_resume", "hingelab_command", "Reproduction",
           "STATE_FILE", "STATUSES", "summary"]
