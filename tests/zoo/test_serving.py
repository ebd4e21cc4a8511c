"""Serving the δ1 checkpoints: units, clear errors, the extrapolation warning, the row and streaming paths."""

from __future__ import annotations

import json
import pickle
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import zoo
from scaling.data.delta_dataset import DeltaDataset
from zoo.scaling_kind import check_rows
from zoo.serving.inputs import split_header


@pytest.fixture(scope="module")
def ffnn() -> zoo.ScalingModel:
    return zoo.load("ffnn-eq10")


@pytest.fixture(scope="module")
def gru() -> zoo.ScalingModel:
    return zoo.load("gru-eq10")


@pytest.fixture(scope="module")
def ensemble() -> zoo.ScalingModel:
    return zoo.load("ensemble-eq10")


@pytest.fixture(scope="module")
def rows() -> pd.DataFrame:
    """The FFNN's check rows (held-out machines) with plain SI names (F21 included: the server ignores it)."""
    frame = check_rows(zoo.resolve("ffnn-eq10")[0])
    return frame.rename(columns=lambda c: split_header(c)[0])


def _si(model: zoo.ScalingModel, frame: pd.DataFrame) -> np.ndarray:
    return frame[list(model.target_variables)].to_numpy(float)


def _inside(model: zoo.ScalingModel, frame: pd.DataFrame) -> np.ndarray:
    """Rows whose features lie in the card's training range, computed by the scaling package (not the server)."""
    pairs = DeltaDataset.from_pairs(model.reference, frame, model.output_group, model.input_groups, warn=False)
    g = model.model.features(pairs)
    rng = model.card["training_range"]
    lo, hi = np.asarray(rng["min"]), np.asarray(rng["max"])
    margin = rng["margin"] * (hi - lo)
    return np.all((g >= lo - margin) & (g <= hi + margin), axis=1)


# ------------------------------------------------------------------------------------------------ units and errors


def test_units_are_converted(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    si = ffnn.scale_force(None, rows)
    lower, upper = si.interval
    assert np.all(lower < si.force) and np.all(si.force < upper) and si.coverage == 0.9
    assert list(si.to_frame().columns[:3]) == ["F21 [N]", "F21_lower [N]", "F21_upper [N]"]
    scaled = rows.copy()
    scaled["F31"] = scaled["F31"] / 1000.0
    scaled["x_b"] = scaled["x_b"] * 1000.0
    scaled = scaled.rename(columns={"F31": "F31 [kN]", "x_b": "x_b [mm]", "m_b": "m_b [kg]"})
    np.testing.assert_allclose(ffnn.scale_force(None, scaled).force, si.force, rtol=1e-9)
    as_dict = {c: scaled[c].to_numpy() for c in scaled.columns}
    np.testing.assert_allclose(ffnn.scale_force(None, as_dict).force, si.force, rtol=1e-9)
    np.testing.assert_allclose(ffnn.scale_force(None, _si(ffnn, rows)).force, si.force, rtol=1e-12)
    records = scaled.to_dict("records")
    np.testing.assert_allclose(ffnn.scale_force(ffnn.reference.to_dict(), records).force, si.force, rtol=1e-9)


def test_recording_target(ffnn: zoo.ScalingModel, tmp_path: Path):
    """A scaletwin recording (its own SI units) as the target: F21 is scaled from the reference row."""
    import gymnasium as gym

    import scaletwin_envs
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.recording import record_episode

    env = gym.make(scaletwin_envs.ENV_ID, scale=1.2)
    try:
        rec = record_episode(env, ScriptedDigPolicy(), seed=0, max_steps=60)
    finally:
        env.close()
    path = rec.to_parquet(tmp_path / "target.parquet")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        direct = ffnn.scale_force(None, rec)
        from_file = ffnn.scale_force(None, zoo.serving.read_table(path))
    np.testing.assert_allclose(direct.force, from_file.force, rtol=1e-12)
    assert len(direct) == len(rec) and np.all(np.isfinite(direct.force))


def test_source_in_other_units_gives_the_same_force(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    ref = ffnn.reference
    source = {f"{k} [kN]" if k in ("F21", "F31", "Pf_tilt", "Pf_lift") else k: ref[k] / 1000.0
              if k in ("F21", "F31", "Pf_tilt", "Pf_lift") else ref[k] for k in ffnn.source_variables}
    np.testing.assert_allclose(ffnn.scale_force(source, rows).force, ffnn.scale_force(None, rows).force, rtol=1e-9)


@pytest.mark.parametrize(("change", "message"), [
    (lambda f: f.drop(columns=["Pf_tilt"]), r"missing quantities: Pf_tilt \[N\]"),
    (lambda f: f.rename(columns={"F31": "F31 [m]"}), r"F31.*unit 'm' cannot be converted to 'N'"),
    (lambda f: f.rename(columns={"F31": "F31 [furlongs per fortnight]"}), r"F31.*cannot be converted"),
    (lambda f: f.assign(m_b=np.where(np.arange(len(f)) == 3, np.nan, f["m_b"])), r"non-finite .* m_b .*first row 3"),
    (lambda f: f.assign(F31=0.0), r"non-finite group"),
    (lambda f: f.assign(a1="fast"), r"'a1' is not numeric"),
])
def test_bad_inputs_are_clear_errors(ffnn: zoo.ScalingModel, rows: pd.DataFrame, change, message: str):
    with pytest.raises(zoo.InputError, match=message):
        ffnn.scale_force(None, change(rows))


def test_bad_source_and_arrays_are_clear_errors(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    with pytest.raises(zoo.InputError, match=r"source: .*missing quantities: F21"):
        ffnn.scale_force(rows.drop(columns=["F21"]).head(1), rows)
    with pytest.raises(zoo.InputError, match=r"shape \(n, 8\)"):
        ffnn.scale_force(None, np.zeros((3, 5)))
    with pytest.raises(zoo.InputError, match="source has 2 rows"):
        ffnn.scale_force(pd.DataFrame([ffnn.reference] * 2), rows.head(5))
    with pytest.raises(zoo.InputError, match="non-finite"):
        ffnn.predict_row([np.nan] * len(ffnn.target_variables))
    with pytest.raises(zoo.InputError, match="coverage"):
        ffnn.scale_force(None, rows, coverage=0.77)
    with pytest.raises(zoo.InputError, match="no rows"):
        ffnn.scale_force(None, rows.head(0))


# ------------------------------------------------------------------------------------------------ extrapolation


@pytest.mark.parametrize("name", ["ffnn-eq10", "ensemble-eq10", "gru-eq10"])
def test_extrapolation_warning_fires_outside_and_not_inside(name: str, rows: pd.DataFrame):
    model = zoo.load(name)
    inside = _inside(model, rows)
    assert inside.sum() > 50
    ok = rows[inside].reset_index(drop=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.ExtrapolationWarning)
        out = model.scale_force(None, ok)
    assert not out.extrapolated.any()
    far = ok.copy()
    far.loc[5, "Pf_lift"] = far.loc[5, "Pf_lift"] * 100.0  # a lift cylinder force far beyond anything trained on
    assert not _inside(model, far)[5]
    with pytest.warns(zoo.ExtrapolationWarning, match=r"1 of \d+ target rows .*Pf_lift/F31"):
        out = model.scale_force(None, far)
    assert out.extrapolated.tolist() == [i == 5 for i in range(len(far))]


def test_extrapolation_warning_on_the_row_path(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    x = _si(ffnn, rows[_inside(ffnn, rows)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.ExtrapolationWarning)
        ffnn.predict_row(x[0])
    far = x[0].copy()
    far[ffnn.target_variables.index("Pf_lift")] *= 100.0
    with pytest.warns(zoo.ExtrapolationWarning):
        ffnn.predict_row(far)


# ------------------------------------------------------------------------------------------------ paths agree


def test_row_path_matches_batch(ffnn: zoo.ScalingModel, ensemble: zoo.ScalingModel, rows: pd.DataFrame):
    for model in (ffnn, ensemble):
        x = _si(model, rows)
        batch = model.scale_force(None, x)
        single = np.array([model.predict_row(r) for r in x[:40]])
        np.testing.assert_allclose(single[:, 0], batch.force[:40], rtol=1e-5)
        np.testing.assert_allclose(single[:, 1], batch.lower[:40], rtol=1e-5)
        np.testing.assert_allclose(single[:, 2], batch.upper[:40], rtol=1e-5)
        assert all(isinstance(v, float) for v in single[0].tolist())


@pytest.mark.parametrize("name", ["ffnn-eq10", "statics-pl"])
def test_folded_row_path_matches_the_feature_path(name: str):
    """The bound-source row path (source folded into the first layer, range check on asinh π) gives the force,
    interval, δ1 and extrapolation flag of the plain path (features, standardise, MLP), here reached by passing the
    same source row explicitly; ``statics-pl`` takes the source's own features too."""
    model = zoo.load(name)
    assert model._bound_row is not None
    frame = check_rows(zoo.resolve(name)[0]).rename(columns=lambda c: split_header(c)[0])
    x = _si(model, frame)[:60]
    far = []  # each target variable far beyond anything trained on, one at a time
    for j in range(x.shape[1]):
        r = x[0].copy()
        r[j] *= 1e3
        far.append(r)
    src = model.reference[list(model.source_variables)].to_numpy(float)
    flagged = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        for r in [*x, *far]:
            folded, plain = model.row(r, None), model.row(r, None, src)
            np.testing.assert_allclose(folded[:4], plain[:4], rtol=1e-11)
            assert folded[4] == plain[4]
            flagged += folded[4]
    assert flagged >= 2


def test_batch_on_several_threads_matches_one(ffnn: zoo.ScalingModel, ensemble: zoo.ScalingModel,
                                              gru: zoo.ScalingModel, rows: pd.DataFrame):
    """Chunks run on threads give the rows back in order, identical to one thread; torch's setting is restored."""
    import torch

    from zoo.serving.kernels import CHUNK

    threads_before = torch.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)
        for model in (ffnn, ensemble):
            x = np.resize(_si(model, rows), (3 * CHUNK + 17, len(model.target_variables)))
            x[:, 0] *= np.linspace(0.9, 1.1, len(x))  # every row different, so a reordering would show
            one, three = model.predict_array(x, threads=1), model.predict_array(x, threads=3)
            np.testing.assert_array_equal(three.force, one.force)
            np.testing.assert_array_equal(three.upper, one.upper)
            np.testing.assert_array_equal(three.extrapolated, one.extrapolated)
        x = np.resize(_si(gru, rows), (4000, len(gru.target_variables)))
        seqs = [np.arange(0, 1000), np.arange(1000, 2000), np.arange(2000, 2500), np.arange(2500, 3000),
                np.arange(3000, 4000)]
        one, three = gru.predict_array(x, sequences=seqs, threads=1), gru.predict_array(x, sequences=seqs, threads=3)
        np.testing.assert_allclose(three.force, one.force, rtol=1e-6)
        alone = gru.predict_array(x[2500:3000], threads=1)  # a sequence run on its own gives the same
        np.testing.assert_allclose(three.force[2500:3000], alone.force, rtol=1e-6)
    assert torch.get_num_threads() == threads_before
    with pytest.raises(zoo.InputError, match="threads"):
        ffnn.predict_array(_si(ffnn, rows), threads=0)


def test_ensemble_interval_widens_with_coverage(ensemble: zoo.ScalingModel, rows: pd.DataFrame):
    narrow, wide = (ensemble.scale_force(None, rows, coverage=c) for c in (0.5, 0.99))
    assert np.all(wide.upper - wide.lower > narrow.upper - narrow.lower)
    assert narrow.interval_method == "ensemble" and wide.coverage == 0.99


def test_source_other_than_the_reference_warns(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    with warnings.catch_warnings():
        warnings.simplefilter("error", zoo.SourceWarning)
        ffnn.scale_force(ffnn.reference, rows)  # the reference itself: no warning
    other = ffnn.reference.copy()
    other["Pf_tilt"] *= 1.5
    with pytest.warns(zoo.SourceWarning, match="Pf_tilt/F31"):
        ffnn.scale_force(other, rows)
    other = ffnn.reference.copy()
    other["F21"] *= 1.1
    with pytest.warns(zoo.SourceWarning, match="π1"):
        ffnn.scale_force(other, rows)


def test_paired_sources_row_by_row(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    same = pd.DataFrame([ffnn.reference] * len(rows))
    np.testing.assert_allclose(ffnn.scale_force(same, rows).force, ffnn.scale_force(None, rows).force, rtol=1e-12)


def test_stream_carries_the_gru_state(gru: zoo.ScalingModel, rows: pd.DataFrame):
    episode = rows[rows["episode"] == rows["episode"].iloc[0]].sort_values("t")
    batch = gru.scale_force(None, episode.drop(columns=["episode"]))  # one sequence
    seen = []
    stream = gru.stream(on_prediction=seen.append)
    preds = [stream.push({k: r[k] for k in gru.target_variables}) for _, r in episode.iterrows()]
    np.testing.assert_allclose([p.force for p in preds], batch.force, rtol=1e-4)
    assert seen == preds and [p.step for p in preds] == list(range(len(episode)))
    stream.reset()
    first = stream.push(_si(gru, episode)[0])
    assert first.force == pytest.approx(preds[0].force, rel=1e-12)
    cold = [gru.scale_force(None, episode.iloc[[i]]).force[0] for i in (0, 10)]
    assert cold[1] != pytest.approx(preds[10].force, rel=1e-6)  # the state matters
    with pytest.raises(TypeError, match="stream"):
        gru.predict_row(_si(gru, episode)[0])


def test_stream_generator_units_and_rerun(ffnn: zoo.ScalingModel, rows: pd.DataFrame, tmp_path: Path):
    frame = rows.head(20).rename(columns={"F31": "F31 [kN]"}).assign(**{"F31 [kN]": rows["F31"].head(20) / 1e3})
    records = frame.to_dict("records")
    rrd = tmp_path / "serving.rrd"
    preds = list(ffnn.predict_stream(records, rerun=rrd))
    np.testing.assert_allclose([p.force for p in preds], ffnn.scale_force(None, rows.head(20)).force, rtol=1e-5)
    assert rrd.is_file() and rrd.stat().st_size > 0
    with pytest.raises(zoo.InputError, match="missing quantities"):
        ffnn.stream().push({"F31": 1.0})


# ------------------------------------------------------------------------------------------------ checkpoints


@pytest.fixture
def ffnn_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "ffnn-eq10"
    shutil.copytree(zoo.resolve("ffnn-eq10")[0], dst)
    return dst


def test_tampered_scaling_weights_refused(ffnn_copy: Path):
    data = bytearray((ffnn_copy / "weights.safetensors").read_bytes())
    data[-10] ^= 0x01
    (ffnn_copy / "weights.safetensors").write_bytes(bytes(data))
    with pytest.raises(zoo.CheckpointError, match=r"weights\.safetensors: sha256 .* tampered"):
        zoo.load(ffnn_copy)


def test_tampered_scaling_card_refused(ffnn_copy: Path, tmp_path: Path):
    registry = tmp_path / "registry.json"
    zoo.register("copy", ffnn_copy, registry=registry)
    assert isinstance(zoo.load("copy", registry=registry), zoo.ScalingModel)
    card = json.loads((ffnn_copy / "card.json").read_text())
    card["metrics"]["mini"]["mean_abs_pct_error"] = 0.01
    (ffnn_copy / "card.json").write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match="card sha256"):
        zoo.load("copy", registry=registry)


def test_tampered_config_and_malformed_scaling_card_refused(ffnn_copy: Path):
    card = json.loads((ffnn_copy / "card.json").read_text())
    del card["interval"]
    (ffnn_copy / "card.json").write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match=r"malformed scaling-model card.*interval"):
        zoo.load(ffnn_copy)
    (ffnn_copy / "config.json").write_text("{}")
    with pytest.raises(zoo.CheckpointError, match=r"config\.json: sha256"):
        zoo.load(ffnn_copy)


def test_pickling_reloads_from_the_zoo(ffnn: zoo.ScalingModel, rows: pd.DataFrame):
    blob = pickle.dumps(ffnn)
    assert len(blob) < 1000
    np.testing.assert_array_equal(pickle.loads(blob).scale_force(None, rows).force, ffnn.scale_force(None, rows).force)
