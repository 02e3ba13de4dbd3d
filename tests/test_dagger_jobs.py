"""``--jobs N`` of ``train high --learner dagger|phase-clone`` (``hingelab.workers.job_pool``).

A tiny DAgger run with ``--jobs 2`` makes what ``--jobs 1`` makes: the same prior episodes (a dataset cut into
blocks of episodes, written side by side) and round datasets (one process per dataset), the same labels, the
members' weights bit for bit, the same metrics; the phase clone's run too. A run of ``--jobs 1`` cut off (its last
round's clone and one prior episode gone) resumes with ``--jobs 2`` to the same clone. Bad counts are one-line
errors, and so is a worker's error or death."""

from __future__ import annotations

import io
import os
import shutil
import zipfile

import numpy as np
import pandas as pd
import pytest

from hingelab.episodes.dataset import Dataset
from hingelab.learners.phase_clone.fit import PhaseDemos
from hingelab.training.high_level_demos import high_level_transitions

TINY = ["--low-level", "privileged", "--no-randomize", "--max-episode-steps", "40", "--eval-episodes", "4",
        "--no-progress"]
# the prior: one dataset of 4 episodes (2 blocks of 2 with --jobs 2); each round: 3 datasets of 1 episode (the
# pick table's first 3 sets, one process each)
DAGGER = ["train", "high", "--learner", "dagger", "--prior-episodes", "4", "--clone-updates", "40",
          "--clone-members", "3", "--net-arch", "16", "16", "--dagger-rounds", "2", "--dagger-episodes", "3",
          "--rollout-objects", "all", "--dagger-updates", "30", *TINY]
FIELDS = ("observations", "actions", "phases", "steps", "next_phases")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The tiny DAgger run with --jobs 1 and with --jobs 2."""
    from hingelab.cli.main import main

    root = tmp_path_factory.mktemp("dagger_jobs")
    for jobs in (1, 2):
        assert main([*DAGGER, "--jobs", str(jobs), "--out", str(root / f"jobs{jobs}")]) == 0
    return root / "jobs1", root / "jobs2"


def _weights(path) -> dict:
    with zipfile.ZipFile(path) as archive:
        arrays = np.load(io.BytesIO(archive.read("weights.npz")))
        return {name: arrays[name] for name in arrays.files}


def _assert_same_weights(a, b) -> None:
    wa, wb = _weights(a), _weights(b)
    assert wa.keys() == wb.keys()
    for name in wa:
        np.testing.assert_array_equal(wa[name], wb[name], err_msg=f"{a} {name}")


def _assert_same_episodes(a, b) -> None:
    """The same episodes (seeds) with the same steps and labels; each dataset's files in the same order where one
    process wrote the dataset."""
    index_a, index_b = Dataset(a).build_index(), Dataset(b).build_index()
    assert sorted(index_a["seed"]) == sorted(index_b["seed"]) and len(index_a) > 0
    demos = [PhaseDemos.from_transitions(high_level_transitions([root], actions="recorded")).in_canonical_order()
             for root in (a, b)]
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(demos[0], field), getattr(demos[1], field), err_msg=f"{a} {field}")


def test_two_jobs_make_the_same_prior_weights_labels_and_metrics(runs):
    one, two = runs
    for name in ("base.zip", "rounds/round_1.zip", "rounds/round_2.zip", "model.zip", "best_model.zip"):
        _assert_same_weights(one / name, two / name)
    pd.testing.assert_frame_equal(pd.read_csv(one / "metrics.csv"), pd.read_csv(two / "metrics.csv"))
    _assert_same_episodes(one / "prior", two / "prior")
    for k in (1, 2):
        datasets = sorted(p.parent.relative_to(one) for p in (one / "rounds" / str(k)).glob("*/dataset.json"))
        assert len(datasets) == 3
        for dataset in datasets:
            _assert_same_episodes(one / dataset, two / dataset)
            # one process per dataset: its episodes in the order one process wrote them
            assert len(Dataset(two / dataset).build_index()) == 1
    assert _fit_figures(one) == _fit_figures(two)


def _fit_figures(run) -> list[dict]:
    """The fit figures of each member of the last round's clone (all but the seconds they took)."""
    from hingelab.policies.phase_clone import PhaseClone

    fit = PhaseClone.load(run / "model.zip").hingelab_provenance["fit"]
    return [{k: v for k, v in member.items() if k != "seconds"} for member in fit["member_fits"]]


def test_a_jobs_1_run_cut_off_resumes_with_two_jobs_to_the_same_clone(runs, tmp_path, capsys):
    from hingelab.cli.main import main

    one, _ = runs
    run = tmp_path / "run"
    shutil.copytree(one, run)
    (run / "rounds" / "round_2.zip").unlink()  # killed in round 2, before its clone was saved
    for episode in sorted((run / "prior" / "episodes").glob("*.mcap"))[:1]:
        episode.unlink()  # and a prior that lacks an episode: not trusted, made again
    pd.read_csv(run / "metrics.csv").iloc[:2].to_csv(run / "metrics.csv", index=False)
    assert main(["train", "high", "--learner", "dagger", "--out", str(run), "--resume", "--jobs", "2",
                 "--no-progress"]) == 0
    capsys.readouterr()
    assert len(list((run / "prior" / "episodes").glob("*.mcap"))) == 4
    _assert_same_episodes(one / "prior", run / "prior")
    _assert_same_weights(one / "rounds" / "round_2.zip", run / "rounds" / "round_2.zip")
    pd.testing.assert_frame_equal(pd.read_csv(one / "metrics.csv"), pd.read_csv(run / "metrics.csv"))


def test_the_phase_clone_with_two_jobs_fits_the_same_members(tmp_path):
    from hingelab.cli.main import main

    args = ["train", "high", "--learner", "phase-clone", "--prior-episodes", "3", "--clone-updates", "40",
            "--clone-members", "2", "--net-arch", "16", *TINY]
    for jobs in (1, 2):
        assert main([*args, "--jobs", str(jobs), "--out", str(tmp_path / f"jobs{jobs}")]) == 0
    _assert_same_weights(tmp_path / "jobs1" / "model.zip", tmp_path / "jobs2" / "model.zip")
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "jobs1" / "metrics.csv"),
                                  pd.read_csv(tmp_path / "jobs2" / "metrics.csv"))
    _assert_same_episodes(tmp_path / "jobs1" / "prior", tmp_path / "jobs2" / "prior")


def test_bad_jobs_get_one_line_errors(tmp_path, capsys):
    from hingelab.arguments import available_cores
    from hingelab.cli.main import main

    cases = {"--jobs 0: give 1 or more": ["--jobs", "0"], "--jobs -2: give 1 or more": ["--jobs", "-2"],
             "--allow-oversubscribe": ["--jobs", str(available_cores() + 1)]}
    for k, (message, args) in enumerate(cases.items()):
        for learner in ("dagger", "phase-clone"):
            code = main(["train", "high", "--learner", learner, "--prior-episodes", "1", "--clone-updates", "1",
                         *args, *TINY, "--out", str(tmp_path / f"{learner}{k}")])
            err = capsys.readouterr().err.strip()
            assert code != 0 and message in err and len(err.splitlines()) == 1, (message, err)
            assert not (tmp_path / f"{learner}{k}").exists()


def test_a_workers_error_and_death_surface_in_one_line(tmp_path, capsys):
    from hingelab.cli.main import main
    from hingelab.errors import ConfigError
    from hingelab.policies.phase_clone import PhaseClone
    from hingelab.workers.job_pool import JobPool, WorkerDied

    with JobPool(2) as pool:
        with pytest.raises(ConfigError, match="not a readable phase-clone checkpoint"):
            pool.map(PhaseClone.load, [str(tmp_path / "missing.zip")])
        with pytest.raises(WorkerDied, match="--resume"):
            pool.map(os._exit, [3])
    # a run whose workers fail (the prior's env: no such mesh) ends as a run of one job does
    code = main(["train", "high", "--learner", "dagger", "--prior-episodes", "2", "--clone-updates", "1",
                 "--object", f"mesh:{tmp_path / 'missing.stl'}", "--jobs", "2", *TINY, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and "missing.stl not found" in err and len(err.splitlines()) == 1, err
    assert not list((tmp_path / "r" / "prior" / "episodes").glob("*.mcap"))


def test_work_is_shared_one_process_per_dataset_or_in_blocks():
    from hingelab.training.prior import work_items
    from hingelab.workers.job_pool import chunks

    assert chunks(5, 2) == [range(0, 3), range(3, 5)] and chunks(2, 6) == [range(0, 1), range(1, 2)]
    assert work_items([10] * 12, 2) == [(k, None) for k in range(12)]  # the 12 sets: a process per dataset
    assert work_items([7], 2) == [(0, range(0, 4)), (0, range(4, 7))]  # one dataset: blocks side by side
