"""``hingelab view DATASET``: the overview and every episode in one .rrd, read back with Rerun's
reader; bad input gives one line."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.writer import Writer
from rerun.blueprint.components import PlayState
from rerun.chunk import RrdReader

from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.viewers import entities as E
from hingelab.viewers import view
from hingelab.viewers.blueprints import (
    DATASET_BLUEPRINT_FILE,
    EPISODE_BLUEPRINT_FILE,
    KINDS,
    kind_blueprint_file,
    save_blueprints,
)
from test_view_episode import rrd_tables, sorted_by

OBJECTS = ("sphere", "sphere", "cube", "cube", "cube", "cylinder")  # success rates 1/2, 2/3, 0
LENGTHS = (12, 7, 20, 9, 15, 11)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data") / "mixed"
    create_dataset(root, name="mixed", source="synthetic", config={"n": len(LENGTHS)}, seed=0)
    for seed, n_steps in enumerate(LENGTHS):  # even seeds succeed
        write_synthetic_episode(root, seed=seed, n_steps=n_steps, object=OBJECTS[seed])
    return root


@pytest.fixture(scope="module")
def recording(dataset, tmp_path_factory):
    rrd = tmp_path_factory.mktemp("rrd") / "mixed.rrd"
    result, _ = view(dataset, save=rrd, cloud_every=5, progress=False)
    assert result.kind == "dataset" and result.episodes == len(LENGTHS) and result.steps == sum(LENGTHS)
    return rrd_tables(rrd), Dataset(dataset).index


def test_overview_bar_charts_are_the_success_rates(recording):
    tables, index = recording
    expected = index.assign(success=index["success"].astype(float)).groupby("object")["success"].mean()
    bars = {}  # one named bar per object: {name: (position, rate)}
    for name in ("cube", "cylinder", "sphere"):
        table = tables[f"/{E.SUCCESS_BY_OBJECT}/{name}"]
        values = table.column("BarChart:values").drop_null().to_pylist()[0][0]  # a tensor
        position = table.column("BarChart:abscissa").drop_null().to_pylist()[0][0]
        assert values["shape"] == [1]
        bars[name] = (position["buffer"][0], values["buffer"][0])
    assert [bars[n][0] for n in ("cube", "cylinder", "sphere")] == [0.0, 1.0, 2.0]  # the summary's rows
    np.testing.assert_allclose([bars[n][1] for n in expected.sort_index().index], expected.sort_index().to_numpy())
    np.testing.assert_allclose([bars[n][1] for n in ("cube", "cylinder", "sphere")], [2 / 3, 0.0, 0.5])
    summary = tables["/" + E.SUMMARY].column("TextDocument:text").to_pylist()[0][0]
    assert "| 0 | cube | 3 | 2 | 0.667 |" in summary  # cubes: seeds 2, 4 succeed, 3 fails


def test_per_episode_series_and_latent_plane(recording):
    tables, index = recording
    returns = sorted_by(tables["/" + E.EPISODE_RETURN], E.TIMELINE_EPISODE)
    assert returns.column(E.TIMELINE_EPISODE).to_pylist() == list(range(len(LENGTHS)))
    np.testing.assert_allclose(np.ravel(returns.column("Scalars:scalars").to_pylist()), index["return"])
    # on dataset_step too, at each episode's middle step: inside the episodes' own span, never at an edge
    lengths = index["length"].to_numpy()  # in the recording's order of episodes
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    on_steps = sorted_by(tables["/" + E.EPISODE_RETURN], E.TIMELINE_DATASET_STEP)
    assert on_steps.column(E.TIMELINE_DATASET_STEP).to_pylist() == (starts + (lengths - 1) // 2).tolist()
    np.testing.assert_allclose(np.ravel(on_steps.column("Scalars:scalars").to_pylist()), index["return"])
    lengths = sorted_by(tables["/" + E.EPISODE_LENGTH], E.TIMELINE_EPISODE)
    assert np.ravel(lengths.column("Scalars:scalars").to_pylist()).tolist() == index["length"].astype(float).tolist()
    plane = tables["/" + E.ALL_LATENTS].column("Points2D:positions").to_pylist()
    assert sum(len(row) for row in plane if row) == sum(LENGTHS)  # every step's z of every episode


def test_every_episode_back_to_back(recording):
    tables, index = recording
    latent = sorted_by(tables["/" + E.LATENT_Z], E.TIMELINE_DATASET_STEP)
    assert latent.num_rows == sum(LENGTHS)
    assert latent.column(E.TIMELINE_DATASET_STEP).to_pylist() == list(range(sum(LENGTHS)))
    per_episode = np.bincount(latent.column(E.TIMELINE_EPISODE).to_numpy())
    assert per_episode.tolist() == index["length"].tolist()
    clouds = sorted_by(tables["/" + E.TOOL_CLOUD], E.TIMELINE_DATASET_STEP)
    kept = sum(len({*range(0, n, 5), n - 1}) for n in index["length"])  # every 5th step and the last
    assert clouds.num_rows == kept
    assert {len(row) for row in clouds.column("Points3D:positions").to_pylist()} == {256}
    facts = sorted_by(tables["/" + E.FACTS], E.TIMELINE_EPISODE)
    assert facts.num_rows == len(LENGTHS)
    events = sorted_by(tables["/" + E.EVENTS], E.TIMELINE_DATASET_STEP).column("TextLog:text").to_pylist()
    outcomes = [text[0] for text in events]
    assert outcomes == ["success" if s else "failure: timeout" for s in index["success"]]
    hand = sorted_by(tables[f"/{E.ROBOT}/hand_base"], E.TIMELINE_DATASET_STEP)  # the scene, posed with the clouds
    assert hand.column(E.TIMELINE_DATASET_STEP).to_pylist() == clouds.column(E.TIMELINE_DATASET_STEP).to_pylist()
    assert tables[f"/{E.ROBOT}/tool_leg_a"].column("Mesh3D:vertex_positions").drop_null().to_pylist()


def test_blueprint_files_are_saved(tmp_path):
    written = save_blueprints(tmp_path)
    assert [p.name for p in written] == [EPISODE_BLUEPRINT_FILE, DATASET_BLUEPRINT_FILE] + [
        kind_blueprint_file(kind) for kind in KINDS]
    assert all(p.stat().st_size > 1000 for p in written)
    # each layout opens on the timeline its series are drawn against (not whichever the viewer picks)
    for name, timeline in ((EPISODE_BLUEPRINT_FILE, E.TIMELINE_STEP), (DATASET_BLUEPRINT_FILE, E.TIMELINE_DATASET_STEP),
                           (kind_blueprint_file("trial"), E.TIMELINE_DATASET_STEP)):
        reader = RrdReader(tmp_path / name)
        chunks = reader.stream(store=reader.blueprints()[0]).to_chunks()
        rows = [row for chunk in chunks if str(chunk.entity_path) == "/time_panel"
                for row in chunk.to_record_batch().to_pylist()]
        assert [row["TimePanelBlueprint:timeline"] for row in rows if "TimePanelBlueprint:timeline" in row] == [
            [timeline]], name
        paused = PlayState.Paused.value  # paused: the per-episode plots keep their range, not follow a cursor
        assert [row["TimePanelBlueprint:play_state"] for row in rows if "TimePanelBlueprint:play_state" in row] == [
            [paused]], name


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: "), err
    return err[0]


def test_bad_input_is_one_line(tmp_path, capsys):
    save = str(tmp_path / "out.rrd")
    assert main(["view", str(tmp_path / "missing"), "--save", save]) == 1
    assert "does not exist" in one_line_error(capsys)

    empty = tmp_path / "empty"
    create_dataset(empty, name="empty", source="synthetic", config={}, seed=0)
    (empty / "episodes").mkdir(exist_ok=True)
    assert main(["view", str(empty), "--save", save]) == 1
    assert "has no episodes" in one_line_error(capsys)

    bare = tmp_path / "bare"
    bare.mkdir()
    assert main(["view", str(bare), "--save", save]) == 1
    assert "empty folder" in one_line_error(capsys)

    no_outcomes = tmp_path / "no_outcomes"
    create_dataset(no_outcomes, name="no_outcomes", source="foreign", config={}, seed=0)
    (no_outcomes / "episodes").mkdir(exist_ok=True)
    with open(no_outcomes / "episodes" / "foreign-1.mcap", "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("episode", {"source": "foreign", "seed": "1", "schema_version": "1"})
        writer.finish()
    assert main(["view", str(no_outcomes), "--save", save]) == 1
    assert "records 'success'" in one_line_error(capsys)

    not_mcap = tmp_path / "notes.txt"
    not_mcap.write_text("x")
    assert main(["view", str(not_mcap), "--save", save]) == 1
    assert "not an episode file" in one_line_error(capsys)

    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 20)
    assert main(["view", str(broken), "--save", save]) == 1
    assert "broken.mcap" in one_line_error(capsys)
    assert not (tmp_path / "out.rrd").exists()


def test_foxglove_layout_names_contract_topics():
    import json

    from hingelab.episodes import schemas as S
    from hingelab.paths import REPO_ROOT

    layout = json.loads((REPO_ROOT / "viewers" / "foxglove_layout.json").read_text())
    panels = set(layout["configById"])

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)  # every panel placed, none dangling
    three_d = layout["configById"]["3D!hingelab_tool"]
    assert three_d["followTf"] == "hand_base" and {S.TOPIC_POINTS, S.TOPIC_TF} <= set(three_d["topics"])
    paths = [p["value"] for c in layout["configById"].values() for p in c.get("paths", [])]
    assert {"/tool/latent.z[0]", "/tool/latent.z_smoothed[1]", "/sim/privileged.hinge_angle",
            "/reward/terms.total"} <= set(paths)
    assert {path.split(".")[0] for path in paths} <= set(S.TOPIC_TYPES)


def test_the_per_episode_plots_span_the_recording(tmp_path):
    # Rerun's default x range is a window of about 1,000 around the cursor: the plots get the recording's span
    from hingelab.viewers.blueprints import dataset_blueprint

    def view_ranges(blueprint):
        path = tmp_path / "layout.rbl"
        blueprint.save(E.APPLICATION_ID, path)
        reader = RrdReader(path)
        return [row["TimeAxis:view_range"] for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks()
                for row in chunk.to_record_batch().to_pylist() if "TimeAxis:view_range" in row]

    steps = 5260  # 50 episodes of about 105 steps: a 2 % margin each side
    assert view_ranges(dataset_blueprint(extent=(50, steps))) == [[{"start": -105, "end": steps - 1 + 105}]] * 3
    assert view_ranges(dataset_blueprint()) == []
