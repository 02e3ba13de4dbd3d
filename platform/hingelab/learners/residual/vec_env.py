"""``ResidualVecEnv``: ToolPick-v0's envs as the residual learner sees them.

SAC acts on the residual (``Box(-1, 1, (5,))``) and observes the residual's inputs
(``hingelab.policies.residual.ResidualInputs``: the standardized observation with a continuous rotation,
the base's memory and the base's action). Underneath, each env steps with the executed action
``clip(base + scale * residual, -1, 1)``; the recording wrapper below records that, so the run's dataset
holds ToolPick-v0's own actions. The base's memory runs on per env and starts anew with every episode.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnvWrapper

from hingelab.policies.residual import ResidualPolicy, compose


class ResidualVecEnv(VecEnvWrapper):
    def __init__(self, venv, policy: ResidualPolicy):
        self.policy = policy
        observation_space = spaces.Box(-np.inf, np.inf, (policy.inputs.dim,), np.float32)
        super().__init__(venv, observation_space=observation_space,
                         action_space=spaces.Box(-1.0, 1.0, (5,), np.float32))
        self.memory = np.zeros((self.num_envs, 2), np.int64)
        self.base_action = np.zeros((self.num_envs, 5), np.float32)
        self.next_memory = self.memory.copy()

    def _inputs(self, obs: np.ndarray) -> np.ndarray:
        """The residual's inputs for ``obs`` under the current memory; keeps the base's action and next memory."""
        x, self.base_action, self.next_memory = self.policy.step(obs, self.memory)
        return x

    def reset(self):
        obs = self.venv.reset()
        self.memory = np.zeros((self.num_envs, 2), np.int64)
        return self._inputs(obs)

    def step_async(self, actions: np.ndarray) -> None:
        executed = compose(self.base_action, np.asarray(actions, np.float32), self.policy.scale)
        self.venv.step_async(executed.astype(np.float32))

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self.memory = self.next_memory
        for i in np.flatnonzero(dones):
            terminal = infos[i].get("terminal_observation")
            if terminal is not None:  # the episode's last observation under the memory it reached
                x, _, _ = self.policy.step(terminal[None], self.memory[i:i + 1])
                infos[i]["terminal_observation"] = x[0]
            self.memory[i] = 0  # obs[i] is the next episode's first
        return self._inputs(obs), rewards, dones, infos


__all__ = ["ResidualVecEnv"]
