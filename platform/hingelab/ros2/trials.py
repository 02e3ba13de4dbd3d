"""``/trial/event`` -> trials: each ``start`` .. ``end`` is one episode, with its outcome.

Events (std_msgs/String, stamped by the bag's log time): ``start`` opens a trial; ``attempt``
starts another attempt after a failed one (attempt count = 1 + the ``attempt`` events);
``success``; ``failure`` or ``failure:<reason>`` (the last one's reason becomes ``failure_reason``);
``abort`` (failure_reason ``abort``); ``end`` closes the trial. A ``start`` before ``end``
closes the open trial there (said in ``notes``); a trial without ``end`` closes at the bag's
last message (said in ``notes``). Unknown events are counted and ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

EVENTS = ("start", "attempt", "success", "failure", "abort", "end")


@dataclass
class Trial:
    start_ns: int
    end_ns: int | None = None
    closed_by: str = "end"  # "end", "next_start" or "last_message"
    attempts: int = 1
    success: bool = False
    success_ns: int | None = None
    first_attempt_success: bool = False
    failure_reason: str | None = None
    events: list = field(default_factory=list)  # (t_ns, text)


def split_trials(events, last_message_ns: int) -> tuple[list[Trial], list[str]]:
    """``events``: [(t_ns, text)] in time order. Returns the trials and notes on anything irregular."""
    trials, notes, open_trial, unknown, outside = [], [], None, {}, 0
    for t, text in events:
        word, _, detail = text.strip().partition(":")
        word = word.strip().lower()
        if word == "start":
            if open_trial is not None:
                open_trial.end_ns, open_trial.closed_by = t, "next_start"
                notes.append(f"the trial started at {open_trial.start_ns / 1e9:.3f} s has no end event; closed at "
                             f"the next start ({t / 1e9:.3f} s)")
                trials.append(open_trial)
            open_trial = Trial(start_ns=t)
        elif word not in EVENTS:
            unknown[text] = unknown.get(text, 0) + 1
            continue
        elif open_trial is None:
            outside += 1
            continue
        open_trial.events.append((t, text))
        if word == "attempt":
            open_trial.attempts += 1
        elif word == "success" and not open_trial.success:
            open_trial.success, open_trial.success_ns = True, t
            open_trial.first_attempt_success = open_trial.attempts == 1
        elif word == "failure":  # the last attempt's reason stands
            open_trial.failure_reason = detail.strip() or "failure"
        elif word == "abort":
            open_trial.failure_reason = "abort"
        elif word == "end":
            open_trial.end_ns = t
            trials.append(open_trial)
            open_trial = None
    if open_trial is not None:
        open_trial.end_ns, open_trial.closed_by = last_message_ns, "last_message"
        notes.append(f"the trial started at {open_trial.start_ns / 1e9:.3f} s has no end event; closed at the "
                     f"bag's last message ({last_message_ns / 1e9:.3f} s)")
        trials.append(open_trial)
    if unknown:
        notes.append("ignored unknown events " + ", ".join(f"{k!r} x{v}" for k, v in unknown.items())
                     + f" (known: {', '.join(EVENTS)})")
    if outside:
        notes.append(f"ignored {outside} events outside any trial (before a start)")
    for trial in trials:
        if trial.success and trial.failure_reason:  # a success then a failure event: the success stands
            trial.failure_reason = None
    return trials, notes


__all__ = ["Trial", "split_trials", "EVENTS"]
