"""`hingelab diagnose grasp`: where the tips hold the object at the lift, and whether that explains failed picks."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.rollouts import grasp_observability as O
from hingelab.rollouts import grasp_offsets as G


def test_the_lift_is_the_first_upward_command_after_the_descent():
    actions = np.zeros((10, 5))
    actions[0, 2] = 0.5  # an upward command before any descent is not the lift
    actions[2:5, 2] = -0.8
    actions[7:, 2] = 0.5
    assert G.lift_step(actions) == 7
    assert G.lift_step(np.zeros((10, 5))) is None  # never descended
    actions[7:, 2] = 0.0
    assert G.lift_step(actions) is None  # descended, never lifted


def _row(dataset, z, success, x=9.0, y=0.0):
    return {"dataset": dataset, "policy": "p", "object": "tetrahedron", "size_m": 0.015, "episode": 0, "seed": 0,
            "first_attempt_success": success, "failure_reason": "" if success else "slip", "lift_step": 60,
            "offset_x_mm": x, "offset_y_mm": y, "offset_z_mm": z, "closing_axis": "y", "hinge_rad": 0.04}


def test_the_verdict_can_say_yes_and_no():
    reference = [_row("ref", z, True) for z in np.linspace(-0.5, 1.0, 10)]
    ranges = G.reference_ranges(reference)
    assert ranges["z"] == pytest.approx((-0.5, 1.0))
    # the failures sit outside the reference's z range and the picks inside: explained, along z
    off_centre = [_row("a", z, True) for z in (0.0, 0.3, 0.6)] + [_row("a", z, False) for z in (1.8, 2.5, 3.0)]
    # the failures sit where the reference picked: not explained
    centred = [_row("b", z, True) for z in (0.0, 0.3, 0.6)] + [_row("b", z, False) for z in (0.1, 0.5, 0.7)]
    thin = [_row("c", z, True) for z in (0.0, 0.3)] + [_row("c", z, False) for z in (1.8, 2.5)]  # two failures
    summary = G.summarize(off_centre + centred + thin, ranges)
    assert "along z" in G.verdict(summary, "a") and "explains its failures" in G.verdict(summary, "a")
    assert "does not explain its failures" in G.verdict(summary, "b")
    assert "too few to tell" in G.verdict(summary, "c")
    z = next(s for s in summary if s["dataset"] == "a" and s["axis"] == "z")
    assert (z["inside"], z["failed_inside"], z["outside"], z["failed_outside"]) == (3, 0, 3, 3)
    with pytest.raises(ConfigError, match="at least 5"):
        G.reference_ranges(reference[:4])


def test_diagnose_grasp_reads_an_eval_dataset_and_refuses_a_thin_reference(tmp_path, capsys):
    out = tmp_path / "scripted"
    assert main(["eval", "high", "--baseline", "scripted", "--object", "tetrahedron", "--size", "0.015",
                 "--episodes", "2", "--seed", "3", "--out", str(out), "--no-progress"]) == 0
    rows = G.episode_rows(out)
    assert len(rows) == 2
    for row in rows:
        assert row["lift_step"] > 0 and row["closing_axis"] == "y"  # the tips close along the hand's y axis
        offset = np.array([row[f"offset_{ax}_mm"] for ax in G.AXES])
        assert np.isfinite(offset).all() and abs(row["offset_y_mm"]) < 3 and abs(row["offset_z_mm"]) < 5
    capsys.readouterr()
    code = main(["diagnose", "grasp", str(out), "--reference", str(out), "--out", str(tmp_path / "report"),
                 "--allow-dirty"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "at least 5" in err and len(err.splitlines()) == 1
    code = main(["diagnose", "grasp-observability", str(out), "--out", str(tmp_path / "seen"), "--allow-dirty"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "at least 30" in err and len(err.splitlines()) == 1
    inputs, offsets = O.samples([out])  # below the floor for a verdict, but the inputs line up
    assert 1 <= len(offsets) <= 2 and offsets.shape[1] == 3  # the scripted lifts hold the object between the tips
    widths = {name: inputs[name].shape for name in O.INPUTS}
    assert widths == {"observation": (len(offsets), 14), "true tool pose": (len(offsets), 15),
                      "true tool pose and object": (len(offsets), 15)}


def test_observability_tells_a_seen_offset_from_a_hidden_one():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(300, 3))
    seen = truth + 0.1 * rng.normal(size=(300, 3))  # the offset in the input, with a little noise
    hidden = rng.normal(size=(300, 3))  # nothing of it
    assert O.held_out_r2(seen, truth[:, 0], seed=0) > 0.9
    assert O.held_out_r2(hidden, truth[:, 0], seed=0) < 0.1
    rows = [{"input": name, "episodes": 300, **{f"r2_{a}": r for a in G.AXES}, **{f"offset_{a}_sd_mm": 1.0
                                                                                for a in G.AXES}}
            for name, r in zip(O.INPUTS, (0.2, 0.9, 1.0))]
    assert "the tool-pose estimate is what the policy cannot see past" in O.verdict(rows, "z")
    rows[0]["r2_z"] = 0.8
    assert "the information is there" in O.verdict(rows, "z")
    rows[0]["r2_z"], rows[1]["r2_z"] = 0.2, 0.3
    assert "does not recover it" in O.verdict(rows, "z")
