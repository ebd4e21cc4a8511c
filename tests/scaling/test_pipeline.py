"""The training pipeline end to end on a tiny simulated data set, and its building blocks."""

from __future__ import annotations

import json
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scaling.data.recordings import DataBundle
from scaling.dimensions.group_choice import AT_REST, EQ10, PI1, POSE, admissible_sets, choose_groups, orient_at_rest
from scaling.dimensions.groups import PiGroup
from scaling.evaluation import metrics as ev
from scaling.evaluation.miniature import static_rows
from scaling.runs.pipeline import PipelineConfig, ScalingPipeline, model_specs
from scaling.runs.run_io import load_run, read_metrics, save_run

FAST = {"FFNN": {"epochs": 40, "patience": 10}, "GRUModel": {"epochs": 5, "window": 32, "stride": 16},
        "DeepEnsemble": {"epochs": 20, "k": 2, "patience": 10}}


def fast_config(names: list[str] | None = None) -> PipelineConfig:
    models = tuple(replace(s, config={**s.config, **FAST.get(s.cls, {})}) for s in model_specs(names))
    return PipelineConfig(models=models, n_shuffles=2)


@pytest.fixture(scope="module")
def run(tiny_frame: pd.DataFrame, tmp_path_factory: pytest.TempPathFactory):
    held = tiny_frame[tiny_frame["machine"] == "wa475"].assign(machine="wa475-copy")
    out = tmp_path_factory.mktemp("run")
    result = ScalingPipeline(fast_config()).run(DataBundle(tiny_frame, held), progress=False)
    save_run(result, out)
    return result, out


def test_orient_at_rest_puts_motion_variables_in_numerators() -> None:
    g = PiGroup({"F31": Fraction(1), "a1": Fraction(-1), "m_b": Fraction(-1)})
    assert orient_at_rest(g, ("a1", "alpha1")).expression() == "a1*m_b/F31"
    assert orient_at_rest(PiGroup({"a1": 1, "alpha1": -1, "x_b": -1}), ("a1", "alpha1")) is None
    assert orient_at_rest(PiGroup({"x_b": 1, "y_b": -1}), ("a1", "alpha1")).expression() == "x_b/y_b"


def test_admissible_sets_are_complete_and_vanish_or_stay_finite_at_rest() -> None:
    sets = admissible_sets(EQ10, AT_REST["eq10"])
    assert sets
    rest = static_rows()
    for s in sets:
        s.validate()
        assert s.groups[0] == PI1 and len(s.groups) == 6  # 9 variables - rank 3
        values = np.column_stack([g.evaluate(rest) for g in s.groups[1:]])
        assert np.all(np.isfinite(values))


def test_choose_groups_orients_sign_changing_forces_upstairs(tiny_frame: pd.DataFrame) -> None:
    choice = choose_groups(tiny_frame, "eq10", n_shuffles=2)
    exprs = [g.expression() for g in choice.inputs]
    assert choice.output.expression() == "F21/F31"
    assert "Pf_tilt/F31" in exprs or not any("Pf_tilt" in e for e in exprs)
    assert len(choice.ranking) >= 1 and choice.ranking["rank"].iloc[0] == 1
    assert choose_groups(tiny_frame, "eq23", n_shuffles=2).output == PI1
    posed = choose_groups(tiny_frame, "eq10+pose", n_shuffles=2)
    assert posed.inputs[:-2] == choice.inputs and [g.expression() for g in posed.inputs[-2:]] == list(POSE)
    with pytest.raises(ValueError, match="unknown variable list"):
        choose_groups(tiny_frame, "eq11")


def test_split_reference_and_domain(tiny_frame: pd.DataFrame) -> None:
    test = ev.split_episodes(tiny_frame, 0.3, seed=0)
    assert test == ev.split_episodes(tiny_frame, 0.3, seed=0)
    for machine in ("er12", "wa475"):
        keys = {k for k in test if k.startswith(machine + "/")}
        assert 0 < len(keys) < tiny_frame.loc[tiny_frame["machine"] == machine, "episode"].nunique()
    ref = ev.pick_reference(tiny_frame, "er12", "static", seed=0)
    row = tiny_frame.loc[[ref]]
    assert row["machine"].iloc[0] == "er12" and ev.at_rest(row)[0] and ev.in_domain(row)[0]
    assert ev.in_domain(pd.DataFrame({"F21": [0.05, 1.0], "F31": [1.0, 1.0]})).tolist() == [False, True]
    assert ev.after_settling(tiny_frame, 10).sum() == len(tiny_frame) - 10 * tiny_frame["episode"].nunique()


def test_end_to_end_run_writes_a_complete_model_directory(run) -> None:
    result, out = run
    assert set(result.models) == {"ffnn", "ffnn-pose", "gru-eq10", "gru-eq23", "power-law", "direct-pi",
                                  "deep-ensemble"}
    assert result.models["ffnn-pose"].groups_ is not None
    assert [g["expression"] for g in result.models["ffnn-pose"].groups_["inputs"]][-2:] == ["boom_angle",
                                                                                           "bucket_pitch"]
    for name in result.models:
        mdir = out / "models" / name
        for f in ("config.json", "weights.safetensors", "metrics.json", "provenance.json", "fit.rrd"):
            assert (mdir / f).is_file(), (name, f)
        prov = json.loads((mdir / "provenance.json").read_text())
        assert prov["code_version"] and prov["seed"] == 0 and prov["data_hashes"]["train"]
        assert prov["params"]["config"]
        assert prov["machine"]["simd"] in {"avx512f", "avx2", "avx", "sse4_2", "unknown"}
        assert prov["machine"]["cpu_model"]  # reproduction bit for bit needs the same kind of CPU
    metrics = read_metrics(out)
    assert set(metrics["models"]) == set(result.models)
    assert "r2_dig" in metrics["models"]["ffnn"] and np.isfinite(metrics["models"]["ffnn"]["r2"])
    assert set(metrics["held_out_machines"]["deep-ensemble"]["wa475-copy"]) >= {"f21_mape_pct", "coverage_90"}
    # The ER12 and the WA475 are two designs, and this data set is tiny (3 dig cycles, 2 holds each) with fits cut
    # to a few epochs: the models learn their distortion only in part. Since v1's servo stopped relaying at relief
    # during holds, δ1 ≡ 1 (direct-Pi) errs 17.5 % on F21 here (31.9 % before), and only the pose model beats it
    # there (9.8 %; the others 20-25 %). What must hold: the best fitted model beats it on F21, and the fitted models
    # as a whole on ln δ1 (median R²; one GRU of 5 epochs may lose).
    direct = metrics["models"]["direct-pi"]
    fitted = {name: m for name, m in metrics["models"].items() if name != "direct-pi"}
    assert min(m["f21_mape_pct"] for m in fitted.values()) < direct["f21_mape_pct"]
    assert np.median([m["r2_log"] for m in fitted.values()]) > direct["r2_log"]
    mini = json.loads((out / "mini.json").read_text())
    assert "direct-pi" in mini["models"] and len(mini["loads_kg"]) == 8
    assert (out / "groups" / "eq10.json").is_file() and (out / "provenance.json").is_file()


def test_run_directory_round_trip_and_determinism(run, tiny_frame: pd.DataFrame) -> None:
    result, out = run
    models, reference = load_run(out)
    assert reference.name == result.reference.name
    test = result.test_sets["eq10"]
    for name in ("ffnn", "power-law", "deep-ensemble"):
        np.testing.assert_allclose(models[name].predict(test), result.models[name].predict(test), rtol=1e-6)
    again = ScalingPipeline(fast_config(["ffnn", "direct-pi"])).run(DataBundle(tiny_frame), progress=False)
    np.testing.assert_array_equal(again.models["ffnn"].predict(test), result.models["ffnn"].predict(test))
    assert again.mini.mean_abs("ffnn") == result.mini.mean_abs("ffnn")


def test_load_run_rejects_other_directories(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        load_run(tmp_path)
