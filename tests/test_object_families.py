"""Procedural object families (``family:NAME[:SEED]``): the meshes, their draws and records, ToolPick-v0 on them,
what ``generate heuristic`` and ``hingelab trial`` record, and the errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hingelab.errors import ConfigError
from hingelab.sim import object_families as F
from hingelab.sim.objects import MASS_LIMITS, SHAPES, SIZE_LIMITS, ObjectSpec


def _draw(name, seed, cap=0.03):
    return F.ObjectFamily.parse(f"family:{name}", cap).draw(seed)


@pytest.mark.parametrize("kind", F.KINDS)
def test_every_kind_builds_graspable_sized_convex_meshes(kind):
    for cap, seeds in ((0.03, range(4)), (0.008, range(2))):
        for seed in seeds:
            mesh = F.ObjectFamily.parse(f"family:{kind}", cap).draw_mesh(seed)
            assert mesh.kind == kind
            extent = mesh.extent
            size = mesh.params["size"]
            assert F.FAMILY_SIZE_RANGE[0] <= size <= cap
            assert extent.max() == pytest.approx(size, abs=1e-12)  # the largest extent is the drawn size
            assert extent[1] >= SIZE_LIMITS[0] and extent[2] >= F.MIN_HEIGHT  # the tips reach it and close on it
            every = np.concatenate([p.vertices for p in mesh.pieces])
            np.testing.assert_allclose((every.max(axis=0) + every.min(axis=0)) / 2, 0, atol=1e-12)  # box-centred
            for piece in mesh.pieces:
                assert piece.is_watertight and piece.is_convex and piece.volume > 0
            assert len(mesh.pieces) == (12 if kind in F.GROUPS["ring"] else 1)
            obj = F.drawn_object(mesh)
            assert obj.height == pytest.approx(extent[2]) and obj.rest_height == pytest.approx(extent[2] / 2)
            assert obj.centre_height == 0.0 and obj.is_mesh
            assert obj.width_at(obj.height / 2) <= extent[1] + 1e-12
            assert obj.mass == pytest.approx(np.clip(F.TRAINING_DENSITY * mesh.volume, *MASS_LIMITS))
            assert sum(m for _, m in obj.mesh_pieces()) == pytest.approx(obj.mass)


def test_rebuilding_a_record_gives_the_same_mesh_bit_for_bit():
    for kind in F.KINDS:
        record = json.loads(json.dumps(_draw(kind, 7).record))  # as an episode's metadata holds it
        drawn = F.build(record["kind"], record["params"])
        F._build.cache_clear()  # built again from the parameters, not taken from the cache
        again = F.rebuild(record)
        assert again.sha256 == record["mesh_sha256"] == F.mesh_sha256(again.pieces)
        for a, b in zip(drawn.pieces, again.pieces):
            assert a is not b
            assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    record["params"]["size"] *= 1.01
    with pytest.raises(ConfigError, match="not the recorded"):
        F.rebuild(record)


def test_draws_depend_on_the_episode_and_family_seeds_only_and_the_split_holds():
    assert _draw("train", 3).record == _draw("train", 3).record
    assert _draw("train", 3) == _draw("train", 3)  # frozen and comparable, as ObjectSpec
    assert _draw("train", 3).record != _draw("train", 4).record
    assert _draw("train:1", 3).record != _draw("train", 3).record != _draw("train:2", 3).record
    assert _draw("train:1", 3).record["family"] == "family:train:1"
    holdout = {_draw("holdout", s).record["kind"] for s in range(60)}
    train = {_draw("train", s).record["kind"] for s in range(60)}
    assert holdout == set(F.HOLDOUT_KINDS) and len(holdout) >= 6 and train == set(F.TRAIN_KINDS)
    assert not holdout & train and not set(SHAPES) & set(F.NAMES)  # none of the paper's shapes either
    hashes = {_draw("holdout", s).record["mesh_sha256"] for s in range(20)}
    assert len(hashes) == 20  # a new object every episode


def test_the_density_sets_the_mass():
    assert F.TRAINING_DENSITY * 4 / 3 * np.pi * 0.01 ** 3 == pytest.approx(0.010)  # the 10 g, 2 cm sphere
    family = F.ObjectFamily.parse("family:rounded_box", 0.03, density=1000.0)
    obj = family.draw(2)
    mesh = family.draw_mesh(2)
    assert obj.mass == pytest.approx(max(1000.0 * mesh.volume, MASS_LIMITS[0]))
    assert obj.record["density_kg_m3"] == 1000.0 and obj.record["mass_kg"] == obj.mass


def _one_line(make):
    with pytest.raises(ConfigError) as caught:
        make()
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_bad_names_seeds_and_sizes_give_one_line_errors():
    parse = F.ObjectFamily.parse
    message = _one_line(lambda: parse("family:banana", 0.02))
    assert "'banana'" in message and "holdout" in message and "ellipsoid" in message
    for text in ("family:", "family:train:1:2", "family:Train"):
        assert "family:NAME[:SEED]" in _one_line(lambda: parse(text, 0.02))
    for seed in ("x", "-1", "1.5", str(2 ** 31)):
        assert "not an integer" in _one_line(lambda: parse(f"family:train:{seed}", 0.02))
    for size in (0.005, 0.031, 0.5, float("nan")):
        message = _one_line(lambda: parse("family:holdout", size))
        assert "8 to 30 mm" in message and "--size" in message
    assert "drawn per episode" in _one_line(lambda: ObjectSpec("family:train", 0.02, 0.01))
    assert "family:NAME[:SEED]" in _one_line(lambda: ObjectSpec("banana", 0.02, 0.01))

    import gymnasium as gym

    import hingelab.envs  # noqa: F401  (registers the envs)

    assert "'banana'" in _one_line(lambda: gym.make("hingelab/ToolPick-v0", object="family:banana"))
    assert "--size" in _one_line(lambda: gym.make("hingelab/ToolPick-v0", object="family:ring", size=0.04))


def _seed_drawing(name, kind, cap=0.03):
    return next(s for s in range(1000) if _draw(name, s, cap).record["kind"] == kind)


def test_tool_pick_draws_an_object_per_episode_that_rests_and_steps():
    import gymnasium as gym

    import hingelab.envs  # noqa: F401
    from hingelab.sim import scripted

    env = gym.make("hingelab/ToolPick-v0", object="family:holdout", size=0.03)
    pick = env.unwrapped
    try:
        seeds = [_seed_drawing("holdout", kind) for kind in ("torus", "prism3", "polytope")]
        for seed in seeds + seeds[:1]:
            env.reset(seed=seed)
            model = pick.sim.model
            record = pick.object_record
            assert record == _draw("holdout", seed).record and pick.object.record == record
            assert len(pick._object_geoms) == (12 if record["kind"] == "torus" else 1)
            assert model.body("object").mass[0] == pytest.approx(record["mass_kg"])
            start = pick.state.object_pos_world.copy()
            assert start[2] - scripted.platform_top(model) == pytest.approx(pick.object.rest_height, abs=1e-9)
            # the bounding box the env observes is the drawn one's (MuJoCo's geom boxes around its pieces)
            np.testing.assert_allclose(pick.observed_object_extent(), F.build(record["kind"], record["params"]).extent,
                                       atol=2e-4)
            for _ in range(10):
                _, _, terminated, truncated, info = env.step(np.zeros(5))
                assert not truncated and info.get("failure_reason") != "divergence"
            moved = pick.state.object_pos_world - start
            assert np.linalg.norm(moved) < 0.002 and np.isfinite(pick.sim.data.qpos).all()
        env.reset(seed=seeds[0])
        assert pick.sim.model is model  # the same draw again: the model is kept, not rebuilt
    finally:
        env.close()


def test_the_fixed_objects_keep_their_model_and_record_nothing():
    import gymnasium as gym

    import hingelab.envs  # noqa: F401

    env = gym.make("hingelab/ToolPick-v0", object="cube", size=0.02)
    try:
        model = env.unwrapped.sim.model
        for seed in (0, 1):
            env.reset(seed=seed)
        assert env.unwrapped.sim.model is model and env.unwrapped.object_record is None
        assert env.unwrapped.object == ObjectSpec("cube", 0.02, 0.01)
    finally:
        env.close()


def test_generate_heuristic_records_each_draw_and_the_files_read_with_mcap(tmp_path, capsys):
    from mcap.reader import make_reader

    from hingelab.cli.main import main
    from hingelab.episodes import schemas as S
    from hingelab.episodes.dataset import Dataset
    from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset

    out = tmp_path / "family_demos"
    summaries = generate_heuristic_dataset(out, HeuristicRunConfig(episodes=2, object="family:ring:4", size=0.03,
                                                                   max_episode_steps=8), progress=False)
    assert len(summaries) == 2
    dataset = Dataset(out)
    assert set(dataset.index["object"]) == {"family:ring:4"}
    records = {}
    for path in dataset.paths():
        with open(path, "rb") as f:  # the plain mcap library, no hingelab
            metadata = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
        for name in (S.METADATA_EPISODE_START, S.METADATA_EPISODE):
            meta = metadata[name]
            record = json.loads(meta[S.KEY_OBJECT_DRAW])
            assert meta[S.KEY_OBJECT] == "family:ring:4" and meta[S.KEY_OBJECT_KIND] == record["kind"]
            assert record["kind"] in F.GROUPS["ring"] and float(meta["object_size"]) == record["size_m"] <= 0.03
        assert record == _draw("ring:4", int(meta[S.KEY_SEED])).record
        assert F.rebuild(record).sha256 == record["mesh_sha256"]
        records[record["mesh_sha256"]] = record
    assert len(records) == 2  # each episode its own object

    code = main(["generate", "heuristic", "--episodes", "1", "--object", "family:nope", "--out",
                 str(tmp_path / "bad"), "--no-progress"])
    assert code != 0
    err = capsys.readouterr().err.strip()
    assert "unknown object family 'nope'" in err and "\n" not in err and not (tmp_path / "bad").exists()


def test_a_trial_on_the_stand_in_records_the_draw_its_env_made(tmp_path):
    from hingelab.episodes import create_dataset, read_episode
    from hingelab.episodes import schemas as S
    from hingelab.robot.controller import HierarchicalController, ScriptedStandInHighLevel
    from hingelab.robot.stand_in import StandInRobot
    from hingelab.robot.trial import TrialConfig, run_trials

    robot = StandInRobot("family:prism", 0.03, max_steps=4)  # camera perception: its renderer follows the rebuilds
    try:
        controller = HierarchicalController(ScriptedStandInHighLevel(robot))
        create_dataset(tmp_path, name="t", source="stand_in", seed=0, config={})
        config = TrialConfig(object="family:prism", size=0.03, trials=2, max_steps=4, depth_every=2)
        table = run_trials(robot, controller, tmp_path, config, progress=False)
        env_record = robot.pick.object_record  # the env's draw for the last trial
        by_seed = {}
        for path in sorted((tmp_path / "episodes").glob("*.mcap")):
            meta = read_episode(path).metadata
            by_seed[int(meta[S.KEY_SEED])] = json.loads(meta[S.KEY_OBJECT_DRAW])
        # an intermittent failure was seen once in a full run; name every side so the next one says which differs
        seeds = [int(s) for s in table["seed"]]
        assert sorted(by_seed) == sorted(seeds), (by_seed.keys(), seeds)
        for seed, record in by_seed.items():
            expected = _draw("prism", seed).record
            assert record == expected, f"seed {seed}: recorded {record} but the family draws {expected}"
        assert len({r["mesh_sha256"] for r in by_seed.values()}) == 2
        last = by_seed[seeds[-1]]
        assert env_record == last, f"the env drew {env_record} for seed {seeds[-1]}; the trial recorded {last}"
    finally:
        robot.close()


def test_picksets_draws_the_pick_tables_twelve_primitives_as_the_fixed_objects_are():
    import gymnasium as gym

    from hingelab.sim.objects import PICK_SETS

    family = F.ObjectFamily.parse("family:picksets", 0.02)
    drawn = [family.draw(seed) for seed in range(300)]
    assert {(o.shape, o.size) for o in drawn} == set(PICK_SETS)  # every set comes up, nothing else
    assert all(o.mass == 0.010 and not o.is_mesh for o in drawn)
    with pytest.raises(ConfigError, match="a MuJoCo primitive, not a drawn mesh"):
        F.rebuild(drawn[0].record)
    env = gym.make("hingelab/ToolPick-v0", object="family:picksets", low_level="privileged", randomize=False)
    seed = next(s for s, o in enumerate(drawn) if o.shape == "tetrahedron")
    env.reset(seed=seed)
    pick = env.unwrapped
    assert pick.object_record["kind"] == "tetrahedron"
    fixed = gym.make("hingelab/ToolPick-v0", object="tetrahedron", size=drawn[seed].size, low_level="privileged",
                     randomize=False)
    fixed.reset(seed=seed)
    np.testing.assert_allclose(pick.observed_object_extent(), fixed.unwrapped.observed_object_extent(), atol=1e-9)
    env.close()
    fixed.close()


def test_train_plus_picksets_draws_the_pick_sets_or_a_train_kind_as_those_families_would():
    mix = F.ObjectFamily.parse("family:train+picksets", 0.03)
    picksets, train = F.ObjectFamily.parse("family:picksets", 0.03), F.ObjectFamily.parse("family:train", 0.03)
    drawn = [mix.draw(seed) for seed in range(120)]
    sets = [seed for seed, o in enumerate(drawn) if not o.is_mesh]
    assert 8 <= len(sets) <= 35  # about one in six
    assert {o.record["kind"] for o in drawn if o.is_mesh} == set(F.TRAIN_KINDS)
    for seed in sets[:5]:
        assert drawn[seed].record["kind"] == picksets.draw(seed).record["kind"]
    meshes = [seed for seed in range(120) if seed not in sets]
    for seed in meshes[:5]:
        own, train_draw = drawn[seed].record, train.draw(seed).record
        assert own["mesh_sha256"] == train_draw["mesh_sha256"] and own["family"] == "family:train+picksets"
    assert [mix.draw(seed).record for seed in range(20)] == [o.record for o in drawn[:20]]  # repeatable


def test_pick_set_weights_shift_the_draws_repeatably_and_bad_weights_give_one_line_errors():
    from dataclasses import replace

    import gymnasium as gym

    from hingelab.sim.objects import PICK_SETS

    family = F.ObjectFamily.parse("family:picksets", 0.02)
    weighted = replace(family, set_weights=F.pick_set_weights({"tetrahedron:0.015": 11}, family))
    assert weighted.set_weights[PICK_SETS.index(("tetrahedron", 0.015))] == pytest.approx(0.5)
    drawn = [weighted.draw(seed) for seed in range(400)]
    share = np.mean([(o.shape, o.size) == ("tetrahedron", 0.015) for o in drawn])
    assert 0.42 < share < 0.58  # half the episodes, where uniform draws give one in twelve
    assert {(o.shape, o.size) for o in drawn} == set(PICK_SETS)  # the others still come up
    assert [weighted.draw(s).record for s in range(10)] == [o.record for o in drawn[:10]]  # seed-determined
    env = gym.make("hingelab/ToolPick-v0", object="family:picksets", low_level="privileged", randomize=False,
                   pick_set_weights={"tetrahedron:0.015": 11})
    env.reset(seed=3)
    assert env.unwrapped.object_record == drawn[3].record
    env.close()
    for bad, message in [({"tetra:0.015": 2}, "is not a pick set"), ({"cube:0.025": 0}, "positive number"),
                         ({"cube:0.025": float("nan")}, "positive number"), ({"cube:0.025": "2"}, "positive number")]:
        with pytest.raises(ConfigError, match=message):
            F.pick_set_weights(bad, family)
    with pytest.raises(ConfigError, match="weighs the pick sets of family:picksets"):
        gym.make("hingelab/ToolPick-v0", object="sphere", pick_set_weights={"cube:0.02": 2})
