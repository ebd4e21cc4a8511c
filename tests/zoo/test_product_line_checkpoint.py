"""The product-line checkpoint: built on a tiny line, its card reports every held-out machine, it serves what the
fitted model predicts on matched source rows, its interval is learnt per row on the calibration machines (the
pooled residual quantile row by row)."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from safetensors.numpy import load_file

import zoo
from scaling.data.delta_dataset import DeltaDataset
from scaling.data.product_line import PI1_LINKAGE, match_rows, nearest_machine, nearest_machines
from scaling.evaluation.conformal import IntervalRisk, RowInterval, RowRisk, group_weighted_quantile
from scaling.evaluation.generalisation import (
    LeaveMachineOut,
    Split,
    finite_groups,
    judged_rows,
    row_kinds,
)
from scaling.models import load_model
from scaling.models.fitted import model_groups
from zoo.product_line import NAME, ProductLineBuild, build_product_line
from zoo.scaling_kind import save_scaling_model

TINY = LeaveMachineOut(n_train=3, n_calibration=2, n_test=1, soils=("gravel",), test_presets=("mini",),
                       pile_heights=(0.7,), hold_episodes=1)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, ProductLineBuild]:
    root = tmp_path_factory.mktemp("pl")
    registry = root / "registry.json"
    registry.write_text(json.dumps({"format_version": 1, "checkpoints": {}}))
    cfg = ProductLineBuild(data_dir=root / "data", layout=TINY, out_root=root / "checkpoints", registry=registry,
                           progress=False, net={"hidden_layers": 1, "units": 16, "lr": 1e-3, "epochs": 30,
                                                "threads": 1})
    return build_product_line(cfg), registry, cfg


def test_card_reports_every_held_out_machine(built: tuple[Path, Path, ProductLineBuild]) -> None:
    _, registry, cfg = built
    card = zoo.card(NAME, registry)
    split = cfg.layout.split()
    metrics = card["metrics"]["held_out_machines"]
    assert set(metrics) == set(split.test) == {"pl1-0", "mini"}
    for m in metrics.values():
        assert m["rows"] > 0 and 0 <= m["interval_coverage"] <= 1
        assert np.isfinite(m["dynamic_mape_pct"]) and np.isfinite(m["direct_pi_dynamic_mape_pct"])
    assert card["training"]["machines"] == list(split.train)
    assert card["training"]["calibration_machines"] == list(split.calibration)
    assert not set(card["training"]["machines"]) & set(metrics)  # no held-out machine was trained on
    assert card["training"]["model"]["config"]["include_source"] is True
    summary = card["metrics"]["summary"]
    # the risk is read off the interval (IntervalRisk): calibrated whether or not a calibration row missed
    assert card["risk"]["score"]["kind"] == "interval" and card["risk"]["score"]["warn_probability"] == 0.5
    assert summary["risk_unavailable"] is None
    assert summary["risk_auroc"] is None or 0 <= summary["risk_auroc"] <= 1  # None: no held-out row 10 % off
    assert all(0 <= m["risk_warned_share"] <= 1 for m in metrics.values())


def test_interval_is_the_calibration_machines_quantile(built: tuple[Path, Path, ProductLineBuild]) -> None:
    """The card's 90 % residual interval is the group-weighted 5 % / 95 % quantile of ln δ1 residuals of the
    model on matched rows of the calibration machines (recomputed here from the recordings)."""
    path, _, cfg = built
    card = zoo.card(path)
    model = load_model(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    split = cfg.layout.split()
    res, grp = [], []
    by = {m: g.reset_index(drop=True) for m, g in frame.groupby("machine")}
    for m in split.calibration:
        src = nearest_machine(split.specs[m], {t: split.specs[t] for t in split.train})
        tgt = by[m][judged_rows(by[m])].reset_index(drop=True)
        pairs = DeltaDataset.from_matched(by[src].iloc[match_rows(by[src], tgt)], tgt, PI1_LINKAGE,
                                          model_groups(model)[1])
        res.append(pairs.log_delta - model.predict_log(pairs))
        grp.append(np.full(len(pairs), m))
    r, g = np.concatenate(res), np.concatenate(grp)
    lo, hi = card["interval"]["log_delta_residual_quantiles"]["0.9"]
    assert hi == pytest.approx(group_weighted_quantile(r, g, 0.95), rel=1e-6)
    assert lo == pytest.approx(-group_weighted_quantile(-r, g, 0.95), rel=1e-6)


def test_served_model_predicts_on_matched_source_rows(built: tuple[Path, Path, ProductLineBuild]) -> None:
    """Loaded by name, with one matched source row per target row, the served δ1 equals the fitted model's on the
    same pairs; the target needs no F21 (drop it and the answer is the same)."""
    path, registry, cfg = built
    served = zoo.load(NAME, registry)
    model = load_model(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)
    tgt = frame[frame["machine"] == "pl1-0"].reset_index(drop=True)
    tgt = tgt[judged_rows(tgt)].reset_index(drop=True)
    groups = model_groups(model)[1]
    ok = finite_groups(tgt, (*groups, PI1_LINKAGE))
    tgt = tgt[ok].reset_index(drop=True)
    source = src.iloc[match_rows(src, tgt)].reset_index(drop=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)  # a tiny model: many rows are risky
        out = served.scale_force(source, tgt.drop(columns=["F21"]))
    pairs = DeltaDataset.from_matched(source, tgt, PI1_LINKAGE, groups)
    assert len(pairs) == len(tgt)
    np.testing.assert_allclose(out.delta1, model.predict(pairs), rtol=1e-5)
    np.testing.assert_allclose(out.force, pairs.recover(model.predict(pairs)), rtol=1e-5)
    assert np.all(out.lower <= out.force) and np.all(out.force <= out.upper)
    # the served risk: the card's interval risk on the novelty of the model's own features, |ln δ1| and the
    # at-rest rows, each computed here from the judge's side (the pairs, and the target rows they came from)
    card = zoo.card(path)
    assert "interval" not in card["risk"]["score"]  # stored once, as the card's learned_scale
    risk = RowRisk.from_state(card["risk"], load_file(str(path / card["risk"]["file"]))["novelty_rows"],
                              RowInterval.from_state(card["interval"]["learned_scale"]))
    static = row_kinds(pairs, tgt) == "static"
    _check_served_risk(out, risk, model.features(pairs), model.predict_log(pairs), static)
    # the served interval: ln δ1 ± q·s(x) on the same features, F21 = F21_linkage·π1(source)/δ1
    assert out.interval_method == card["interval"]["method"] == "learned-scale"
    half = RowInterval.from_state(card["interval"]["learned_scale"]).half_width(
        RowRisk.features(risk.novelty, model.features(pairs), model.predict_log(pairs), static), 0.9)
    np.testing.assert_allclose(out.lower, pairs.recover(model.predict(pairs) * np.exp(half)), rtol=1e-5)
    np.testing.assert_allclose(out.upper, pairs.recover(model.predict(pairs) * np.exp(-half)), rtol=1e-5)
    with pytest.raises(ValueError, match="F21_linkage"):
        served.scale_force(source, tgt.drop(columns=["F21_linkage"]))
    assert "tilt_load" not in served.target_variables  # nothing served reads it


@pytest.mark.slow
def test_rebuild_is_deterministic(built: tuple[Path, Path, ProductLineBuild], tmp_path: Path) -> None:
    """Same data and seed: the same weights (the weights file's hash on the card)."""
    path, _, cfg = built
    registry = tmp_path / "registry.json"
    registry.write_text(json.dumps({"format_version": 1, "checkpoints": {}}))
    again = build_product_line(replace(cfg, out_root=tmp_path / "checkpoints", registry=registry))
    first, second = zoo.card(path)["files"], zoo.card(again)["files"]
    assert first["weights.safetensors"] == second["weights.safetensors"]
    assert pd.read_csv(path / "check.csv").equals(pd.read_csv(again / "check.csv"))


def test_risk_can_be_skipped_for_throughput(built: tuple[Path, Path, ProductLineBuild]) -> None:
    """``risk=False``: the same forces, no risk, no warning (the error score's warnings replace the training-range
    rule for such checkpoints, so none fires), and the pooled residual interval instead of the learned one."""
    path, _, cfg = built
    served = zoo.load(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)
    tgt = frame[frame["machine"] == "mini"].reset_index(drop=True)
    tgt = tgt[judged_rows(tgt)].reset_index(drop=True)
    groups = model_groups(served.model)[1]
    ok = finite_groups(tgt, (*groups, PI1_LINKAGE))
    tgt = tgt[ok].reset_index(drop=True)
    source = src.iloc[match_rows(src, tgt)].reset_index(drop=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        full = served.scale_force(source, tgt)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fast = served.scale_force(source, tgt, risk=False)
    assert fast.risk is None and (full.risk is not None) == (served.risk_unavailable is None)
    np.testing.assert_array_equal(fast.force, full.force)
    assert (fast.interval_method, full.interval_method) == ("residual-quantiles", "learned-scale")
    q_lo, q_hi = zoo.card(path)["interval"]["log_delta_residual_quantiles"]["0.9"]
    np.testing.assert_allclose(fast.upper, fast.force * np.exp(-q_lo), rtol=1e-6)  # F21 falls as δ1 rises
    np.testing.assert_allclose(fast.lower, fast.force * np.exp(-q_hi), rtol=1e-6)


def test_predict_command_pairs_rows_for_a_product_line_model(built: tuple[Path, Path, ProductLineBuild],
                                                             tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``scaletwin predict`` with a whole source recording: every target row is paired with its matched source
    row (as ``match_rows`` pairs them), the output equals the served model's on those pairs and carries the risk;
    a target without the pose is refused, naming what is missing."""
    from scaletwin.cli import main

    path, _, cfg = built
    served = zoo.load(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    groups = model_groups(served.model)[1]
    keep = ["kind", *dict.fromkeys([*served.source_variables, "boom_angle", "bucket_pitch", "fill"])]
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)[keep]
    tgt = frame[frame["machine"] == "pl1-0"].reset_index(drop=True)
    tgt = tgt[judged_rows(tgt)].reset_index(drop=True)
    ok = finite_groups(tgt, (*groups, PI1_LINKAGE))
    tgt = tgt[ok].reset_index(drop=True)[["kind", *dict.fromkeys([*served.target_variables, *keep[-3:]])]]
    src.to_csv(tmp_path / "src.csv", index=False)
    tgt.to_csv(tmp_path / "tgt.csv", index=False)
    assert main(["predict", "--model", str(path), "--source", str(tmp_path / "src.csv"), "--target",
                 str(tmp_path / "tgt.csv"), "--out", str(tmp_path / "out.csv")]) == 0
    out = pd.read_csv(tmp_path / "out.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        expected = served.scale_force(src.iloc[match_rows(src, tgt)].reset_index(drop=True), tgt)
    np.testing.assert_allclose(out["F21 [N]"], expected.force, rtol=1e-9)
    _check_risk_column(out, expected.risk)
    assert "paired with its nearest" in capsys.readouterr().err
    tgt.drop(columns=["bucket_pitch"]).to_csv(tmp_path / "bad.csv", index=False)
    capsys.readouterr()
    assert main(["predict", "--model", str(path), "--source", str(tmp_path / "src.csv"), "--target",
                 str(tmp_path / "bad.csv")]) != 0
    assert "bucket_pitch" in capsys.readouterr().err


def test_predict_command_computes_the_design_signals_from_the_designs_named(
        built: tuple[Path, Path, ProductLineBuild], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A logger's files without design signals, in other units (deg, kN, mm, t): ``--target-design`` (the
    machine's LoaderSpec JSON, or `scaletwin product-line`'s machines.json#NAME) and ``--source-design`` (a preset)
    give the same forces and risks as files that carry the signals computed in Python; a design that cannot be
    read, a missing input and a count of designs that does not match the sources are one-line errors."""
    from scaletwin.cli import main
    from scaletwin_envs.signal_units import DESIGN_SIGNAL_UNITS

    path, _, cfg = built
    served = zoo.load(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    specs = cfg.layout.split().specs
    groups = model_groups(served.model)[1]
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)
    tgt = _judged_target(frame, "pl1-0", groups)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        expected = served.scale_force(src.iloc[match_rows(src, tgt)].reset_index(drop=True), tgt)

    def logger_file(rows: pd.DataFrame, name: str) -> Path:
        """What a data logger writes: the recorded signals only, several not in SI."""
        out = rows.drop(columns=[c for c in rows.columns if c in DESIGN_SIGNAL_UNITS or c == "machine"])
        out = out.rename(columns={"boom_angle": "boom_angle [deg]", "Pf_tilt": "Pf_tilt [kN]",
                                  "tilt_extension": "tilt_extension [mm]", "m_load": "m_load [t]"})
        out["boom_angle [deg]"] = np.degrees(out["boom_angle [deg]"])
        out["Pf_tilt [kN]"] /= 1e3
        out["tilt_extension [mm]"] *= 1e3
        out["m_load [t]"] /= 1e3
        out.to_csv(file := tmp_path / name, index=False)
        return file

    src_file, tgt_file = logger_file(src, "src.csv"), logger_file(tgt, "tgt.csv")
    (tmp_path / "pl1-0.json").write_text(specs["pl1-0"].to_json())
    machines = {"machines": [{"name": "pl1-0", "spec": specs["pl1-0"].to_dict()}]}
    (tmp_path / "machines.json").write_text(json.dumps(machines))
    for design in (str(tmp_path / "pl1-0.json"), f"{tmp_path / 'machines.json'}#pl1-0"):
        assert main(["predict", "--model", str(path), "--source", str(src_file), "--source-design", "er12",
                     "--target", str(tgt_file), "--target-design", design, "--out", str(tmp_path / "out.csv")]) == 0
        out = pd.read_csv(tmp_path / "out.csv")
        np.testing.assert_allclose(out["F21 [N]"], expected.force, rtol=1e-9)
        _check_risk_column(out, expected.risk)
        assert expected.stroke_end is not None  # the tilt stroke, computed from the logged extension
        np.testing.assert_array_equal(out["stroke_end"], expected.stroke_end)
    capsys.readouterr()
    bad = [(["--target-design", "excavator"], "not a preset"),
           (["--target-design", f"{tmp_path / 'machines.json'}#pl9-9"], "pl1-0"),
           (["--target-design", str(tmp_path / "src.csv.json")], "cannot read"),
           (["--target-design", "er12", "--source-design", "er12", "--source-design", "er12"], "once per --source")]
    for extra, message in bad:
        assert main(["predict", "--model", str(path), "--source", str(src_file), "--target", str(tgt_file),
                     *extra]) == 2
        assert message in capsys.readouterr().err
    pd.read_csv(tgt_file).drop(columns=["m_load [t]"]).to_csv(tmp_path / "no_load.csv", index=False)
    assert main(["predict", "--model", str(path), "--source", str(src_file), "--source-design", "er12",
                 "--target", str(tmp_path / "no_load.csv"), "--target-design", "er12"]) == 2
    err = capsys.readouterr().err
    assert "no_load.csv" in err and "m_load" in err


def _check_served_risk(out: zoo.ScaledForce, risk: RowRisk, g: np.ndarray, log_delta: np.ndarray,
                       static: np.ndarray) -> None:
    """``out.risk`` is the card's risk on the judge's features, or None where the card has no risk."""
    if risk.score is None:
        assert out.risk is None and out.warned is None
        return
    assert out.risk is not None and np.all((out.risk >= 0) & (out.risk <= 1))
    np.testing.assert_allclose(out.risk, risk.risk(g, log_delta, static), rtol=1e-6, atol=1e-9)


def _check_risk_column(table: pd.DataFrame, risk: np.ndarray | None) -> None:
    if risk is None:
        assert "risk [1]" not in table.columns
    else:
        np.testing.assert_allclose(table["risk [1]"], risk, rtol=1e-9)


def _judged_target(frame: pd.DataFrame, machine: str, groups: tuple) -> pd.DataFrame:
    tgt = frame[frame["machine"] == machine].reset_index(drop=True)
    tgt = tgt[judged_rows(tgt)].reset_index(drop=True)
    return tgt[finite_groups(tgt, (*groups, PI1_LINKAGE))].reset_index(drop=True)


def _matched_sources(frame: pd.DataFrame, split: Split, machine: str, tgt: pd.DataFrame
                     ) -> tuple[list[str], list[pd.DataFrame]]:
    """The three calibration machines nearest ``machine`` and, from each, the rows matched to ``tgt``."""
    names = nearest_machines(split.specs[machine], {m: split.specs[m] for m in split.train}, 3)
    sources = []
    for name in names:
        rows = frame[frame["machine"] == name].reset_index(drop=True)
        sources.append(rows.iloc[match_rows(rows, tgt)].reset_index(drop=True))
    return names, sources


def test_three_sources_serve_the_judged_prediction_and_coverage(built: tuple[Path, Path, ProductLineBuild]) -> None:
    """From the three training machines nearest in design, ``scale_force_sources`` gives the geometric mean of the
    three single-source forces, and on the held-out machine its interval covers exactly the share of rows the
    card's leave-machine-out judge measured for three sources (two routes to one number: the judge in
    ``scaling.evaluation.generalisation``, the served path in ``zoo.serving``)."""
    path, _, cfg = built
    served = zoo.load(path)
    card = zoo.card(path)
    assert served.calibrated_sources == card["interval"]["multi_source"]["sources"] == cfg.sources == 3
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    split = cfg.layout.split()
    groups = model_groups(served.model)[1]
    for machine in split.test:
        tgt = _judged_target(frame, machine, groups)
        names, sources = _matched_sources(frame, split, machine, tgt)
        assert card["metrics"]["multi_source"]["held_out_machines"][machine]["source"] == "+".join(names)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
            out = served.scale_force_sources(sources, tgt.drop(columns=["F21"]))
            singles = [served.scale_force(s, tgt, risk=False).force for s in sources]
        np.testing.assert_allclose(out.force, np.exp(np.mean(np.log(singles), axis=0)), rtol=1e-9)
        assert out.interval_method == "learned-scale, 3 sources"
        assert np.all(out.lower <= out.force) and np.all(out.force <= out.upper)
        if served.sources_risk_unavailable() is None:
            assert out.risk is not None and np.all((out.risk >= 0) & (out.risk <= 1))
        else:
            assert out.risk is None
        f21 = tgt["F21"].to_numpy(float)
        covered = float(np.mean((out.lower <= f21) & (f21 <= out.upper)))
        judged = card["metrics"]["multi_source"]["held_out_machines"][machine]["interval_coverage"]
        assert covered == pytest.approx(judged, abs=1e-9), machine
    with pytest.raises(zoo.InputError, match="calibrated for 3 sources"):
        served.scale_force_sources(sources[:2], tgt)


def test_predict_command_takes_one_source_per_calibrated_machine(built: tuple[Path, Path, ProductLineBuild],
                                                                tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``--source`` three times: every file paired row by row with the target, the answer of
    ``scale_force_sources``; twice is refused, saying how many the model is calibrated for."""
    from scaletwin.cli import main

    path, _, cfg = built
    served = zoo.load(path)
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    groups = model_groups(served.model)[1]
    keep = ["kind", *dict.fromkeys([*served.source_variables, "boom_angle", "bucket_pitch", "fill"])]
    tgt = _judged_target(frame, "mini", groups)[["kind", *dict.fromkeys([*served.target_variables, *keep[-3:]])]]
    tgt.to_csv(tmp_path / "tgt.csv", index=False)
    files, matched = [], []
    for name in cfg.layout.split().train[:3]:
        src = frame[frame["machine"] == name].reset_index(drop=True)[keep]
        src.to_csv(file := tmp_path / f"{name}.csv", index=False)
        files += ["--source", str(file)]
        matched.append(src.iloc[match_rows(src, tgt)].reset_index(drop=True))
    assert main(["predict", "--model", str(path), *files, "--target", str(tmp_path / "tgt.csv"), "--out",
                 str(tmp_path / "out.csv")]) == 0
    out = pd.read_csv(tmp_path / "out.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        expected = served.scale_force_sources(matched, tgt)
    np.testing.assert_allclose(out["F21 [N]"], expected.force, rtol=1e-9)
    np.testing.assert_allclose(out["F21_upper [N]"], expected.upper, rtol=1e-9)
    capsys.readouterr()
    assert main(["predict", "--model", str(path), *files[:4], "--target", str(tmp_path / "tgt.csv")]) == 2
    assert "calibrated for 3 source(s), not 2" in capsys.readouterr().err


def _resaved(path: Path, out: Path, score: IntervalRisk | None, reason: str | None) -> Path:
    """The checkpoint at ``path`` saved again at ``out`` with the risk ``score`` (one source and three), or, with
    ``score`` None, as a card without a risk: the novelty kept (the learned interval reads it), no score,
    ``reason`` on the card and in its metrics, the risk figures null."""
    card = zoo.card(path)
    served = zoo.load(path)
    assert served.risk is not None
    skip = ("files", "risk", "format_version", "kind", "versions", "created", "model")
    fields = {k: v for k, v in card.items() if k not in skip}
    multi = card["interval"]["multi_source"]
    fields["interval"] = {**card["interval"], "multi_source": {
        **multi, "risk": None if score is None else score.state(), "risk_unavailable": reason}}
    if score is None:
        metrics = card["metrics"]
        fields["metrics"] = {**metrics, "risk_unavailable": reason,
                             "summary": {**metrics["summary"], "risk_unavailable": reason, "risk_auroc": None,
                                         "risk_warned_share_median": None, "risk_false_alarms_median": None},
                             "held_out_machines": {m: {**v, "risk_warned_share": None, "risk_false_alarms": None}
                                                   for m, v in metrics["held_out_machines"].items()}}
    return save_scaling_model(load_model(path), out, fields, risk=RowRisk(served.risk.novelty, score, reason))


def test_a_checkpoint_with_an_error_score_serves_it(built: tuple[Path, Path, ProductLineBuild],
                                                     tmp_path: Path) -> None:
    """The served risk is the card's interval risk on the served features (computed here from the judge's side:
    the pairs and the target rows they came from), the rows at its warning probability or above are the warned
    ones and a warning counts them; from three sources a risk is served too. The miss line is set low here
    (0.1 % of F21), so that rows are warned on whatever the tiny line's errors."""
    path, _, cfg = built
    served = zoo.load(path)
    assert served.risk is not None and served.risk.score is not None
    score = IntervalRisk(served.risk.score.interval, 0.001, math.log1p(0.001))
    scored_path = _resaved(path, tmp_path / "scored", score, None)
    scored, model = zoo.load(scored_path), load_model(scored_path)
    assert scored.risk_unavailable is None and scored.sources_risk_unavailable() is None
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    groups = model_groups(model)[1]
    tgt = _judged_target(frame, "pl1-0", groups)
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)
    source = src.iloc[match_rows(src, tgt)].reset_index(drop=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", zoo.ExtrapolationWarning)
        out = scored.scale_force(source, tgt.drop(columns=["F21"]))
    pairs = DeltaDataset.from_matched(source, tgt, PI1_LINKAGE, groups)
    static = row_kinds(pairs, tgt) == "static"
    assert scored.risk is not None and scored.risk.score is not None
    _check_served_risk(out, scored.risk, model.features(pairs), model.predict_log(pairs), static)
    assert out.risk is not None and out.warned is not None
    np.testing.assert_array_equal(out.warned, score.above(out.risk))
    assert out.warned.any()
    assert any(f"{int(out.warned.sum())} of {len(tgt)} target rows are likely" in str(w.message)
               for w in caught) == bool(out.warned.any())
    _, sources = _matched_sources(frame, cfg.layout.split(), "pl1-0", tgt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        out3 = scored.scale_force_sources(sources, tgt)
    assert out3.risk is not None and np.all((out3.risk >= 0) & (out3.risk <= 1))


def test_a_checkpoint_without_an_error_score_serves_and_says_so(built: tuple[Path, Path, ProductLineBuild],
                                                                 tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A card without a risk (a build that could calibrate none) says why (``metrics.risk_unavailable``, the risk
    figures null), the checkpoint still loads and serves the same
    forces and learned intervals, from one source and from three, with ``out.risk`` None and the reason in
    ``ScalingModel.risk_unavailable``, and ``scaletwin predict`` says on stderr that no risk column is served. The
    risk is removed from the tiny line's checkpoint here."""
    from scaletwin.cli import main

    path, _, cfg = built
    reason = "calibration rows are all on one side of the 10% miss line: nothing to learn an error score from"
    bare_path = _resaved(path, tmp_path / "bare", None, reason)
    bare, served = zoo.load(bare_path), zoo.load(path)
    assert bare.risk is not None and bare.risk.score is None
    assert bare.risk_unavailable == reason and bare.sources_risk_unavailable() == reason
    assert zoo.card(bare_path)["metrics"]["summary"]["risk_unavailable"] == reason
    frame = cfg.layout.load(cfg.data_dir, executor="serial", progress=False)
    groups = model_groups(served.model)[1]
    tgt = _judged_target(frame, "pl1-0", groups)
    src = frame[frame["machine"] == "er12"].reset_index(drop=True)
    source = src.iloc[match_rows(src, tgt)].reset_index(drop=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        out, ref = bare.scale_force(source, tgt.drop(columns=["F21"])), served.scale_force(source, tgt)
    assert out.risk is None and out.warned is None and "risk [1]" not in out.to_frame()
    assert out.interval_method == ref.interval_method == "learned-scale"
    for a, b in ((out.force, ref.force), (out.lower, ref.lower), (out.upper, ref.upper)):
        np.testing.assert_array_equal(a, b)
    names = nearest_machines(cfg.layout.split().specs["pl1-0"], {m: cfg.layout.split().specs[m]
                                                                  for m in cfg.layout.split().train}, 3)
    sources = []
    for name in names:
        rows = frame[frame["machine"] == name].reset_index(drop=True)
        sources.append(rows.iloc[match_rows(rows, tgt)].reset_index(drop=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        out3, ref3 = bare.scale_force_sources(sources, tgt), served.scale_force_sources(sources, tgt)
    assert out3.risk is None and out3.interval_method == ref3.interval_method
    np.testing.assert_array_equal(out3.upper, ref3.upper)
    keep = ["kind", *dict.fromkeys([*bare.source_variables, "boom_angle", "bucket_pitch", "fill"])]
    src[keep].to_csv(tmp_path / "src.csv", index=False)
    tgt[["kind", *dict.fromkeys([*bare.target_variables, *keep[-3:]])]].to_csv(tmp_path / "tgt.csv", index=False)
    capsys.readouterr()
    assert main(["predict", "--model", str(bare_path), "--source", str(tmp_path / "src.csv"), "--target",
                 str(tmp_path / "tgt.csv"), "--out", str(tmp_path / "out.csv")]) == 0
    assert f"serves no risk score (no risk [1] column): {reason}" in capsys.readouterr().err
    table = pd.read_csv(tmp_path / "out.csv")
    assert "risk [1]" not in table.columns
    np.testing.assert_allclose(table["F21 [N]"], ref.force, rtol=1e-9)
