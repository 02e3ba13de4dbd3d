"""``PinnedVecEnv``: stable-baselines3's ``SubprocVecEnv``, with observations, actions, rewards and
dones through shared memory and each worker process held to one core.

Why: 2 workers in a ``SubprocVecEnv`` step markedly slower than two independent env processes.
``SubprocVecEnv`` pickles every observation through a pipe both ways (main-process time on every
vector step) and lets the scheduler move the workers between the cores (and each move starts a
step on caches that hold the other worker's data). Here the arrays stay in shared memory (the
pipe carries a one-byte command and the info dict) and worker i runs on core i mod cores
(``pin=False`` leaves placement to the scheduler); both changes help, together most. The rest of
the gap to independent processes is the lockstep: each vector step waits for the slower env.
``hingelab bench envs`` measures PinnedVecEnv against SubprocVecEnv (``analysis/bench/envs.md``).

The contract is SubprocVecEnv's (SB3 ``VecEnv``): ``step`` auto-resets finished envs and puts
the last observation in ``info["terminal_observation"]``, ``info["TimeLimit.truncated"]``,
``reset_infos``, ``get_attr``/``set_attr``/``env_method``/``env_is_wrapped``, seeds and options
passed on the next ``reset``. Box and Dict-of-Box observation spaces (what hingelab's envs have).
A worker that raises sends the error back: the main process raises it with the env's index.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import traceback
from collections.abc import Callable, Sequence
from multiprocessing import shared_memory

import cloudpickle
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnv
from stable_baselines3.common.vec_env.patch_gym import _patch_env

from hingelab.errors import ConfigError

STEP = b"s"


def _obs_layout(space: gym.Space) -> dict:
    """{key: (shape, dtype)}; key None for a Box space."""
    if isinstance(space, spaces.Box):
        return {None: (space.shape, space.dtype)}
    if isinstance(space, spaces.Dict) and all(isinstance(s, spaces.Box) for s in space.spaces.values()):
        return {k: (s.shape, s.dtype) for k, s in space.spaces.items()}
    raise ConfigError(f"PinnedVecEnv takes Box or Dict-of-Box observation spaces, got {space}")


class _Buffers:
    """The shared arrays of all envs: obs per key (n, ...), actions (n, ...), rewards (n,), dones (n,)."""

    def __init__(self, n_envs: int, obs_space: gym.Space, action_space: gym.Space, names: dict | None = None):
        self.obs_layout = _obs_layout(obs_space)
        fields = {f"obs:{k}": ((n_envs, *shape), dtype) for k, (shape, dtype) in self.obs_layout.items()}
        fields["action"] = ((n_envs, *action_space.shape), np.dtype(action_space.dtype))
        fields["reward"] = ((n_envs,), np.dtype(np.float64))
        fields["done"] = ((n_envs,), np.dtype(bool))
        self.owner = names is None
        self.memory, self.arrays = {}, {}
        for name, (shape, dtype) in fields.items():
            size = max(int(np.prod(shape)) * np.dtype(dtype).itemsize, 1)
            memory = (shared_memory.SharedMemory(create=True, size=size) if self.owner
                      else shared_memory.SharedMemory(name=names[name]))
            self.memory[name] = memory
            self.arrays[name] = np.ndarray(shape, dtype, buffer=memory.buf)

    @property
    def names(self) -> dict:
        return {name: memory.name for name, memory in self.memory.items()}

    def write_obs(self, index: int, obs) -> None:
        for key in self.obs_layout:
            self.arrays[f"obs:{key}"][index] = obs if key is None else obs[key]

    def read_obs(self):
        copies = {key: self.arrays[f"obs:{key}"].copy() for key in self.obs_layout}
        return copies[None] if None in copies else copies

    def close(self) -> None:
        self.arrays.clear()
        for memory in self.memory.values():
            memory.close()
            if self.owner:
                memory.unlink()
        self.memory.clear()


def _worker(remote, parent_remote, env_fn: CloudpickleWrapper, index: int, core: int | None) -> None:
    parent_remote.close()
    if core is not None:
        os.sched_setaffinity(0, {core})
    buffers = None
    try:
        env = _patch_env(env_fn.var())
        remote.send(("ok", (env.observation_space, env.action_space)))
        buffers = _Buffers(*remote.recv())
        remote.send(("ok", None))
    except Exception as exc:  # noqa: BLE001 (sent to the main process, which raises it)
        remote.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
        return
    while True:
        try:
            message = remote.recv_bytes()
            if message == STEP:
                observation, reward, terminated, truncated, info = env.step(buffers.arrays["action"][index].copy())
                done = terminated or truncated
                info["TimeLimit.truncated"] = truncated and not terminated
                reset_info = None
                if done:
                    info["terminal_observation"] = observation
                    observation, reset_info = env.reset()
                buffers.write_obs(index, observation)
                buffers.arrays["reward"][index] = reward
                buffers.arrays["done"][index] = done
                remote.send(("ok", (info, reset_info)))
                continue
            cmd, data = pickle.loads(message)
            if cmd == "reset":
                seed, options = data
                observation, reset_info = env.reset(seed=seed, **({"options": options} if options else {}))
                buffers.write_obs(index, observation)
                out = reset_info
            elif cmd == "close":
                env.close()
                remote.send(("ok", None))
                break
            elif cmd == "env_method":
                name, args, kwargs = data
                out = env.get_wrapper_attr(name)(*args, **kwargs)
            elif cmd == "get_attr":
                out = env.get_wrapper_attr(data)
            elif cmd == "has_attr":
                try:
                    env.get_wrapper_attr(data)
                    out = True
                except AttributeError:
                    out = False
            elif cmd == "set_attr":
                out = setattr(env, data[0], data[1])
            elif cmd == "is_wrapped":
                out = is_wrapped(env, data)
            elif cmd == "render":
                out = env.render()
            else:
                raise NotImplementedError(f"`{cmd}` is not implemented in the worker")
            remote.send(("ok", out))
        except (EOFError, KeyboardInterrupt):
            break
        except Exception as exc:  # noqa: BLE001
            remote.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    if buffers is not None:
        buffers.close()


class PinnedVecEnv(VecEnv):
    """``n`` env processes stepped in lockstep (see the module docstring).

    Args:
        env_fns: callables that build the envs (run in the workers).
        start_method: multiprocessing start method (default "spawn": safe with torch and MuJoCo).
        pin: hold worker i to core i mod (cores this process may use; Linux only); False: the scheduler
            places them.
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], start_method: str = "spawn", pin: bool = True):
        ctx = mp.get_context(start_method)
        pin = pin and hasattr(os, "sched_setaffinity")  # Linux; elsewhere the scheduler places them
        cores = sorted(os.sched_getaffinity(0)) if pin else []
        self.remotes, self.processes = [], []
        for i, fn in enumerate(env_fns):
            remote, work_remote = ctx.Pipe()
            core = cores[i % len(cores)] if pin else None
            process = ctx.Process(target=_worker, args=(work_remote, remote, CloudpickleWrapper(fn), i, core),
                                  daemon=True)
            process.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
        self.closed = False
        self.buffers = None
        obs_space, action_space = self._gather()[0]
        self.buffers = _Buffers(len(env_fns), obs_space, action_space)
        for remote in self.remotes:
            remote.send((len(env_fns), obs_space, action_space, self.buffers.names))
        self._gather()
        super().__init__(len(env_fns), obs_space, action_space)  # asks the workers for render_mode

    # ------------------------------------------------------------------ plumbing
    def _gather(self, indices=None) -> list:
        """The answers of the workers of ``indices`` (default all); a worker's error is raised here with
        its env index."""
        out = []
        for i in (range(len(self.remotes)) if indices is None else self._get_indices(indices)):
            remote = self.remotes[i]
            try:
                status, value = remote.recv()
            except EOFError:
                raise RuntimeError(f"env worker {i} exited (see its error above)") from None
            if status == "error":
                raise RuntimeError(f"env worker {i} failed: {value}")
            out.append(value)
        return out

    def _call(self, cmd: str, data=None, indices=None) -> list:
        message = cloudpickle.dumps((cmd, data))
        for i in self._get_indices(indices):
            self.remotes[i].send_bytes(message)
        return self._gather(indices)

    # ------------------------------------------------------------------ VecEnv API
    def step_async(self, actions: np.ndarray) -> None:
        self.buffers.arrays["action"][:] = np.asarray(actions).reshape(self.buffers.arrays["action"].shape)
        for remote in self.remotes:
            remote.send_bytes(STEP)

    def step_wait(self):
        results = self._gather()
        infos = [info for info, _ in results]
        for i, (_, reset_info) in enumerate(results):
            if reset_info is not None:
                self.reset_infos[i] = reset_info
        a = self.buffers.arrays
        return self.buffers.read_obs(), a["reward"].copy(), a["done"].copy(), infos

    def reset(self):
        data = [(self._seeds[i], self._options[i]) for i in range(self.num_envs)]
        for remote, item in zip(self.remotes, data):
            remote.send_bytes(cloudpickle.dumps(("reset", item)))
        self.reset_infos = self._gather()
        self._reset_seeds()
        self._reset_options()
        return self.buffers.read_obs()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for remote in self.remotes:
            try:
                remote.send_bytes(cloudpickle.dumps(("close", None)))
                remote.recv()
            except (EOFError, BrokenPipeError, OSError):
                pass
        for process in self.processes:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
        if self.buffers is not None:
            self.buffers.close()

    def get_images(self):
        return self._call("render")

    def get_attr(self, attr_name: str, indices=None) -> list:
        return self._call("get_attr", attr_name, indices)

    def has_attr(self, attr_name: str) -> bool:
        return all(self._call("has_attr", attr_name))

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        self._call("set_attr", (attr_name, value), indices)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        return self._call("env_method", (method_name, method_args, method_kwargs), indices)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list:
        return self._call("is_wrapped", wrapper_class, indices)

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 (interpreter shutdown)
            pass


__all__ = ["PinnedVecEnv"]
