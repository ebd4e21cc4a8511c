"""The miniature validation (paper section 4): analytical static rows, the env at rest, predictions and JSON."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from scaletwin_envs.specs import make_loader
from scaling.data.delta_dataset import DeltaDataset
from scaling.dimensions.group_choice import EQ10, PI1
from scaling.dimensions.groups import PiGroup
from scaling.evaluation.miniature import CARRY_POSE, LOADS, MiniValidation, env_at_rest, static_rows, validate_mini
from scaling.models import DirectPi, PowerLaw

SIGNALS = ("F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b")
INPUTS = (PiGroup({"a1": 1, "m_b": 1, "F31": -1}), PiGroup({"Pf_tilt": 1, "F31": -1}),
          PiGroup({"Pf_lift": 1, "F31": -1}), PiGroup({"alpha1": 1, "m_b": 1, "x_b": 1, "F31": -1}))


@pytest.fixture(scope="module")
def rows() -> pd.DataFrame:
    return static_rows()


def test_static_rows_cover_the_papers_loads_at_rest(rows: pd.DataFrame) -> None:
    np.testing.assert_allclose(rows["load_kg"], np.linspace(0.5, 4.0, 8))
    assert LOADS[0] == 0.5 and LOADS[-1] == 4.0
    assert (rows[["a1", "alpha1", "V1", "w1"]] == 0).all().all()
    mini = make_loader("mini")
    np.testing.assert_allclose(rows["m_b"], mini.masses.bucket + rows["load_kg"])
    assert set(EQ10) <= set(rows.columns)
    assert np.all(np.diff(rows["F21"]) > 0) and np.all(np.isfinite(rows[list(SIGNALS)].to_numpy()))
    np.testing.assert_allclose(rows["bucket_pitch"], CARRY_POSE["pitch"])
    # statics is linear in the load when the load's centre of mass is fixed; here it moves with the fill,
    # so only check the order of magnitude: F21 of a few times the weight of the load
    ratio = rows["F21"] / (rows["load_kg"] * 9.81)
    assert np.all((ratio > 0.5) & (ratio < 3.0))


@pytest.mark.parametrize("index", [0, 3, 7])
def test_validation_rows_equal_the_env_at_rest_within_1_percent(rows: pd.DataFrame, index: int) -> None:
    """Analytical statics (no MuJoCo) against the simulator's MuJoCo model settled at the same pose and load."""
    sim = env_at_rest("mini", float(rows.loc[index, "load_kg"]))
    assert sim["a1"] < 1e-4 and sim["alpha1"] < 1e-3  # really at rest
    for name in SIGNALS:
        assert sim[name] == pytest.approx(rows.loc[index, name], rel=0.01), name


def test_log_distortion_features_stay_finite_at_rest(rows: pd.DataFrame, tiny_frame: pd.DataFrame) -> None:
    reference = tiny_frame[tiny_frame["machine"] == "er12"].iloc[20]
    pairs = DeltaDataset.from_pairs(reference, rows, PI1, INPUTS)
    assert len(pairs) == len(rows)
    model = PowerLaw(rel_eps=0.1).fit(DeltaDataset.from_recordings(tiny_frame[tiny_frame["F21"] > 0.1 * tiny_frame[
        "F31"]], PI1, INPUTS, reference_index=[reference.name], warn=False))
    x = model.features(pairs)
    assert np.all(np.isfinite(x))
    assert np.all(np.isfinite(model.predict_target(pairs)))


def test_direct_pi_is_exact_when_the_reference_is_the_target_state(rows: pd.DataFrame) -> None:
    """δ1 ≡ 1 is exact when source and target rows are similar (same π1): the reference is a miniature row."""
    reference = rows.iloc[3]
    pairs = DeltaDataset.from_pairs(reference, rows.iloc[[3]], PI1, INPUTS)
    model = DirectPi().fit(pairs)
    result = validate_mini({"direct-pi": model}, reference, rows)
    assert result.pct_error("direct-pi")[3] == pytest.approx(0.0, abs=1e-9)
    # the direct-Pi error at other loads is the change of π1 with the load, and no more
    pi1 = rows["F21"] / rows["F31"]
    np.testing.assert_allclose(result.pct_error("direct-pi"), 100 * (pi1.iloc[3] / pi1 - 1), rtol=1e-9)


def test_json_has_exactly_the_documented_schema(rows: pd.DataFrame) -> None:
    result = MiniValidation(rows["load_kg"].to_numpy(), rows["F21"].to_numpy(),
                            {"ffnn": rows["F21"].to_numpy() * 1.02, "direct-pi": rows["F21"].to_numpy() * 0.6})
    payload = json.loads(json.dumps(result.to_json()))
    assert set(payload) == {"loads_kg", "models"}
    assert payload["loads_kg"] == pytest.approx(list(LOADS))
    assert set(payload["models"]) == {"ffnn", "direct-pi"}
    for entry in payload["models"].values():
        assert set(entry) == {"mean_abs_pct_error", "pct_error"}
        assert len(entry["pct_error"]) == len(LOADS)
        assert entry["mean_abs_pct_error"] == pytest.approx(np.mean(np.abs(entry["pct_error"])))
    assert payload["models"]["ffnn"]["mean_abs_pct_error"] == pytest.approx(2.0)
    assert payload["models"]["direct-pi"]["pct_error"][0] == pytest.approx(-40.0)
    assert result.reduction("ffnn") == pytest.approx(0.95)
