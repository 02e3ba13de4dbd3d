"""Fitting the phase clone (``hingelab.policies.phase_clone``) to the scripted demonstrator's demos:
the action and the demonstrator's next phase, from the observation and the phase and steps before it.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from hingelab.errors import ConfigError
from hingelab.policies.phase_clone import ACTION_DIM, LABELS, PhaseCloneNet, net_from_state, net_state
from hingelab.seeds import ensemble_member_seed


# ------------------------------------------------------------------ fitting
@dataclass
class PhaseDemos:
    """Demo steps: observation (N, D), action (N, 5) in [-1, 1], the demonstrator's phase and steps
    before the step, its phase after (N,) int."""

    observations: np.ndarray
    actions: np.ndarray
    phases: np.ndarray
    steps: np.ndarray
    next_phases: np.ndarray

    @classmethod
    def from_transitions(cls, transitions, where: str = "the demos") -> "PhaseDemos":
        """The demos' phases from their step infos (recorded by ``DemonstratorLabels``)."""
        missing = [k for k in LABELS if k not in transitions.infos]
        if missing:
            raise ConfigError(f"{where} do not record the demonstrator's phases ({', '.join(missing)}); the phase "
                              "clone needs scripted demos recorded by this hingelab: drop --from to generate them "
                              "(--prior-source scripted)")
        infos = transitions.infos
        # demos with noise on the executed action (--prior-action-noise) label the clean one
        clean = [infos.get(f"demo_action_{i}") for i in range(ACTION_DIM)]
        actions = transitions.actions if any(a is None for a in clean) else np.stack(clean, axis=1)
        return cls(np.asarray(transitions.observations, np.float32), np.asarray(actions, np.float32),
                   infos["demo_phase"].astype(np.int64), infos["demo_phase_steps"].astype(np.int64),
                   infos["demo_next_phase"].astype(np.int64))

    def __len__(self) -> int:
        return len(self.actions)

    def in_canonical_order(self) -> "PhaseDemos":
        """The same steps sorted by their content (observation, memory, labels): a dataset lists its episodes by
        file name, whose random part orders the episodes of one second at random, and the fit's batches are rows
        by index, so without this the same demos read from two generations would fit different weights."""
        keys = np.column_stack([self.observations, self.actions, self.phases, self.steps, self.next_phases])
        order = np.lexsort(keys.T[::-1])
        return PhaseDemos(*(getattr(self, f)[order] for f in
                            ("observations", "actions", "phases", "steps", "next_phases")))

    @classmethod
    def concat(cls, parts: list["PhaseDemos"]) -> "PhaseDemos":
        """The steps of ``parts`` one after another."""
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                     ("observations", "actions", "phases", "steps", "next_phases")))


def fit_phase_clone(demos: PhaseDemos, hidden: tuple[int, ...], updates: int, batch_size: int,
                    learning_rate: float, seed: int, progress: bool = False,
                    start: PhaseCloneNet | None = None) -> tuple[PhaseCloneNet, dict]:
    """Fit a ``PhaseCloneNet``: squared action error + cross-entropy of the next phase, Adam with a
    cosine decay. Returns the net and its fit (final losses on all demos, phase accuracy overall and on
    the demonstrator's phase changes). ``start``: a net to go on from (a copy of it is fitted, its
    observation standardization kept; ``hidden`` is then its own), else a new one standardized on the demos."""
    if len(demos) == 0:
        raise ConfigError("no demo steps to clone")
    demos = demos.in_canonical_order()
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    if start is not None:
        if start.observation_dim != demos.observations.shape[1]:
            raise ConfigError(f"the clone to go on from takes {start.observation_dim}-D observations, the demos hold "
                              f"{demos.observations.shape[1]}-D ones")
        net = copy.deepcopy(start)
    else:
        std = demos.observations.std(0) + 1e-6
        net = PhaseCloneNet(demos.observations.shape[1], hidden, demos.observations.mean(0), std)
    tensors = [torch.as_tensor(a) for a in (demos.observations, np.clip(demos.actions, -1, 1), demos.phases,
                                            demos.steps, demos.next_phases)]
    optimizer = torch.optim.Adam(net.parameters(), lr=learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, max(updates, 1))
    started = time.perf_counter()
    net.train()
    for update in tqdm(range(updates), desc="phase clone", unit="update", disable=not progress, mininterval=2):
        index = torch.randint(len(demos), (batch_size,), generator=generator)
        obs, action, phase, steps, next_phase = (t[index] for t in tensors)
        predicted, logits = net(obs, phase, steps)
        loss = ((predicted - action) ** 2).sum(1).mean() + nn.functional.cross_entropy(logits, next_phase)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    net.eval()
    with torch.no_grad():
        predicted, logits = net(tensors[0], tensors[2], tensors[3])
        guessed = logits.argmax(1)
        changes = tensors[4] != tensors[2]
        fit = {"updates": updates, "demo_steps": len(demos),
               "action_squared_error": float(((predicted - tensors[1]) ** 2).sum(1).mean()),
               "phase_accuracy": float((guessed == tensors[4]).float().mean()),
               "phase_change_accuracy": float((guessed[changes] == tensors[4][changes]).float().mean())
               if bool(changes.any()) else 1.0,
               "seconds": round(time.perf_counter() - started, 1)}
    return net, fit


def _fit_member(job: dict) -> tuple[dict, dict]:
    """One member's fit in a ``--jobs`` worker: ``fit_phase_clone`` of the job's demos and seed; the net as
    ``net_state`` and the fit."""
    start = None if job["start"] is None else net_from_state(job["start"])
    net, fit = fit_phase_clone(PhaseDemos(**job["demos"]), job["hidden"], job["updates"], job["batch_size"],
                               job["learning_rate"], job["seed"], progress=False, start=start)
    return net_state(net), fit


def fit_phase_clone_members(demos: PhaseDemos, members: int, hidden: tuple[int, ...], updates: int, batch_size: int,
                            learning_rate: float, seed: int, progress: bool = False,
                            starts: list[PhaseCloneNet] | None = None,
                            pool=None) -> tuple[list[PhaseCloneNet], dict]:
    """``members`` nets fitted by ``fit_phase_clone`` on the same demos from different seeds (an ensemble
    for ``PhaseClone``); the nets and the fit (member 0's figures, every member's, total seconds).
    ``starts``: one net per member to go on from (``fit_phase_clone``'s ``start``). ``pool`` (a
    ``hingelab.workers.job_pool.JobPool``): the members fitted side by side in its workers, one torch thread
    each: each fit depends only on the demos, its seed and its start, so the nets are the ones fitted here one
    after another (on one thread, ``--threads 1``) bit for bit."""
    if members < 1:
        raise ConfigError(f"an ensemble needs at least one member, not {members}")
    if starts is not None and len(starts) != members:
        raise ConfigError(f"{members} members to fit from {len(starts)} nets to go on from")
    nets, fits = [], []
    if pool is not None and members > 1:
        arrays = {f: getattr(demos, f) for f in ("observations", "actions", "phases", "steps", "next_phases")}
        jobs = [{"demos": arrays, "hidden": tuple(hidden), "updates": updates, "batch_size": batch_size,
                 "learning_rate": learning_rate, "seed": ensemble_member_seed(seed, member),
                 "start": None if starts is None else net_state(starts[member])} for member in range(members)]
        if progress:
            print(f"phase clone: fitting {members} members in {min(pool.jobs, members)} processes")

        def done(member, _):
            if progress:
                print(f"phase clone: member {member + 1} of {members} fitted")

        for state, fit in pool.map(_fit_member, jobs, done=done):
            nets.append(net_from_state(state))
            fits.append(fit)
    else:
        for member in range(members):
            if progress and members > 1:
                print(f"phase clone: member {member + 1} of {members}")
            net, fit = fit_phase_clone(demos, hidden, updates, batch_size, learning_rate,
                                       ensemble_member_seed(seed, member), progress=progress,
                                       start=None if starts is None else starts[member])
            nets.append(net)
            fits.append(fit)
    fit = dict(fits[0])
    if members > 1:
        fit.update(members=members, member_fits=fits, seconds=round(sum(f["seconds"] for f in fits), 1))
    return nets, fit


__all__ = ["PhaseDemos", "fit_phase_clone", "fit_phase_clone_members"]
