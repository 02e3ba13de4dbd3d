"""The paper's privileged replay buffer: heuristic demos pre-fill the high-level SAC buffer.

``high_level_transitions`` turns recorded ToolPick-v0 episodes (``hingelab generate heuristic``,
or any high-level recording of ToolPick-v0) into transitions of the env's own spaces
(observation 14-D, action 5-D); ``fill_high_level_buffer`` writes them into an SB3 buffer.

The action (paper: "we treat the current latent state of the tweezer as the high-level
policy's action output from the previous time step"). ToolPickEnv.step, when the heuristic
drives it (``command_privileged``), reports ``info["executed_action"]`` =
``clip([z_bar / 3, v_hand / 0.08], -1, 1)``: z_bar the smoothed latent the tool reached at the
end of the step, v_hand the heuristic's commanded arm velocity in the hand frame.
RecordingWrapper records that as the ``/step`` action. Here the latent half is rebuilt from
``/tool/latent`` ``z_smoothed`` at the step's time (``actions="reached"``, the default): for
heuristic recordings this equals the recorded action bit for bit; for a policy's recording it
replaces the commanded goal by the reached latent (``actions="recorded"`` keeps the command).
The velocity half is the recorded one: the heuristic's commanded (not measured) arm velocity,
turned into the hand frame with the hand's rotation after the step. It is clipped to the action
box: the heuristic clips its world-frame components to 0.08 m/s, so a hand-frame component can
exceed 0.08 m/s and is stored as +-1, the nearest action the policy has (3 sphere episodes:
5.6% of steps have a velocity component at +-1). The recording cannot give the unclipped value
(the hand's world rotation is not recorded).

The reward is recomputed with the env's own ``high_level_terms`` for ``reward_config``:
the object-target distance, success and table collision are the recorded step infos
(``object_target_distance``, ``is_success``, ``table_collision``: exact); the tool-object
distance (tool = the grip point between the tips, which needs the world z axis that the
recording does not hold) is recovered from the recorded ``tool_object`` term,
``d = -ln(term) / c_h2`` of the config the episode was recorded with (``recorded_reward``;
by default the one its metadata names, ``reward_config``, and for recordings made before
episodes named it the paper's reward of the default weights; every episode is
checked against it: its sparse, object-target, penalty and absorbing terms, its step reward = the
sum of its terms, and the recovered distance against the tips' midpoint in ``/sim/privileged``).
The relabelled rewards follow ``reward_config``'s mode too: an old recording relabelled for mode
"absorbing" gains the absorbing term on its success step, as the env would pay it now.
With the default config the relabelled rewards equal the recorded ones (bit for bit on the
test datasets; the recovered distance could differ in the last bit); another
weight relabels old demos. A different ``success_radius`` is refused: it would change which
step ends the episode, which a recording cannot relabel.

Filling: ``fill_high_level_buffer`` adds through the buffer's own ``add`` (one transition
at a time, n_envs 1) or in bulk through ``buffer_fill.insert_transitions`` (the
platform's documented bulk path: whole rows of ``n_envs`` transitions, ``pos``/``full``
advanced as ``add`` would).

Kept demo share (``DemoShareReplayBuffer``, ``--demo-share``) or plain pre-fill (``--demo-share 0``,
the paper's). Plain pre-fill lets SAC's own transitions overwrite the demos once the buffer wraps,
and dilutes them before that. ``DemoShareReplayBuffer`` holds the demos in a separate fixed
store (a plain ``ReplayBuffer`` of exactly ``len(demos)`` rows, filled once through
``fill_high_level_buffer``) next to the ordinary ring buffer that ``add`` writes;
``sample(batch_size)`` draws ``round(demo_share * batch_size)`` rows from the demos and the rest
from the ring (all from the demos while the ring is empty). SAC takes it as
``replay_buffer_class=DemoShareReplayBuffer, replay_buffer_kwargs={"demos": transitions,
"demo_share": 0.25}``; ``demo_share`` is a plain attribute (a callback may anneal it, 0 = plain
SAC on its own data); ``save_replay_buffer`` pickles both stores. The demos' rewards are those of
the transitions given: relabel them for the run's ``HighLevelRewardConfig`` first.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from hingelab.envs import TOOL_PICK_ID
from hingelab.envs.rewards import LEGACY_MODE, HighLevelRewardConfig, high_level_terms
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.transitions import Transitions, concat_transitions, episode_transitions, fill_replay_buffer
from hingelab.errors import ConfigError
from hingelab.perception.encoder import load_encoder
from hingelab.tasks import Z_SCALE, observation_dim
from hingelab.training import real_demos
from hingelab.training.buffer_fill import _check_shapes, insert_transitions

OBSERVATION_DIM = observation_dim()  # 14
OBSERVATION_DIMS = (observation_dim(False), observation_dim(True))  # without and with observe_extent
ACTION_DIM = 5
TERMS = ("sparse", "tool_object", "object_target", "penalty")
NEEDED_INFOS = ("object_target_distance", "is_success", "table_collision")
TOPICS = [S.TOPIC_STEP, S.TOPIC_REWARD, S.TOPIC_LATENT, S.TOPIC_PRIVILEGED]
ACTION_MODES = ("reached", "recorded")


def relabel_rewards(tool_object_m: np.ndarray, object_target_m: np.ndarray, table_collision: np.ndarray,
                    config: HighLevelRewardConfig) -> np.ndarray:
    """The env's reward for each step from its distances (m) and table collisions, through the
    env's own ``high_level_terms`` (positions on one axis: ``||(d, 0, 0)|| == d`` exactly)."""
    zero = np.zeros(3)
    out = np.empty(len(tool_object_m))
    for i, (d_tool, d_target, collided) in enumerate(zip(tool_object_m, object_target_m, table_collision)):
        terms = high_level_terms(np.array([d_tool, 0.0, 0.0]), zero, np.array([d_target, 0.0, 0.0]),
                                 bool(collided), config)
        out[i] = float(sum(terms.values()))
    return out


def _at(topic: dict, times: np.ndarray, path: Path, name: str) -> np.ndarray:
    """Rows of ``topic`` logged at exactly ``times`` (the step's log times)."""
    logged = topic["log_time_ns"]
    rows = np.searchsorted(logged, times)
    if (rows >= len(logged)).any() or (logged[np.minimum(rows, len(logged) - 1)] != times).any():
        raise DatasetError(f"{path}: {name} is not logged at every step's time; the recording is incomplete")
    return rows


def _check_episode(episode, path: Path, observation_dim: int) -> None:
    meta = episode.metadata
    task, level = meta.get(S.KEY_TASK), meta.get(S.KEY_ACTION_LEVEL)
    if task != TOOL_PICK_ID or level != "high":
        raise DatasetError(f"{path} is a {task} episode (action level {level!r}), not a {TOOL_PICK_ID} high-level "
                           "recording; give heuristic datasets (hingelab generate heuristic) or high-level ones")
    step = episode.topics.get(S.TOPIC_STEP, {})
    if "reward" not in step:
        raise DatasetError(f"{path} has no learner transitions (/step with reward); record it with RecordingWrapper")
    obs, act = step.get("observation"), step["action"]
    if obs is None or obs.shape[1:] != (observation_dim,) or act.shape[1:] != (ACTION_DIM,):
        raise DatasetError(f"{path} has observations {None if obs is None else obs.shape[1:]} and actions "
                           f"{act.shape[1:]}, not the run's {TOOL_PICK_ID} ({observation_dim},) and ({ACTION_DIM},)"
                           + ("; record the demos with the same observe_extent as the run" if obs is not None
                              and obs.shape[1] in OBSERVATION_DIMS else ""))
    missing = [f"info.{k}" for k in NEEDED_INFOS if f"info.{k}" not in step]
    terms = episode.topics.get(S.TOPIC_REWARD, {})
    missing += [f"{S.TOPIC_REWARD}:{k}" for k in TERMS if k not in terms]
    if S.TOPIC_LATENT not in episode.topics:
        missing.append(f"{S.TOPIC_LATENT}:z_smoothed")
    if missing:
        raise DatasetError(f"{path} does not record {', '.join(missing)}, which the reward relabelling needs; "
                           "re-record it with this hingelab")


def recorded_reward_config(episode) -> HighLevelRewardConfig:
    """The reward config an episode was recorded with: its metadata's ``reward_config``, or, for a
    recording made before episodes named it, the paper's reward with the default weights."""
    text = episode.metadata.get(S.KEY_REWARD_CONFIG)
    if not text:
        return HighLevelRewardConfig(mode=LEGACY_MODE)
    try:
        return HighLevelRewardConfig(**json.loads(text))
    except (ValueError, TypeError) as exc:
        raise DatasetError(f"{episode.path}: its reward_config metadata is not a high-level reward config "
                           f"({type(exc).__name__}: {exc})") from exc


def _episode(episode, index: int, config: HighLevelRewardConfig, recorded: HighLevelRewardConfig | None,
             actions: str, observation_dim: int) -> Transitions:
    path = episode.path
    _check_episode(episode, path, observation_dim)
    recorded = recorded or recorded_reward_config(episode)
    if config.success_radius != recorded.success_radius:
        raise ConfigError(f"a success radius of {config.success_radius} m (recorded in {path}: "
                          f"{recorded.success_radius} m) would change where the recorded episodes end; relabelling "
                          "cannot change that")
    tr = episode_transitions(episode, index)
    m = len(tr)
    step = episode.topics[S.TOPIC_STEP]
    times = step["log_time_ns"][:m]
    terms_topic = episode.topics[S.TOPIC_REWARD]
    rows = _at(terms_topic, times, path, S.TOPIC_REWARD)
    terms = {k: np.asarray(terms_topic[k][rows], float) for k in TERMS}
    d_target = np.asarray(tr.infos["object_target_distance"], float)
    success = np.asarray(tr.infos["is_success"], float) > 0.5
    collided = np.asarray(tr.infos["table_collision"], float) > 0.5
    with np.errstate(divide="ignore"):
        d_tool = -np.log(terms["tool_object"]) / recorded.c_h2  # exp underflow (term 0): infinitely far
    # the recording against the config it is said to be recorded with
    penalty = (d_tool > recorded.far) | (d_target > recorded.far) | collided
    problems = []
    if not np.allclose(terms["sparse"], recorded.c_h1 * success, rtol=0, atol=1e-12):
        problems.append("sparse")
    if not np.allclose(terms["object_target"], recorded.c_h3 * np.exp(-recorded.c_h4 * d_target), rtol=1e-9,
                       atol=1e-12):
        problems.append("object_target")
    if not np.allclose(terms["penalty"], -recorded.c_h5 * penalty, rtol=0, atol=1e-12):
        problems.append("penalty")
    # recordings from before the absorbing term have no such term: it was 0
    absorbing = np.asarray(terms_topic["absorbing"][rows], float) if "absorbing" in terms_topic else np.zeros(m)
    if not np.allclose(absorbing, recorded.absorbing_bonus * success, rtol=1e-12, atol=1e-12):
        problems.append("absorbing")
    if not np.allclose(tr.rewards, sum(terms.values()) + absorbing, rtol=1e-12, atol=1e-12):
        problems.append("reward = sum of the terms")
    privileged = episode.topics.get(S.TOPIC_PRIVILEGED)
    if privileged is not None and {"tip_a", "tip_b", "object_position"} <= privileged.keys():
        p = _at(privileged, times, path, S.TOPIC_PRIVILEGED)
        a, b, obj = privileged["tip_a"][p], privileged["tip_b"][p], privileged["object_position"][p]
        # the grip point lies within half the tip gap of the tips' midpoint
        slack = 0.5 * np.linalg.norm(a - b, axis=1) + 1e-4
        if (np.abs(d_tool - np.linalg.norm(0.5 * (a + b) - obj, axis=1)) > slack).any():
            problems.append("tool_object (against the tips in /sim/privileged)")
    if problems:
        raise DatasetError(f"{path}: the recorded reward terms ({', '.join(problems)}) do not match the reward "
                           f"config it is read as recorded with ({recorded}); pass recorded_reward=")
    tr.infos["tool_object_distance"] = d_tool
    tr.rewards = relabel_rewards(d_tool, d_target, collided, config)
    if actions == "reached":
        latent = episode.topics[S.TOPIC_LATENT]
        z_bar = np.asarray(latent["z_smoothed"][_at(latent, times, path, S.TOPIC_LATENT)], float)
        tr.actions = np.concatenate([np.clip(z_bar / Z_SCALE, -1.0, 1.0), np.asarray(tr.actions[:, 2:], float)],
                                    axis=1)
    return tr


def high_level_transitions(datasets, reward_config: HighLevelRewardConfig | None = None,
                           recorded_reward: HighLevelRewardConfig | None = None, actions: str = "reached",
                           progress: bool = False, observation_dim: int = OBSERVATION_DIM,
                           skipped: list | None = None, encoder_path=None) -> Transitions:
    """The transitions of every episode of ``datasets`` (dataset folders) for ToolPick-v0's
    14-D (``observation_dim``: 17 with ``observe_extent``) / 5-D spaces, rewards relabelled with
    ``reward_config`` (default: the env's default).

    ``recorded_reward``: the config the episodes were recorded with (default: the one each
    episode's metadata names; the paper's reward for recordings that name none). ``actions``: "reached" (the
    paper's: the reached latent / 3 clipped, and the recorded hand velocity) or "recorded".
    Each transition's infos add ``tool_object_distance`` (m). A dataset or episode that is
    not a ToolPick-v0 high-level recording is a one-line DatasetError naming its file.

    Real episodes (source ``real``, ``hingelab datasets import-ros2``) go through
    ``real_demos.real_episode_transitions``: rewards rebuilt from perception and the arm's
    kinematics, the opening read with the calibration of the encoder at ``encoder_path`` (default:
    the shipped one, which the import uses too). One that lacks what it needs raises its one-line
    error, or, with a list as ``skipped``, is left out and appended to it as (path, reason); a
    dataset none of whose real episodes can be used raises the first one's error all the same.
    """
    config = reward_config or HighLevelRewardConfig()
    recorded = recorded_reward
    if actions not in ACTION_MODES:
        raise ConfigError(f"actions must be one of {', '.join(ACTION_MODES)}, not {actions!r}")
    if isinstance(datasets, (str, Path)):
        datasets = [datasets]
    parts, index, calibration = [], 0, None
    for root in datasets:
        root = Path(root)
        if not root.exists():
            raise ConfigError(f"dataset {root} does not exist; give a dataset folder "
                              "(hingelab datasets info lists one)")
        dataset = Dataset(root)
        if len(dataset) == 0:
            raise DatasetError(f"dataset {root} has no finished episodes to learn from")
        left_out, n_real = [], 0
        for episode in dataset.iter_episodes(topics=TOPICS + real_demos.TOPICS, progress=progress):
            if not real_demos.is_real(episode):
                parts.append(_episode(episode, index, config, recorded, actions, observation_dim))
                index += 1
                continue
            n_real += 1
            if calibration is None:

                calibration = load_encoder(encoder_path).calibration
            try:
                parts.append(real_demos.real_episode_transitions(episode, index, config, calibration, actions,
                                                                   observation_dim))
                index += 1
            except real_demos.RealEpisodeError as exc:
                if skipped is None:
                    raise
                left_out.append((str(episode.path), str(exc)))
        if left_out and len(left_out) == n_real:
            raise DatasetError(f"dataset {root}: none of its {len(left_out)} real episodes can be used; "
                               f"the first: {left_out[0][1]}")
        if skipped is not None:
            skipped.extend(left_out)
    if not parts:
        raise ConfigError("no datasets given to pre-fill from")
    return concat_demos(parts)


def concat_demos(parts: list) -> Transitions:
    """``concat_transitions`` of demos of several sources, keeping the infos all of them have (a rig's
    steps carry none of the env's, the env's none of the import's)."""
    common = set.intersection(*(set(p.infos) for p in parts))
    for part in parts:
        part.infos = {k: v for k, v in part.infos.items() if k in common}
    return concat_transitions(parts)


def look_ahead(transitions: Transitions, steps: int) -> Transitions:
    """The latent half of each action replaced by the one ``steps - 1`` transitions later in the same
    episode (the episode's last where it ends sooner): with ``actions="reached"``, the latent the
    tool reached ``steps`` steps after the observation (1: unchanged, the paper's)."""
    if steps < 1:
        raise ConfigError(f"the look-ahead is a number of steps >= 1, not {steps}")
    if steps == 1:
        return transitions
    actions = np.array(transitions.actions, copy=True)
    for episode in np.unique(transitions.episode_index):
        rows = np.flatnonzero(transitions.episode_index == episode)
        later = rows[np.minimum(np.arange(len(rows)) + steps - 1, len(rows) - 1)]
        actions[rows, :2] = transitions.actions[later, :2]
    out = copy.copy(transitions)
    out.actions = actions
    return out


def fill_high_level_buffer(buffer, transitions: Transitions, method: str = "add") -> int:
    """Write ``transitions`` into an SB3 ``ReplayBuffer`` of ToolPick-v0's spaces; the number added.

    ``method``: "add" (the buffer's own ``add``, one transition at a time; n_envs 1) or "bulk"
    (``buffer_fill.insert_transitions``: whole rows of n_envs transitions; a remainder of
    fewer than n_envs is left out). The demos must fit in the room left: pre-filling past the
    end would overwrite the first demos with the last.
    """

    if getattr(buffer.observation_space, "spaces", None) is not None or hasattr(buffer, "ep_length"):
        raise ConfigError("the high-level pre-fill takes a plain ReplayBuffer (ToolPick-v0 has flat observations), "
                          f"not a {type(buffer).__name__}")
    _check_shapes(buffer, transitions)
    room = (buffer.buffer_size - buffer.pos) * buffer.n_envs
    if len(transitions) > room:
        raise ConfigError(f"the datasets hold {len(transitions)} transitions, the replay buffer has room for {room}; "
                          "raise buffer_size or pre-fill from fewer datasets")
    if method == "bulk":
        return insert_transitions(buffer, transitions)
    if method != "add":
        raise ConfigError(f"method must be 'add' or 'bulk', not {method!r}")
    if buffer.n_envs != 1:
        raise ConfigError(f"method 'add' fills a buffer of one env, this one has {buffer.n_envs}; use method='bulk'")
    return fill_replay_buffer(buffer, transitions)


class DemoShareReplayBuffer(ReplayBuffer):
    """SAC's ring buffer plus a kept store of demos, ``demo_share`` of every batch (module docstring)."""

    def __init__(self, buffer_size, observation_space, action_space, device="auto", n_envs: int = 1,
                 optimize_memory_usage: bool = False, handle_timeout_termination: bool = True,
                 demos: Transitions | None = None, demo_share: float = 0.25):
        """``demos=None``: no demo store yet, what a model loaded from a zip builds before its saved
        buffer (with its demos) replaces it (``load_replay_buffer``); it samples its ring alone."""
        super().__init__(buffer_size, observation_space, action_space, device=device, n_envs=n_envs,
                         optimize_memory_usage=optimize_memory_usage,
                         handle_timeout_termination=handle_timeout_termination)
        if demos is not None and len(demos) == 0:
            raise ConfigError("DemoShareReplayBuffer got no demos (high_level_transitions of heuristic datasets)")
        if not 0.0 <= demo_share <= 1.0:
            raise ConfigError(f"demo_share is a fraction of the batch in [0, 1], not {demo_share}")
        self.demo_share = float(demo_share)
        self.demos = None
        if demos is not None:
            self.demos = ReplayBuffer(len(demos), observation_space, action_space, device=device, n_envs=1,
                                      handle_timeout_termination=handle_timeout_termination)
            fill_high_level_buffer(self.demos, demos)

    def sample(self, batch_size: int, env=None) -> ReplayBufferSamples:
        if self.demos is None:
            return super().sample(batch_size, env=env)
        n_demo = batch_size if self.size() == 0 else int(round(self.demo_share * batch_size))
        if n_demo == 0:
            return super().sample(batch_size, env=env)
        demo = self.demos.sample(n_demo, env=env)
        if n_demo == batch_size:
            return demo
        own = super().sample(batch_size - n_demo, env=env)
        return ReplayBufferSamples(*(None if a is None else torch.cat([a, b]) for a, b in zip(demo, own)))


__all__ = ["high_level_transitions", "concat_demos", "look_ahead", "fill_high_level_buffer", "relabel_rewards",
           "recorded_reward_config", "DemoShareReplayBuffer"]
