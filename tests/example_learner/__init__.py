"""An example learner: behaviour cloning of the prior's demos by an MLP, in one folder, registered by name.

It shows what a new learner of hingelab is: a config composed of the shared parts plus its own fields,
a ``train`` that writes a run folder (config.json, metrics.csv, model.zip), a policy with
``predict(obs, state, episode_start)`` and a file format that ``hingelab.policies.load_policy`` finds,
all registered on import: ``hingelab train high --learner bc-mlp`` and ``hingelab eval high RUNDIR``
work with no edit anywhere else (tests/test_example_learner.py).
"""

from __future__ import annotations

import io
import json
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from hingelab.learners.registry import register_learner
from hingelab.policies.loading import register_policy_format
from hingelab.provenance import code_version
from hingelab.tasks import TOOL_PICK_ID
from hingelab.training.config_parts import PickReward, PickTask, PriorDemos, RunSettings
from hingelab.training.pick_run_parts import PickEvaluation, PriorData, check_pick_inputs
from hingelab.training.run_config import option
from hingelab.training.run_folder import RunFolder

META = "bc_mlp.json"


@dataclass(frozen=True)
class BCConfig(PriorDemos, PickReward, PickTask, RunSettings):
    hidden: int = option(64, "units of the MLP's two hidden layers")
    updates: int = option(500, "Adam updates on the demos")

    env_id, train_source, action_level = TOOL_PICK_ID, "high_level_training", "high"


class BCPolicy:
    """A Markov MLP: observation -> action in [-1, 1]."""

    def __init__(self, net: nn.Module, provenance: dict):
        self.net, self.hingelab_provenance = net, provenance

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation, np.float32)
        with torch.no_grad():
            action = self.net(torch.as_tensor(np.atleast_2d(obs))).numpy()
        return (action if obs.ndim > 1 else action[0]), None

    def save(self, path: Path) -> None:
        weights = io.BytesIO()
        np.savez(weights, **{k: v.numpy() for k, v in self.net.state_dict().items()})
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr(META, json.dumps({"hingelab_provenance": self.hingelab_provenance}))
            archive.writestr("weights.npz", weights.getvalue())


def make_net(observation_dim: int, hidden: int) -> nn.Module:
    return nn.Sequential(nn.Linear(observation_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, 5), nn.Tanh())


def is_bc_mlp(path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return META in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def load_bc_mlp(path, **context) -> BCPolicy:
    with zipfile.ZipFile(path) as archive:
        meta = json.loads(archive.read(META))
        with np.load(io.BytesIO(archive.read("weights.npz")), allow_pickle=False) as npz:
            state = {k: torch.as_tensor(npz[k]) for k in npz.files}
    net = make_net(state["0.weight"].shape[1], state["0.weight"].shape[0])
    net.load_state_dict(state)
    return BCPolicy(net, meta["hingelab_provenance"])


register_policy_format("example bc-mlp", is_bc_mlp, load_bc_mlp)


@register_learner
class BCLearner:
    name, level = "bc-mlp", "high"
    config_class = BCConfig
    default_out = "runs/bc_seed{SEED}"
    help = "an example: behaviour cloning of the prior's demos by a Markov MLP"
    description = "Clone the prior's demos with an MLP (an example learner of the tests)."

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        started = time.perf_counter()
        folder = RunFolder(Path(run_dir), config, resume=resume, name=name)
        c = folder.config
        if not resume:
            check_pick_inputs(c)
            folder.write_run_files({"learner": "bc-mlp"})
        prior = PriorData(c, folder.path, folder.name, progress)
        prior.load()
        torch.manual_seed(c.seed)
        obs = torch.as_tensor(np.asarray(prior.demos.observations), dtype=torch.float32)
        act = torch.as_tensor(np.clip(prior.demos.actions, -1, 1), dtype=torch.float32)
        net = make_net(obs.shape[1], c.hidden)
        optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
        for _ in range(c.updates):
            loss = ((net(obs) - act) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        policy = BCPolicy(net, {"env_id": c.env_id, "env_kwargs": c.env_arguments(), "config": c.to_dict(),
                                "low_level": c.low_level, **code_version()})
        evaluation = PickEvaluation(c)
        row = {"env_steps": 0, "seed": c.seed, "updates": c.updates, **evaluation(policy)}
        evaluation.close()
        folder.metrics.append(row)
        policy.save(folder.path / "model.zip")
        return {"run_dir": str(folder.path), "wall_time_s": time.perf_counter() - started, "last_evaluation": row,
                "loss": float(loss.detach())}

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        return (f"Cloned the demos with an MLP (final loss {result['loss']:.4f}); evaluation success "
                f"{result['last_evaluation']['success_rate']:.2f}. Policy: {run_dir}/model.zip.")
