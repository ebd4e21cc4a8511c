"""Leave-machine-out evaluation on a small simulated product line, and the ``product-line`` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scaletwin.cli import main as cli_main
from scaling.data.product_line import LINKAGE_GROUPS, PI1_LINKAGE, ProductLine, add_design_signals
from scaling.data.recordings import generate_frame
from scaling.dimensions.group_choice import PI1, POSE_GROUPS
from scaling.dimensions.groups import PiGroup
from scaling.evaluation.conformal import RowRisk
from scaling.evaluation.generalisation import (
    INTERVAL_VARIANTS,
    MISS_LINES,
    SERVED_WARNING,
    WARN_VARIANTS,
    Candidate,
    Split,
    cross_fit_served,
    evaluate,
    judged_rows,
)
from scaling.evaluation.metrics import at_stroke_end
from scaling.models import FFNN

LINE = ProductLine(n_machines=6, seed=5, soils=("gravel",), pile_heights=(0.7,), dig_seeds=1, hold_episodes=1,
                   hold_poses=2, presets=("er12",))
GROUPS = (PiGroup({"Pf_tilt": 1, "F31": -1}, name="pt"), *POSE_GROUPS, *LINKAGE_GROUPS)


@pytest.fixture(scope="module")
def frame() -> pd.DataFrame:
    return add_design_signals(generate_frame(LINE.dataset_spec(), executor="serial"), LINE.specs())


@pytest.fixture(scope="module")
def split() -> Split:
    names = [m.name for m in LINE.machines]
    return Split(train=("er12", *names[:3]), calibration=tuple(names[3:5]), test=tuple(names[5:]),
                 specs=LINE.specs())


def test_split_keeps_machines_apart() -> None:
    specs = LINE.specs()
    with pytest.raises(ValueError, match="two sides"):
        Split(train=("er12", "pl5-0"), calibration=("pl5-0", "pl5-1"), test=(), specs=specs)
    with pytest.raises(ValueError, match="no spec"):
        Split(train=("er12",), calibration=("pl5-0", "pl5-1"), test=("nowhere",), specs=specs)
    with pytest.raises(ValueError, match="two calibration machines"):
        Split(train=("er12",), calibration=("pl5-0",), test=(), specs=specs)
    with pytest.raises(ValueError, match="reference"):
        Split(train=("pl5-0",), calibration=("pl5-1", "pl5-2"), test=(), specs=specs)


def test_every_held_out_machine_is_judged_against_the_baselines(frame: pd.DataFrame, split: Split) -> None:
    """Each test machine gets a row per model and baseline; the direct-Pi row equals a hand computation of
    F31_target · π1(matched source row) on the judged rows; a fitted model beats direct-Pi on its training data
    signal (the linkage statics) and its intervals cover something."""
    cands = [Candidate("ffnn", lambda: FFNN(hidden_layers=1, units=16, epochs=60, include_source=True), GROUPS)]
    result = evaluate(frame, split, cands)
    table = result.frame()
    models = {"direct-Pi (ER12)", "direct-Pi (nearest machine)", "ffnn", "linkage statics"}
    assert set(table["model"]) == models
    assert set(table["machine"]) == set(split.test)
    assert (table.groupby("machine").size() == len(models)).all()
    # direct-Pi from the ER12 by hand
    from scaling.data.product_line import match_rows

    by = {m: g.reset_index(drop=True) for m, g in frame.groupby("machine")}
    for m in split.test:
        tgt = by[m][judged_rows(by[m])].reset_index(drop=True)
        src = by["er12"].iloc[match_rows(by["er12"], tgt)].reset_index(drop=True)
        pred = tgt["F31"] * PI1.evaluate(src).reshape(-1)
        err = np.abs(pred - tgt["F21"]) / tgt["F21"]
        ok = np.isfinite(err) & np.all(np.isfinite(np.column_stack([g.evaluate(tgt).reshape(-1) for g in GROUPS])),
                                       axis=1)
        row = table[(table["machine"] == m) & (table["model"] == "direct-Pi (ER12)")].iloc[0]
        assert row.rows == int(ok.sum())
        assert 100 * float(np.mean(err[ok] > 0.1)) == pytest.approx(100 * row.miss_share, abs=1e-9)
    assert table["coverage"].dropna().between(0, 1).all()
    assert table["coverage_spread"].dropna().between(0, 1).all()
    assert set(result.extrapolation["auroc_error_score"]) == models - {"linkage statics"}
    assert set(result.extrapolation["machine_score"]) == set(split.test)
    assert result.fit_seconds["ffnn"] > 0
    # rows more than 10 % off, counted by hand from the table; each flagged by the risk, the stroke end or both
    misses = result.extrapolation["row_risk_misses"]["ffnn"]
    assert set(misses) == set(split.test)
    for m, count in misses.items():
        row = table[(table["machine"] == m) & (table["model"] == "ffnn")].iloc[0]
        assert count["rows"] == round(row.miss_share * row.rows)
        assert max(count["at_stroke_end"], count["warned"]) <= count["flagged"] <= count["rows"]
        assert count["flagged"] <= count["at_stroke_end"] + count["warned"]
        share = result.extrapolation["stroke_end_share"]["ffnn"][m]
        tgt = by[m][judged_rows(by[m])]
        assert 0.0 <= share <= 1.0 and (share > 0) == bool(at_stroke_end(tgt).any())


def test_product_line_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--dry-run lists the machines with their validity values; a real run records every episode and the
    machine table; bad arguments are refused with a message."""
    assert cli_main(["product-line", str(tmp_path / "x"), "--machines", "2", "--seed", "4", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "pl4-0" in out and "pl4-1" in out and "breakout_per_weight" in out
    assert not (tmp_path / "x").exists()
    out_dir = tmp_path / "line"
    assert cli_main(["product-line", str(out_dir), "--machines", "1", "--soils", "gravel", "--holds", "0",
                     "--workers", "serial"]) == 0
    meta = json.loads((out_dir / "machines.json").read_text())
    assert meta["machines"][0]["name"] == "pl0-0" and meta["machines"][0]["validity"]["reasons"] == []
    assert len(list(out_dir.glob("ep-*.parquet"))) == len(ProductLine(1, soils=("gravel",), hold_episodes=0)
                                                             .dataset_spec().tasks())
    assert cli_main(["product-line", str(out_dir), "--machines", "0"]) != 0
    assert cli_main(["product-line", str(out_dir), "--soils", "lava"]) != 0
    assert "lava" in capsys.readouterr().err


def test_relief_share_counts_dig_rows_at_either_relief() -> None:
    """A row counts when the lift or the tilt pressure reaches 98 % of that cylinder's relief (either sign);
    hold episodes are left out."""
    from scaletwin_envs.specs import make_loader
    from scaling.data.product_line import relief_share

    spec = make_loader("er12")
    pl, pt = spec.lift.relief_pressure, spec.tilt.relief_pressure
    frame = pd.DataFrame({"machine": "er12", "kind": ["dig"] * 4 + ["hold"],
                          "p_lift": [0.99 * pl, 0.5 * pl, -0.99 * pl, 0.1 * pl, pl],
                          "p_tilt": [0.0, 0.97 * pt, 0.0, -pt, pt]})
    assert relief_share(frame, {"er12": spec})["er12"] == pytest.approx(3 / 4)


def test_several_sources_give_the_geometric_mean_of_their_forces(frame: pd.DataFrame, split: Split) -> None:
    """A candidate judged from the 2 nearest training machines: its F21 per row is the geometric mean of the forces
    predicted from each source alone (computed here by hand from matched pairs), its ln δ1 recovers that mean from
    the first source's pairs, it reuses the fitted model of the one-source candidate without refitting, and its
    rows name both sources, nearest first."""
    from scaling.data.product_line import matched_pairs, nearest_machines
    from scaling.evaluation.generalisation import combine_sources

    one = Candidate("ffnn", lambda: FFNN(hidden_layers=1, units=16, epochs=60, include_source=True), GROUPS)
    two = Candidate("ffnn, 2 sources", one.build, GROUPS, sources=2, same_model_as="ffnn")
    result = evaluate(frame, split, [one, two])
    assert result.models["ffnn, 2 sources"] is result.models["ffnn"] and "ffnn, 2 sources" not in result.fit_seconds
    model = result.models["ffnn"]
    by = {m: g.reset_index(drop=True) for m, g in frame.groupby("machine")}
    train_specs = {m: split.specs[m] for m in split.train}
    for m in split.test:
        near = nearest_machines(split.specs[m], train_specs, 2)
        row = result.frame().query("machine == @m and model == 'ffnn, 2 sources'").iloc[0]
        assert row.source == "+".join(near)
        tgt = by[m][judged_rows(by[m])].reset_index(drop=True)
        per_source = [matched_pairs(by[s], tgt, PI1, GROUPS) for s in near]
        pairs, log_pred, _, value = combine_sources(model, per_source)
        by_hand = np.sqrt(np.abs(per_source[0].recover(np.exp(model.predict_log(per_source[0])))
                                 * per_source[1].recover(np.exp(model.predict_log(per_source[1])))))
        assert len(pairs) == len(per_source[0]) == len(per_source[1])  # every source matched every judged row
        np.testing.assert_allclose(np.abs(value), by_hand, rtol=1e-9)
        np.testing.assert_allclose(pairs.recover(np.exp(log_pred)), value, rtol=1e-9)
    with pytest.raises(ValueError, match="no earlier fitted"):
        evaluate(frame, split, [Candidate("lonely", one.build, GROUPS, sources=2, same_model_as="ffnn")])


CAL_LINE = ProductLine(n_machines=10, seed=5, soils=("gravel",), pile_heights=(0.7,), dig_seeds=1, hold_episodes=1,
                       hold_poses=2, presets=("er12",))


def test_served_interval_covers_what_it_claims_on_calibration_machines_left_out() -> None:
    """On a small simulated product line (the ER12 and 3 drawn machines train, 7 calibrate), the served interval
    and risk fitted on six calibration machines and judged on the seventh, each in turn
    (``cross_fit_served``): the 90 % interval covers about 90 % of the rows of the machine it never saw (median
    over the seven 0.8–0.97) and the 50 % one about half (0.3–0.7), the pooled bound 90 % of an average machine's
    rows (mean over the seven 0.8–0.97), the bound for 90 % of the machines at least as much as the median
    machine's; every share is a share."""
    frame = add_design_signals(generate_frame(CAL_LINE.dataset_spec(), executor="serial"), CAL_LINE.specs())
    names = [m.name for m in CAL_LINE.machines]
    split = Split(train=("er12", *names[:3]), calibration=tuple(names[3:]), test=(), specs=CAL_LINE.specs())
    cands = [Candidate("ffnn", lambda: FFNN(hidden_layers=1, units=16, epochs=60, include_source=True), GROUPS,
                       PI1_LINKAGE)]
    rows = evaluate(frame, split, cands).calibration_rows["ffnn"]
    assert set(rows["machine"]) == set(split.calibration)
    ninety, half = cross_fit_served(rows, coverage=0.9), cross_fit_served(rows, coverage=0.5)
    served = next(iter(INTERVAL_VARIANTS))
    assert list(ninety.coverage.index) == sorted(split.calibration)
    assert 0.8 <= ninety.coverage[served].median() <= 0.97
    assert 0.3 <= half.coverage[served].median() <= 0.7
    assert 0.8 <= ninety.coverage["average machine (pooled)"].mean() <= 0.97  # its claim: an average machine
    assert ninety.coverage["90 % of machines (before)"].median() >= ninety.coverage[served].median()
    assert ((ninety.warned >= 0) & (ninety.warned <= 1)).all().all()
    summary = ninety.summary()
    assert summary["coverage"][served]["machines"] == 7
    with pytest.raises(ValueError, match="at least three"):
        cross_fit_served(rows[rows["machine"].isin(split.calibration[:2])])
    # the served warning (the interval's risk) and the logistic scores compared with it, each left out in turn
    assert list(ninety.warned.columns) == [SERVED_WARNING, *WARN_VARIANTS]
    assert set(summary["auroc"]) == set(summary["auroc_logistic"]) == {str(line) for line in MISS_LINES}
    assert list(rows.columns[rows.columns.str.startswith("served_")]) == [
        f"served_{k}" for k in range(len(RowRisk.FEATURES))]
    assert np.isfinite(rows[["ln_tilt_load", "ln_spread"]].to_numpy()).all()
