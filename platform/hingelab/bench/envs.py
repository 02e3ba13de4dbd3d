"""``hingelab bench envs``: env steps per second with perception on, vs raw ``mj_step``.

For both envs: ``env.step`` with random actions in one process (1 worker), and a
stable-baselines3 ``SubprocVecEnv`` of 2 envs (2 workers, total steps per second); the
baseline is the same model's bare ``mj_step`` loop on one core, in control steps (25
physics steps each). Goal (issue): at least 0.6 of the raw physics rate.
"""

from __future__ import annotations

import time

import gymnasium as gym
import mujoco
import numpy as np

from hingelab.bench.table import BenchTable
from hingelab.envs import TOOL_PICK_ID, TOOL_SHAPE_ID


def _raw_rate(model: mujoco.MjModel, control_steps: int, n_substeps: int) -> float:
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    start = time.perf_counter()
    for _ in range(control_steps * n_substeps):
        mujoco.mj_step(model, data)
    return control_steps / (time.perf_counter() - start)


def _env_rate(env_id: str, steps: int, seed: int = 0) -> tuple[float, object]:
    env = gym.make(env_id)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() * 0.3 for _ in range(steps)]
    start = time.perf_counter()
    for action in actions:
        *_, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    sim = env.unwrapped.sim
    env.close()
    return rate, sim


def _vec_rate(env_id: str, n_envs: int, steps: int) -> float:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=SubprocVecEnv,
                       vec_env_kwargs={"start_method": "spawn"})
    vec.reset()
    actions = [np.stack([vec.action_space.sample() * 0.3 for _ in range(n_envs)]) for _ in range(steps)]
    start = time.perf_counter()
    for action in actions:
        vec.step(action)
    rate = steps * n_envs / (time.perf_counter() - start)
    vec.close()
    return rate


def run(quick: bool = False) -> BenchTable:
    steps = 40 if quick else 400
    rows, ratios = [], {}
    for env_id in (TOOL_SHAPE_ID, TOOL_PICK_ID):
        one, sim = _env_rate(env_id, steps)
        raw = _raw_rate(sim.model, steps, sim.n_substeps)
        two = _vec_rate(env_id, 2, steps // 2)
        rows.append({"env": env_id, "raw mj_step (control steps/s)": raw, "1 worker (steps/s)": one,
                     "2 workers (steps/s)": two, "1 worker / raw": one / raw, "2 workers / raw": two / raw})
        ratios[f"{env_id}: 1 worker / raw"] = one / raw
        ratios[f"{env_id}: 2 workers / raw"] = two / raw
    return BenchTable(
        name="envs",
        title="Env steps per second with perception on vs raw mj_step of the same model",
        columns=list(rows[0]), rows=rows, ratios=ratios,
        notes=[f"{steps} steps per figure, random actions at 30% of the range; perception = cloud synthesis "
               "(noise, occlusion, pose error) + registration + encoder + smoothing every step.",
               "Raw: the model's bare mj_step loop on one core, in 20 Hz control steps (25 physics steps).",
               "2 workers: SubprocVecEnv of 2 envs (spawned processes), total steps per second."],
        config={"steps": steps},
    )
