"""δ1 models: oracles on synthetic power laws, determinism, safe persistence, ensemble coverage, GRU memory."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from scaling.data.delta_dataset import DeltaDataset
from scaling.models import (
    FFNN,
    DeepEnsemble,
    DeltaModel,
    DirectPi,
    GRUModel,
    PowerLaw,
    load_model,
    r2_score,
)
from tests.scaling.test_factors import (
    EXPONENTS,
    INPUTS,
    PI1,
    STATIC_EXPONENTS,
    similar_copy,
    synthetic_recordings,
    true_delta,
)

torch.set_num_threads(1)
FAST = {"epochs": 150, "threads": 1}


@pytest.fixture(scope="module")
def split() -> tuple[DeltaDataset, DeltaDataset]:
    rec = synthetic_recordings(episodes=(10, 10), steps=50, seed=11)
    return DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=0).split_by_episode(0.25, seed=0)


def test_direct_pi_predicts_unit_delta(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    train, test = split
    model = DirectPi().fit(train)
    np.testing.assert_array_equal(model.predict(test), 1.0)
    assert "δ1 ≡ 1" in model.describe()


def test_power_law_recovers_exponents_exactly(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    train, test = split
    model = PowerLaw(rel_eps=1e-9).fit(train)
    np.testing.assert_allclose(list(model.exponents().values()), list(EXPONENTS.values()), atol=1e-6)
    assert abs(model.intercept_) < 1e-6  # C cancels in δ1
    np.testing.assert_allclose(model.predict(test), true_delta(test, EXPONENTS), rtol=1e-6)
    assert model.score(test) > 0.999999
    assert "d[Pf_tilt/F31]^+0.5" in model.describe()


def test_power_law_does_not_extrapolate_beyond_its_training_features(
        split: tuple[DeltaDataset, DeltaDataset], tmp_path) -> None:
    """Inside the training range widened by half its span the law is exact; a feature far outside (a group
    crossing zero) is clipped to that edge, so the prediction equals the one at the edge instead of growing like
    e^(a·g); the range is saved with the model."""
    train, test = split
    model = PowerLaw(rel_eps=1e-9).fit(train)
    x = model.features(test)
    lo, hi = model.features(train).min(axis=0), model.features(train).max(axis=0)
    lo, hi = lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo)
    inside = np.all((x >= lo) & (x <= hi), axis=1)
    np.testing.assert_allclose(model.predict(x[inside]), true_delta(test, EXPONENTS)[inside], rtol=1e-6)
    far = np.tile(x[:1], (2, 1))
    far[0, 0], far[1, 0] = hi[0] + 50.0, hi[0]
    assert model.predict(far[1:])[0] != model.predict(far[1:] - [[1.0, *np.zeros(far.shape[1] - 1)]])[0]
    pred = model.predict(far)
    assert pred[0] == pred[1] and np.isfinite(pred).all()
    from scaling.models import load_model

    again = load_model(model.save(tmp_path / "pl"))
    np.testing.assert_array_equal(again.predict(far), pred)


def test_unit_distortions_give_unit_delta_after_fitting(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    train, _ = split
    rec = synthetic_recordings(episodes=(1, 0), steps=10, seed=3)
    copies = pd.concat([similar_copy(rec.iloc[[4]], lam) for lam in (0.003, 0.5, 8.0)], ignore_index=True)
    similar = DeltaDataset.from_pairs(rec.iloc[4], copies, PI1, INPUTS)
    np.testing.assert_allclose(similar.delta, 1.0, rtol=1e-12)
    exact = PowerLaw(fit_intercept=False).fit(train)
    np.testing.assert_allclose(exact.predict(similar), 1.0, rtol=1e-12)
    np.testing.assert_allclose(PowerLaw().fit(train).predict(similar), 1.0, atol=1e-4)


def test_ffnn_approaches_the_power_law(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    train, test = split
    model = FFNN(**FAST).fit(train)
    assert model.score(test) >= 0.99
    rel = np.abs(model.predict(test) / true_delta(test, EXPONENTS) - 1)
    assert np.median(rel) < 0.02 and rel.max() < 0.15
    np.testing.assert_allclose(model.predict_target(test), test.target_values(), rtol=0.15)
    again = FFNN(**FAST).fit(train)
    np.testing.assert_array_equal(again.predict(test), model.predict(test))  # seeded
    assert "MLP 2×32" in model.describe()


def test_features_must_match_groups(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    train, _ = split
    with pytest.raises(RuntimeError, match="not fitted"):
        PowerLaw().predict(train)
    model = PowerLaw().fit(train)
    other = DeltaDataset.from_recordings(synthetic_recordings(episodes=(2, 1), steps=10), PI1, INPUTS[:3])
    with pytest.raises(ValueError, match="groups differ"):
        model.predict(other)
    np.testing.assert_allclose(model.predict(model.features(train)), model.predict(train))


def _forbid_pickle(monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*_: object, **__: object) -> None:
        raise AssertionError("pickle/torch.save/torch.load must not be used")

    for mod, names in ((pickle, ("dump", "dumps", "load", "loads")), (torch, ("save", "load"))):
        for name in names:
            monkeypatch.setattr(mod, name, boom)


@pytest.mark.parametrize("model", [
    DirectPi(),
    PowerLaw(ridge=1e-6),
    FFNN(hidden_layers=1, units=8, epochs=5, threads=1),
    GRUModel(hidden_size=8, epochs=3, window=12, threads=1),
    DeepEnsemble(k=2, hidden_layers=1, units=8, epochs=5, threads=1),
], ids=lambda m: m.name)
def test_save_load_round_trip_without_pickle(model: DeltaModel, split: tuple[DeltaDataset, DeltaDataset],
                                             tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    train, test = split
    model.fit(train)
    expected = model.predict(test)
    _forbid_pickle(monkeypatch)
    model.save(tmp_path / "m")
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["config.json", "weights.safetensors"]
    loaded = load_model(tmp_path / "m")
    assert type(loaded) is type(model) and loaded.get_config() == model.get_config()
    np.testing.assert_array_equal(loaded.predict(test), expected)
    assert loaded.name in loaded.describe()


def test_ensemble_intervals_cover_the_nominal_fraction() -> None:
    rec = synthetic_recordings(episodes=(12, 12), steps=50, seed=5, noise=0.05, exponents=STATIC_EXPONENTS)
    train, test = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=2).split_by_episode(0.3, seed=1)
    model = DeepEnsemble(k=3, hidden_layers=1, units=16, epochs=200, lr=1e-2, threads=1).fit(train)
    for coverage in (0.5, 0.9):
        lo, hi = model.predict_interval(test, coverage)
        assert np.all(lo < hi)
        hit = np.mean((test.delta >= lo) & (test.delta <= hi))
        assert abs(hit - coverage) < 0.08, (coverage, hit)
    f_lo, f_hi = model.predict_target_interval(test, 0.9)
    f21 = test.target_values()
    assert np.all(f_lo < f_hi) and abs(np.mean((f21 >= f_lo) & (f21 <= f_hi)) - 0.9) < 0.08
    mean, var = model.predict_log_dist(test)
    np.testing.assert_allclose(np.exp(mean), model.predict(test))
    assert np.all(var > 0) and model.score(test) > 0.8
    with pytest.raises(ValueError, match="coverage"):
        model.predict_interval(test, 1.0)


def test_gru_learns_time_memory_better_than_a_constant() -> None:
    rec = synthetic_recordings(episodes=(12, 12), steps=40, seed=9, memory=0.85, exponents=STATIC_EXPONENTS)
    train, test = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=1).split_by_episode(0.3, seed=2)
    gru = GRUModel(hidden_size=16, epochs=120, lr=1e-2, window=20, stride=10, burn_in=5, threads=1).fit(train)
    constant = r2_score(test.delta, np.full(len(test), train.delta.mean()))
    assert constant < 0.05
    assert gru.score(test) > 0.8, gru.describe()
    memoryless = FFNN(**FAST).fit(train).score(test)
    assert gru.score(test) > memoryless + 0.1
    x = gru.features(test)[test.sequences()[0]]
    np.testing.assert_allclose(gru.predict(x), gru.predict(test)[test.sequences()[0]], rtol=1e-5)
    assert gru.predict(np.stack([x, x])).shape == (2, len(x))
