"""``hingelab bench envs``: env steps per second with perception on, vs raw ``mj_step``.

For both envs: ``env.step`` with random actions in one process (1 worker), and 2 env processes
stepped in lockstep by ``PinnedVecEnv`` (2 workers, total steps per second; what ``hingelab
train low --envs 2`` uses), with stable-baselines3's ``SubprocVecEnv`` beside it; the
baseline is the same model's bare ``mj_step`` on one core, in control steps (25 physics
steps each), replaying the 1-worker run's own steps (start states with the solver's warm
start, and controls): the same physics work, so the ratio is what the env adds to it. The
physics of a moving arm and object costs more than the resting scene's in ToolPick-v0, so a
resting loop (also reported, "at rest") makes the env look slower than it is.
Raw, 1 worker and 2 workers take turns in rounds; the figures are medians over rounds.
Goal: at least 0.6 of the raw physics rate.
"""

from __future__ import annotations

import time
import types

import gymnasium as gym
import mujoco
import numpy as np
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv

from hingelab.bench.table import BenchTable
from hingelab.envs import TOOL_PICK_ID, TOOL_SHAPE_ID
from hingelab.envs.vec_env import PinnedVecEnv
from hingelab.perception import tool_state_kernels

# the code and models this benchmark measures (the bench module itself: hingelab.bench.measured_paths):
# the envs, their physics and perception, and every asset (ToolPick-v0 runs the shipped low-level policy)
MEASURES = ("platform/hingelab/envs", "platform/hingelab/sim", "platform/hingelab/perception", "assets")


WARMUP_STEPS = 20  # untimed steps first, in every worker
# the replayed steps' start: positions, velocities, time and the solver's warm start (without it the
# replay's contact solver starts elsewhere and drifts by ~1e-7)
PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_WARMSTART
ROUNDS = 10  # raw, 1 worker and 2 workers take turns: a slower spell of the machine hits all three
# (these shared machines drift by tens of percent within minutes: many short rounds, medians of ratios)


def _raw_rate(model: mujoco.MjModel, control_steps: int, n_substeps: int) -> float:
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    start = time.perf_counter()
    for _ in range(control_steps * n_substeps):
        mujoco.mj_step(model, data)
    return control_steps / (time.perf_counter() - start)


class _OneWorker:
    """One env in this process, stepped with random actions (30% of the range)."""

    def __init__(self, env_id: str, seed: int = 0):
        self.env = gym.make(env_id)
        self.env.reset(seed=seed)
        self.env.action_space.seed(seed)
        self.sim = self.env.unwrapped.sim
        self.rate(WARMUP_STEPS)  # first calls load the compiled registration and fill caches

    def rate(self, steps: int) -> float:
        """Steps per second; keeps each step's start state and controls for ``replayed_raw_rate``."""
        actions = [self.env.action_space.sample() * 0.3 for _ in range(steps)]
        model, data = self.sim.model, self.sim.data
        size = mujoco.mj_stateSize(model, PHYSICS)
        states = np.empty((steps + 1, size))
        controls = np.empty((steps, model.nu))
        fresh = np.zeros(steps, bool)  # a reset came before this step: its start state is not the last end state
        mujoco.mj_getState(model, data, states[0], PHYSICS)
        start = time.perf_counter()
        for i, action in enumerate(actions):
            *_, terminated, truncated, _ = self.env.step(action)
            controls[i] = data.ctrl  # what this step ran with (the env sets it before its substeps)
            if terminated or truncated:
                self.env.reset()
                if i + 1 < steps:
                    fresh[i + 1] = True
            mujoco.mj_getState(model, data, states[i + 1], PHYSICS)
        rate = steps / (time.perf_counter() - start)
        self.replay = (states[:-1][~fresh], controls[~fresh])
        return rate

    def replayed_raw_rate(self) -> float:
        """Bare mj_step on the last ``rate`` call's steps: the same start states and controls, in a
        fresh MjData of the same model, control steps (n_substeps each) per second."""
        model, states, controls = self.sim.model, *self.replay
        data = mujoco.MjData(model)
        elapsed = 0.0
        for state, control in zip(states, controls):
            mujoco.mj_setState(model, data, state, PHYSICS)
            data.ctrl[:] = control
            start = time.perf_counter()
            for _ in range(self.sim.n_substeps):
                mujoco.mj_step(model, data)
            elapsed += time.perf_counter() - start
        return len(states) / elapsed


    def breakdown(self, steps: int) -> dict[str, float]:
        """Milliseconds per step of each part of perception (timers around them for ``steps``
        steps), the replayed physics of those steps, and the rest (total minus those)."""
        perception = self.env.unwrapped.perception
        tool_state = perception.tool_state
        # encode_scaled is where every encoding goes (encode too); tracked_step is the compiled step
        # between resets (tracking and differencing), track and register the general path's parts
        timed = {"cloud": [(perception.synthesizer, "from_sim")],
                 "registration": [(tool_state_kernels, "tracked_step"), (tool_state.registration, "track"),
                                  (tool_state.registration, "register")],
                 "encoder": [(tool_state.encoder, "encode_scaled")]}
        spent = dict.fromkeys(timed, 0.0)

        def timer(part, function):
            def wrapped(*args, **kwargs):
                start = time.perf_counter()
                try:
                    return function(*args, **kwargs)
                finally:
                    spent[part] += time.perf_counter() - start
            return wrapped

        originals = [(owner, name, getattr(owner, name)) for methods in timed.values() for owner, name in methods]
        for part, methods in timed.items():
            for owner, name in methods:
                setattr(owner, name, timer(part, getattr(owner, name)))
        try:
            total = steps / self.rate(steps)
        finally:
            for owner, name, original in originals:
                if isinstance(owner, types.ModuleType):
                    setattr(owner, name, original)
                else:
                    del owner.__dict__[name]  # back to the class's method
        physics = steps / self.replayed_raw_rate()
        out = {"physics": physics, **spent}
        out["rest"] = total - sum(out.values())
        return {part: 1000 * value / steps for part, value in out.items()}


class _Workers:
    """``n_envs`` spawned env processes in a vec env (PinnedVecEnv or SB3's SubprocVecEnv): total steps/s."""

    def __init__(self, env_id: str, n_envs: int, vec_env_cls=None):
        self.vec = make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=vec_env_cls or PinnedVecEnv,
                                vec_env_kwargs={"start_method": "spawn"})
        self.vec.reset()
        self.n_envs = n_envs
        self.rate(WARMUP_STEPS)

    def rate(self, steps: int) -> float:
        actions = [np.stack([self.vec.action_space.sample() * 0.3 for _ in range(self.n_envs)])
                   for _ in range(steps)]
        start = time.perf_counter()
        for action in actions:
            self.vec.step(action)  # auto-resets finished envs
        return steps * self.n_envs / (time.perf_counter() - start)


def run(quick: bool = False) -> BenchTable:
    steps = 40 if quick else 4000
    rounds = 2 if quick else ROUNDS
    block = steps // rounds
    rows, ratios = [], {}
    for env_id in (TOOL_SHAPE_ID, TOOL_PICK_ID):
        one, two, stock = _OneWorker(env_id), _Workers(env_id, 2), _Workers(env_id, 2, SubprocVecEnv)
        raw_r, rest_r, one_r, two_r, stock_r = [], [], [], [], []
        for _ in range(rounds):
            one_r.append(one.rate(block))
            raw_r.append(one.replayed_raw_rate())
            rest_r.append(_raw_rate(one.sim.model, block, one.sim.n_substeps))
            two_r.append(two.rate(block // 2))
            stock_r.append(stock.rate(block // 2))
        parts = one.breakdown(block)
        one.env.close()
        two.vec.close()
        stock.vec.close()
        raw_r, rest_r, one_r, two_r, stock_r = (np.array(x) for x in (raw_r, rest_r, one_r, two_r, stock_r))
        row = {"env": env_id, "raw mj_step, same steps (control steps/s)": float(np.median(raw_r)),
               "raw mj_step, at rest (control steps/s)": float(np.median(rest_r)),
               "1 worker (steps/s)": float(np.median(one_r)), "2 workers (steps/s)": float(np.median(two_r)),
               "1 worker / raw": float(np.median(one_r / raw_r)), "2 workers / raw": float(np.median(two_r / raw_r)),
               "1 worker / raw, range over rounds": f"{(one_r / raw_r).min():.2f}-{(one_r / raw_r).max():.2f}",
               "2 workers / raw, range over rounds": f"{(two_r / raw_r).min():.2f}-{(two_r / raw_r).max():.2f}",
               "1 worker / raw at rest": float(np.median(one_r / rest_r)),
               "2 workers / (2 x raw), per core": float(np.median(two_r / (2 * raw_r))),
               "2 workers, SubprocVecEnv (steps/s)": float(np.median(stock_r)),
               "2 workers, SubprocVecEnv / raw": float(np.median(stock_r / raw_r)),
               "1 worker, ms per step": ", ".join(f"{part} {ms:.2f}" for part, ms in parts.items())}
        rows.append(row)
        ratios[f"{env_id}: 1 worker / raw"] = row["1 worker / raw"]
        ratios[f"{env_id}: 2 workers / raw"] = row["2 workers / raw"]
        ratios[f"{env_id}: 2 workers, PinnedVecEnv / SubprocVecEnv"] = float(np.median(two_r / stock_r))
    return BenchTable(
        name="envs",
        title="Env steps per second with perception on vs raw mj_step of the same model",
        columns=list(rows[0]), rows=rows, ratios=ratios,
        notes=[f"{steps} steps per figure (1 worker; 2 workers: {steps // 2} vector steps) in {rounds} rounds "
               f"after {WARMUP_STEPS} untimed steps; in each round raw, 1 worker and 2 workers run in turn and "
               "the figures are medians over rounds (ratios: medians of the rounds' ratios). Random actions "
               "at 30% of the range; perception = cloud synthesis (noise, occlusion, pose error) + "
               "registration + encoder + smoothing every step.",
               "Raw, same steps (the baseline of the ratios): bare mj_step of the same model on one core, replaying "
               "the 1-worker run's steps (each step's start state and controls, mj_setState), in 20 Hz control "
               "steps (25 physics steps); the physics of a moving hand, arm and object costs more than at rest.",
               "Raw, at rest: the same loop from the grasp keyframe with the controls left alone (the baseline "
               "of earlier runs of this bench; ToolPick-v0's arm and object cost more physics when they move).",
               "2 workers: PinnedVecEnv of 2 envs (spawned processes, each held to one core, observations, actions, "
               "rewards and dones in shared memory; hingelab train low's vec env), total steps per second; '2 "
               "workers / raw' divides them by one core's raw rate (the issue's figure), '2 workers / (2 x raw), "
               "per core' by two cores' (what each core keeps of its physics rate; the two envs step in lockstep, "
               "so each vector step waits for the slower one). SubprocVecEnv: stable-baselines3's, the same 2 "
               "envs, taking turns with the others in every round.",
               "1 worker, ms per step: one more round of the 1-worker run with timers around the perception's "
               "parts (cloud synthesis; registration: the compiled tracking step between resets, with the "
               "differencing and the encoder's input, and the registrations of resets and lost tools; encoder), "
               "physics = the replayed raw steps of that round, rest = everything else of env.step and reset "
               "(the sim's bookkeeping, privileged state, rewards, observation, delays)."],
        config={"steps": steps, "rounds": rounds},
    )
