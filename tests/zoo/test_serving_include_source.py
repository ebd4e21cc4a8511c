"""Serving δ1 models fitted with ``include_source=True``: the served features append the source's own
``s·asinh(π^s/2ε)`` (2k features), for one source row and for one matched source row per target row, on every path
(batch, row, stream; FFNN, deep ensemble, GRU), and the card's training range is 2k wide."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

import zoo
from scaling.data.delta_dataset import DeltaDataset, concat_datasets
from scaling.dimensions.factors import LogDistortion
from scaling.models import FFNN, DeepEnsemble, DeltaModel, GRUModel
from tests.scaling.test_factors import INPUTS, PI1, synthetic_recordings
from zoo.scaling_kind import check_rows
from zoo.serving.inputs import split_header
from zoo.serving.kernels import Features

torch.set_num_threads(1)
RTOL = 1e-6  # the served float32 nets against the model's own predict (same weights, same float32 arithmetic)
N_PAIRS = 25


@pytest.fixture(scope="module")
def recordings() -> pd.DataFrame:
    """Synthetic ER12 (source) and WA475 (target) dig cycles; F21 = F31·c·∏ π_n^{a_n}."""
    return synthetic_recordings(episodes=(4, 4), steps=30, seed=7)


@pytest.fixture(scope="module")
def train(recordings: pd.DataFrame) -> DeltaDataset:
    """Every row paired with matched ER12 source rows drawn at random (three draws), as for the product line:
    δ1 depends on the source as well as on g, and every ER12 row is a training source."""
    rng = np.random.default_rng(0)
    er12 = recordings[recordings["machine"] == "er12"]
    parts = [DeltaDataset.from_matched(er12.iloc[rng.permutation(np.resize(np.arange(len(er12)), len(recordings)))],
                                       recordings, PI1, INPUTS, reference_id=i) for i in range(3)]
    return concat_datasets(parts)


def _card(model: DeltaModel, train: DeltaDataset, reference: pd.Series, *,
          training_range: dict[str, Any] | None = None) -> dict[str, Any]:
    """A minimal valid scaling-model card (:data:`zoo.scaling_kind.CARD_KEYS`) for a synthetic model."""
    assert model.groups_ is not None
    g = model.features(train)
    interval = ({"method": "ensemble", "coverage": 0.9} if isinstance(model, DeepEnsemble) else
                {"method": "residual-quantiles", "coverage": 0.9,
                 "log_delta_residual_quantiles": {"0.9": [-0.1, 0.1]}})
    return {
        "predicts": {"variable": "F21", "unit": "N"},
        "delta_convention": "δ1 = π1(source)/π1(target)",
        "groups": {"set": "synthetic", **model.groups_},
        "source": {"machine": "er12", "index": int(reference.name),
                   "row": {k: float(v) for k, v in reference.items() if isinstance(v, int | float | np.number)}},
        "inputs": [],
        "interval": interval,
        "training_range": training_range or {"min": g.min(axis=0).tolist(), "max": g.max(axis=0).tolist(),
                                             "margin": 0.1},
        "training": {}, "metrics": {},
    }


def _reference(recordings: pd.DataFrame) -> pd.Series:
    return recordings[recordings["machine"] == "er12"].iloc[5]


def _save(model: DeltaModel, train: DeltaDataset, recordings: pd.DataFrame, path: Path) -> zoo.ScalingModel:
    """Save through :func:`zoo.save_scaling_model` (its own round trip on the check rows included) and load."""
    model.fit(train)
    check = recordings[recordings["machine"] == "wa475"].iloc[:40]
    directory = zoo.save_scaling_model(model, path, _card(model, train, _reference(recordings)), check)
    served = zoo.load(directory)
    assert isinstance(served, zoo.ScalingModel)
    return served


@pytest.fixture(scope="module")
def ffnn(train: DeltaDataset, recordings: pd.DataFrame, tmp_path_factory: pytest.TempPathFactory
         ) -> zoo.ScalingModel:
    model = FFNN(include_source=True, hidden_layers=1, units=8, epochs=20, seed=1)
    return _save(model, train, recordings, tmp_path_factory.mktemp("ffnn") / "ffnn-source")


@pytest.fixture(scope="module")
def ensemble(train: DeltaDataset, recordings: pd.DataFrame, tmp_path_factory: pytest.TempPathFactory
             ) -> zoo.ScalingModel:
    model = DeepEnsemble(k=2, include_source=True, hidden_layers=1, units=8, epochs=20, seed=2)
    return _save(model, train, recordings, tmp_path_factory.mktemp("ensemble") / "ensemble-source")


@pytest.fixture(scope="module")
def gru(train: DeltaDataset, recordings: pd.DataFrame, tmp_path_factory: pytest.TempPathFactory
        ) -> zoo.ScalingModel:
    model = GRUModel(include_source=True, hidden_size=6, epochs=5, seed=3)
    return _save(model, train, recordings, tmp_path_factory.mktemp("gru") / "gru-source")


def _pairs(recordings: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(source rows, target rows): N_PAIRS ER12 rows matched one to one with WA475 rows (different sources)."""
    src = recordings[recordings["machine"] == "er12"].iloc[::3].iloc[:N_PAIRS].reset_index(drop=True)
    tgt = recordings[recordings["machine"] == "wa475"].iloc[:N_PAIRS].reset_index(drop=True)
    return src, tgt


def _si(rows: pd.DataFrame, names: tuple[str, ...]) -> np.ndarray:
    return rows[list(names)].to_numpy(float)


# ------------------------------------------------------------------------------------------------ features


@pytest.mark.parametrize("include_source", [False, True])
def test_features_match_log_distortion(include_source: bool):
    """:class:`Features` gives :meth:`LogDistortion.transform` for one source row, paired rows and one row."""
    rng = np.random.default_rng(0)
    fit = rng.normal(size=(50, 4)) * [1.0, 10.0, 0.1, 3.0] - [0.0, 20.0, 0.0, 0.0]
    transform = LogDistortion(include_source=include_source).fit(fit)
    pi_s, pi_t = rng.normal(size=(6, 4)), rng.normal(size=(6, 4))
    one = Features.build(transform, pi_s[0])
    paired = Features.build(transform, pi_s)
    assert one.n_features == paired.n_features == transform.n_features(4)
    np.testing.assert_allclose(one(pi_t), transform.transform(pi_s[0], pi_t), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(paired(pi_t), transform.transform(pi_s, pi_t), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(paired.rows(2, 4)(pi_t[2:4]), transform.transform(pi_s[2:4], pi_t[2:4]),
                               rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(one.with_source(pi_s[3])(pi_t[1]), transform.transform(pi_s[3], pi_t[1:2])[0],
                               rtol=1e-13, atol=1e-13)


# ------------------------------------------------------------------------------------------------ feed-forward


@pytest.mark.parametrize("name", ["ffnn", "ensemble"])
def test_one_source_row_matches_the_model(name: str, request: pytest.FixtureRequest, recordings: pd.DataFrame):
    """One (non-reference) source row for every target: batch and row paths give the model's own δ1 and F21."""
    served: zoo.ScalingModel = request.getfixturevalue(name)
    assert served.include_source and served._features.n_features == 2 * len(INPUTS)
    src, tgt = _pairs(recordings)
    source = src.iloc[[4]]
    pairs = DeltaDataset.from_pairs(source.iloc[0], tgt, PI1, INPUTS, warn=False)
    assert len(pairs) == len(tgt)
    delta = served.model.predict(pairs)
    force = pairs.recover(delta)
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.SourceWarning)  # the model takes the source as an input: no warning
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        batch = served.scale_force(source, tgt)
        bound = served.with_source(source)
        x = _si(tgt, served.target_variables)
        rows = np.array([bound.row(r, None)[:4] for r in x])
        own = np.array([served.predict_row(r, source=_si(source, served.source_variables)[0]) for r in x])
    np.testing.assert_allclose(batch.delta1, delta, rtol=RTOL)
    np.testing.assert_allclose(batch.force, force, rtol=RTOL)
    np.testing.assert_allclose(rows[:, 3], delta, rtol=RTOL)
    np.testing.assert_allclose(rows[:, 0], force, rtol=RTOL)
    np.testing.assert_allclose(own, rows[:, :3], rtol=1e-12)
    np.testing.assert_allclose(rows[:, 1], batch.lower, rtol=RTOL)
    np.testing.assert_allclose(rows[:, 2], batch.upper, rtol=RTOL)


@pytest.mark.parametrize("name", ["ffnn", "ensemble"])
def test_paired_source_rows_match_the_model(name: str, request: pytest.FixtureRequest, recordings: pd.DataFrame):
    """One matched source row per target row (the product-line setting): batch, row and stream paths."""
    served: zoo.ScalingModel = request.getfixturevalue(name)
    src, tgt = _pairs(recordings)
    pairs = DeltaDataset.from_matched(src, tgt, PI1, INPUTS)
    assert len(pairs) == N_PAIRS
    delta = served.model.predict(pairs)
    force = pairs.recover(delta)
    # the source matters: the same targets from the reference alone give other δ1
    assert not np.allclose(served.scale_force(None, tgt).delta1, delta, rtol=1e-3)
    batch = served.scale_force(src, tgt)
    np.testing.assert_allclose(batch.delta1, delta, rtol=RTOL)
    np.testing.assert_allclose(batch.force, force, rtol=RTOL)
    x, s = _si(tgt, served.target_variables), _si(src, served.source_variables)
    rows = np.array([served.row(xi, None, si)[:4] for xi, si in zip(x, s, strict=True)])
    np.testing.assert_allclose(rows[:, 3], delta, rtol=RTOL)
    np.testing.assert_allclose(rows[:, :3], np.column_stack([batch.force, batch.lower, batch.upper]), rtol=RTOL)
    one_by_one = [served.with_source(src.iloc[[i]]).predict_row(x[i])[0] for i in range(N_PAIRS)]
    np.testing.assert_allclose(one_by_one, force, rtol=RTOL)
    with served.stream() as stream:
        streamed = [stream.push(xi, source=si).force for xi, si in zip(x, s, strict=True)]
    np.testing.assert_allclose(streamed, rows[:, 0], rtol=1e-12)
    with pytest.raises(zoo.InputError, match="single source row"):
        served.with_source(src).predict_row(x[0])
    with pytest.raises(zoo.InputError, match="source row needs"):
        served.predict_row(x[0], source=s[0][:-1])


def test_source_outside_training_range_is_extrapolation(ffnn: zoo.ScalingModel, recordings: pd.DataFrame):
    """A source far from every training source: its own features are out of range, so the rows are flagged
    (the warning names the source features), and no SourceWarning is raised."""
    _, tgt = _pairs(recordings)
    far = ffnn.reference.copy()
    far["Pf_lift"] *= 1e3
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.SourceWarning)
        with pytest.warns(zoo.ExtrapolationWarning, match="Pf_lift/F31 of the source"):
            out = ffnn.scale_force(far, tgt)
    assert out.extrapolated.all()


def test_training_range_must_cover_every_feature(train: DeltaDataset, recordings: pd.DataFrame, tmp_path: Path):
    """A card whose training range has k entries for a 2k-feature model is refused at load (and at save)."""
    model = FFNN(include_source=True, hidden_layers=1, units=4, epochs=2).fit(train)
    k = len(INPUTS)
    short = {"min": [-1.0] * k, "max": [1.0] * k, "margin": 0.1}
    with pytest.raises(zoo.CheckpointError, match="training_range"):
        zoo.save_scaling_model(model, tmp_path / "m", _card(model, train, _reference(recordings),
                                                            training_range=short))


# ------------------------------------------------------------------------------------------------ recurrent


def test_gru_one_and_paired_sources_match_the_model(gru: zoo.ScalingModel, recordings: pd.DataFrame):
    """GRU: one episode as one sequence, from one source row (batch and stream) and from matched rows (batch)."""
    wa = recordings[recordings["machine"] == "wa475"]
    episode = wa[wa["episode"] == wa["episode"].iloc[0]].reset_index(drop=True)
    er = recordings[recordings["machine"] == "er12"]
    source = er.iloc[[11]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        pairs = DeltaDataset.from_pairs(source.iloc[0], episode, PI1, INPUTS, warn=False)
        delta = gru.model.predict(pairs)
        batch = gru.scale_force(source, episode)
        np.testing.assert_allclose(batch.delta1, delta, rtol=1e-5)
        with gru.with_source(source).stream() as stream:
            streamed = [stream.push(r).delta1 for r in _si(episode, gru.target_variables)]
        np.testing.assert_allclose(streamed, delta, rtol=1e-5)
        matched = er.iloc[:len(episode)].reset_index(drop=True)
        pairs = DeltaDataset.from_matched(matched, episode, PI1, INPUTS)
        delta = gru.model.predict(pairs)
        np.testing.assert_allclose(gru.scale_force(matched, episode).delta1, delta, rtol=1e-5)
        with gru.stream() as stream:
            streamed = [stream.push(r, source=s).delta1 for r, s in zip(
                _si(episode, gru.target_variables), _si(matched, gru.source_variables), strict=True)]
        np.testing.assert_allclose(streamed, delta, rtol=1e-5)


# ------------------------------------------------------------------------------------------------ without the source


def test_row_source_on_a_model_without_the_source():
    """An include_source=False model (shipped): ``source=`` on the row path is the bound source's arithmetic, and a
    source other than the reference still warns there as in the batch path."""
    served = zoo.load("ffnn-eq10")
    assert not served.include_source and served._features.n_features == len(served.input_groups)
    rows = check_rows(zoo.resolve("ffnn-eq10")[0]).rename(columns=lambda c: split_header(c)[0])
    x = _si(rows, served.target_variables)[:5]
    reference = served.reference[list(served.source_variables)].to_numpy(float)
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.SourceWarning)
        np.testing.assert_allclose([served.predict_row(r, source=reference) for r in x],
                                   [served.predict_row(r) for r in x], rtol=1e-12)
    other = reference.copy()
    other[served.source_variables.index("Pf_tilt")] *= 1.5
    with pytest.warns(zoo.SourceWarning, match="Pf_tilt/F31"):
        got = served.predict_row(x[0], source=other)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.SourceWarning)
        assert got == pytest.approx(served.with_source(dict(zip(served.source_variables, other, strict=True)))
                                    .predict_row(x[0]), rel=1e-12)
