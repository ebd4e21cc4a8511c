"""Distortion factors, δ1 convention, round trips, unit invariance and the δ1 data set.

Also hosts the synthetic ER12/WA475 recordings used by the model and grid tests: π1 = C·∏ π_n^{a_n} (or a running
average of it, for time memory), so the true δ1 = ∏ d_n^{a_n} is known.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from scaling.data.delta_dataset import DeltaDataset, concat_datasets
from scaling.dimensions import factors
from scaling.dimensions.factors import (
    LogDistortion,
    NonFiniteRowsWarning,
    distortions,
    group_values,
    pi1_to_source,
    pi1_to_target,
    prediction_factor,
    recover_target,
    scaled_variable,
)
from scaling.dimensions.groups import PiGroup

PI1 = PiGroup({"F21": 1, "F31": -1}, "pi1")
INPUTS = (
    PiGroup({"Pf_tilt": 1, "F31": -1}, "pi2"),
    PiGroup({"Pf_lift": 1, "F31": -1}, "pi3"),
    PiGroup({"x_b": 1, "y_b": -1}, "pi4"),
    PiGroup({"m_b": 1, "a1": 1, "F31": -1}, "pi5"),
    PiGroup({"m_b": 1, "alpha1": 1, "x_b": 1, "F31": -1}, "pi6"),
)
EXPONENTS = {"pi2": 0.5, "pi3": -0.3, "pi4": 0.4, "pi5": 0.2, "pi6": -0.1}
STATIC_EXPONENTS = {"pi2": 0.5, "pi3": -0.3, "pi4": 0.4}  # no a1/α1 groups: F21 stays finite at rest
MACHINES = {"er12": (1.0, 1.0, 1.0), "wa475": (2.0, 7.9, 1.3)}  # length scale, mass scale, distortion
# exponents of (M, L, T) per column, for unit rescaling
DIMS = {"F21": (1, 1, -2), "F31": (1, 1, -2), "Pf_tilt": (1, 1, -2), "Pf_lift": (1, 1, -2), "x_b": (0, 1, 0),
        "y_b": (0, 1, 0), "m_b": (1, 0, 0), "a1": (0, 1, -2), "alpha1": (0, 0, -2), "V1": (0, 1, -1),
        "w1": (0, 0, -1), "t": (0, 0, 1)}


def synthetic_recordings(*, episodes: tuple[int, int] = (6, 6), steps: int = 40, seed: int = 0,
                         rest_steps: int = 0, signed: bool = False, exponents: dict[str, float] | None = None,
                         c: float = 0.8, noise: float = 0.0, memory: float | None = None) -> pd.DataFrame:
    """Dig cycles of two machines; F21 = F31·c·exp(Σ a_n ln|π_n| [+ running average] [+ noise])."""
    rng = np.random.default_rng(seed)
    exps = EXPONENTS if exponents is None else exponents
    frames, ep = [], 0
    for (machine, scales), n_ep in zip(MACHINES.items(), episodes, strict=True):
        for _ in range(n_ep):
            frames.append(_episode(rng, machine, ep, steps, scales, rest_steps, signed))
            ep += 1
    df = pd.concat(frames, ignore_index=True)
    with np.errstate(divide="ignore"):
        log_pi1 = sum(exps[g.name] * np.log(np.abs(g.evaluate(df))) for g in INPUTS if g.name in exps)
    log_pi1 = np.asarray(log_pi1, dtype=float)
    if memory is not None:
        log_pi1 = _ema_by_episode(log_pi1, df["episode"].to_numpy(), memory)
    df["F21"] = df["F31"] * c * np.exp(log_pi1 + noise * rng.standard_normal(len(df)))
    return df


def _episode(rng: np.random.Generator, machine: str, ep: int, steps: int, scales: tuple[float, float, float],
             rest_steps: int, signed: bool) -> pd.DataFrame:
    length, mass, dist = scales
    s = np.linspace(0.0, 1.0, steps)
    ph, w = rng.uniform(0, 2 * np.pi, 4), rng.uniform(2.0, 6.0, 4)
    wave = [np.sin(w[i] * 2 * np.pi * s + ph[i]) for i in range(4)]
    m_b = 600.0 * mass * (0.4 + 0.6 * s**2 + 0.05 * rng.random()) * (1 + 0.1 * wave[0])
    x_b = length * (0.6 + 0.2 * s) * (1 + 0.15 * wave[1])
    y_b = length * (0.3 + 0.1 * wave[2]) * (-1.0 if signed else 1.0)
    a1 = 2.0 * dist * (1.2 + np.sin(w[3] * 3 * s + ph[3]))
    alpha1 = a1 / length * (1.0 + 0.3 * wave[3]) * dist
    a1[:rest_steps], alpha1[:rest_steps] = 0.0, 0.0
    f31 = m_b * (9.81 * (1.2 + 0.3 * s) + a1)
    tilt = f31 * ((0.3 + np.cos(np.pi * s + ph[0])) if signed else (0.9 + 0.4 * wave[0] * wave[3]) * dist)
    lift = f31 * (1.5 + 0.5 * s + 0.3 * wave[1]) / dist
    return pd.DataFrame({"machine": machine, "episode": ep, "t": s * 8.0, "F31": f31, "Pf_tilt": tilt,
                         "Pf_lift": lift, "x_b": x_b, "y_b": y_b, "m_b": m_b, "a1": a1, "alpha1": alpha1,
                         "V1": np.cumsum(a1) * 0.2, "w1": np.cumsum(alpha1) * 0.2})


def _ema_by_episode(x: np.ndarray, episode: np.ndarray, memory: float) -> np.ndarray:
    out = np.empty_like(x)
    for e in np.unique(episode):
        idx = np.flatnonzero(episode == e)
        acc = x[idx[0]]
        for i in idx:
            acc = memory * acc + (1 - memory) * x[i]
            out[i] = acc
    return out


def true_delta(ds: DeltaDataset, exponents: dict[str, float]) -> np.ndarray:
    """∏ d_n^{a_n} for the groups of the synthetic law."""
    d = ds.distortions()
    names = [g.name for g in ds.input_groups]
    return np.prod([d[:, names.index(k)] ** a for k, a in exponents.items()], axis=0)


def rescale_units(df: pd.DataFrame, mass: float, length: float, time: float) -> pd.DataFrame:
    """Same recording in other units: a value with dimension M^a L^b T^c is multiplied by mass^a·length^b·time^c."""
    out = df.copy()
    for col, (a, b, c) in DIMS.items():
        out[col] = df[col] * mass**a * length**b * time**c
    return out


def similar_copy(df: pd.DataFrame, lam: float) -> pd.DataFrame:
    """A geometrically and dynamically similar machine (Froude scaling, density kept): every group is unchanged."""
    out = rescale_units(df, lam**3, lam, lam**0.5)
    out["machine"] = "similar"
    return out


@pytest.fixture(scope="module")
def rec() -> pd.DataFrame:
    return synthetic_recordings()


# ------------------------------------------------------------------------------------------------ raw factors


def test_distortions_and_delta_follow_eq18_and_eq20(rec: pd.DataFrame) -> None:
    src, tgt = rec.iloc[5], rec.iloc[100:110]
    d = distortions(src, tgt, INPUTS)
    expected = group_values(src, INPUTS)[0] / group_values(tgt, INPUTS)
    np.testing.assert_allclose(d, expected, rtol=1e-14)
    delta = prediction_factor(src, tgt, PI1)
    np.testing.assert_allclose(delta, (src["F21"] / src["F31"]) / (tgt["F21"] / tgt["F31"]).to_numpy(), rtol=1e-14)


def test_all_unit_distortions_give_unit_delta(rec: pd.DataFrame) -> None:
    src = rec.iloc[[7]]
    tgt = similar_copy(src, 8.0)
    np.testing.assert_allclose(distortions(src, tgt, INPUTS), 1.0, rtol=1e-12)
    np.testing.assert_allclose(prediction_factor(src, tgt, PI1), 1.0, rtol=1e-12)
    g = LogDistortion().fit(group_values(rec, INPUTS)).transform(group_values(src, INPUTS), group_values(tgt, INPUTS))
    np.testing.assert_allclose(g, 0.0, atol=1e-12)


def test_vanishing_group_raises_unless_kept(rec: pd.DataFrame) -> None:
    tgt = rec.iloc[:3].copy()
    tgt["a1"] = 0.0
    with pytest.raises(ValueError, match="non-finite"):
        distortions(rec.iloc[10], tgt, INPUTS)
    d = distortions(rec.iloc[10], tgt, INPUTS, nonfinite="keep")
    assert np.isinf(d[:, 3]).all() and np.isfinite(np.delete(d, 3, axis=1)).all()


def test_round_trip_target_source_target_is_identity(rec: pd.DataFrame) -> None:
    src, tgt = rec.iloc[3], rec[rec["machine"] == "wa475"]
    delta = prediction_factor(src, tgt, PI1)
    f21 = recover_target(src, tgt.drop(columns="F21"), PI1, delta)
    np.testing.assert_allclose(f21, tgt["F21"].to_numpy(), rtol=1e-12)
    pi1_t = (tgt["F21"] / tgt["F31"]).to_numpy()
    np.testing.assert_allclose(pi1_to_target(pi1_to_source(pi1_t, delta), delta), pi1_t, rtol=1e-14)
    back = prediction_factor(tgt.iloc[0], src.to_frame().T, PI1)  # swapping roles inverts δ1
    np.testing.assert_allclose(back * delta[0], 1.0, rtol=1e-12)


def test_recover_general_exponent_and_variable_choice(rec: pd.DataFrame) -> None:
    pi1 = PiGroup({"F21": 2, "F31": -1, "Pf_lift": -1})
    src, tgt = rec.iloc[0], rec.iloc[50:60]
    with pytest.raises(ValueError, match="exponent 1"):
        scaled_variable(pi1)
    assert scaled_variable(pi1, "F21") == ("F21", 2)
    delta = prediction_factor(src, tgt, pi1)
    np.testing.assert_allclose(recover_target(src, tgt, pi1, delta, variable="F21"), tgt["F21"], rtol=1e-12)
    assert scaled_variable(PI1) == ("F21", 1)
    with pytest.raises(ValueError, match=r"not finite|non-finite"):
        recover_target(src, tgt, PI1, np.zeros(len(tgt)))


def test_rescaling_units_leaves_groups_and_delta_unchanged(rec: pd.DataFrame) -> None:
    mm_g_ms = rescale_units(rec, mass=1e3, length=1e3, time=1e3)
    assert not np.allclose(mm_g_ms["a1"], rec["a1"])
    ds_si = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=4)
    ds_mm = DeltaDataset.from_recordings(mm_g_ms, PI1, INPUTS, seed=4)
    np.testing.assert_allclose(ds_mm.delta, ds_si.delta, rtol=1e-10)
    np.testing.assert_allclose(ds_mm.pi_target, ds_si.pi_target, rtol=1e-10)
    tr = LogDistortion().fit(ds_si.pi_target)
    np.testing.assert_allclose(LogDistortion().fit(ds_mm.pi_target).eps, tr.eps, rtol=1e-10)
    np.testing.assert_allclose(tr.transform(ds_mm.pi_source, ds_mm.pi_target),
                               tr.transform(ds_si.pi_source, ds_si.pi_target), atol=1e-9)
    np.testing.assert_allclose(ds_mm.target_values(), mm_g_ms["F21"].to_numpy(), rtol=1e-12)


# ------------------------------------------------------------------------------------------------ log distortions


def test_log_distortion_is_ln_d_for_large_values_and_finite_at_zero() -> None:
    pis = np.array([[2.0, -3.0], [4.0, -1.5], [1.0, -6.0]])
    tr = LogDistortion(rel_eps=1e-6).fit(pis)
    np.testing.assert_array_equal(tr.sign, [1.0, -1.0])
    np.testing.assert_allclose(tr.eps, [2e-6, 3e-6])
    g = tr.transform(pis[0], pis)
    np.testing.assert_allclose(g, np.log(pis[0] / pis), atol=1e-9)  # both signs: g = ln d_n
    at_zero = tr.transform(pis[0], np.zeros((1, 2)))
    assert np.isfinite(at_zero).all() and (np.abs(at_zero) > 10).all()
    mixed = tr.transform(pis[0], -pis[:1])
    assert np.isfinite(mixed).all()


def test_log_distortion_golden_values_near_zero() -> None:
    """Where π is comparable to ε the feature is not ln d but the documented s·[asinh(π^s/2ε) − asinh(π^t/2ε)]:
    ε = 0.1 × median |π| = 0.2, π^s = 1, π^t = 0.5 and 0 give asinh(2.5) − asinh(1.25) and asinh(2.5) (values from
    the asinh table: asinh(2.5) = 1.6472311463710958, asinh(1.25) = 1.0475930126492587); a negative group gives the
    same with its orientation. Shipped checkpoints store ε and rely on this exact form."""
    tr = LogDistortion(rel_eps=0.1).fit(np.array([[1.0, -1.0], [2.0, -2.0], [3.0, -3.0]]))
    np.testing.assert_allclose(tr.eps, [0.2, 0.2])
    g = tr.transform(np.array([1.0, -1.0]), np.array([[0.5, -0.5], [0.0, 0.0]]))
    np.testing.assert_allclose(g, [[0.599638133721837] * 2, [1.6472311463710958] * 2], rtol=1e-12)


def test_log_distortion_edge_cases_and_serialisation() -> None:
    tr = LogDistortion(rel_eps=1e-2, include_source=True).fit(np.array([[0.0, 1.0], [0.0, np.inf], [0.0, 3.0]]))
    np.testing.assert_allclose(tr.eps, [1.0, 2e-2])  # all-zero group: ε = 1; inf ignored
    assert tr.transform(np.array([1.0, 2.0]), np.ones((4, 2))).shape == (4, 4)
    back = LogDistortion.from_dict(tr.to_dict())
    np.testing.assert_array_equal(back.eps, tr.eps)
    assert back.include_source
    with pytest.raises(RuntimeError, match="not fitted"):
        LogDistortion().transform(np.ones(2), np.ones((1, 2)))


# ------------------------------------------------------------------------------------------------ data set


def test_builder_pairs_reference_rows_with_every_target(rec: pd.DataFrame) -> None:
    ds = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=1)
    assert len(ds) == len(rec) and ds.labelled and set(ds.machine) == {"er12", "wa475"}
    assert np.unique(ds.pi1_source).size == 1
    again = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=1)
    np.testing.assert_array_equal(again.delta, ds.delta)
    aug = DeltaDataset.from_recordings(rec, PI1, INPUTS, seed=1, n_references=3)
    assert len(aug) == 3 * len(rec) and set(aug.reference) == {0, 1, 2}
    assert len(aug.sequences()) == 3 * rec["episode"].nunique()
    only_wa = DeltaDataset.from_recordings(rec, PI1, INPUTS, target_machines=["wa475"], reference_index=[4])
    assert set(only_wa.machine) == {"wa475"}
    np.testing.assert_allclose(only_wa.pi_source[0], group_values(rec.loc[[4]], INPUTS)[0])
    with pytest.raises(ValueError, match="source machine"):
        DeltaDataset.from_recordings(rec, PI1, INPUTS, source_machine="kabolite")
    assert len(concat_datasets([ds, only_wa])) == len(ds) + len(only_wa)


def test_sequences_are_time_ordered(rec: pd.DataFrame) -> None:
    ds = DeltaDataset.from_recordings(rec.sample(frac=1.0, random_state=0), PI1, INPUTS)
    for idx in ds.sequences():
        assert len(set(ds.sequence_keys()[idx])) == 1
        assert np.all(np.diff(ds.t[idx]) > 0)


def test_split_by_episode_has_no_shared_episodes(rec: pd.DataFrame) -> None:
    ds = DeltaDataset.from_recordings(rec, PI1, INPUTS, n_references=2)
    train, test = ds.split_by_episode(0.3, seed=2)
    k_train, k_test = set(train.episode_keys()), set(test.episode_keys())
    assert not k_train & k_test
    assert k_train | k_test == set(ds.episode_keys()) and len(train) + len(test) == len(ds)
    assert set(train.machine) == set(test.machine) == {"er12", "wa475"}
    with pytest.raises(ValueError):
        ds.split_by_episode(1.5)


def test_non_finite_rows_are_dropped_counted_and_warned(rec: pd.DataFrame) -> None:
    bad = rec.copy()
    bad.loc[20, "Pf_tilt"] = np.nan
    bad.loc[21, "F31"] = 0.0
    bad.loc[22, "F21"] = -1.0
    bad.loc[23, "x_b"] = np.inf
    with pytest.warns(NonFiniteRowsWarning, match="dropped"):
        ds = DeltaDataset.from_recordings(bad, PI1, INPUTS, reference_index=[0])
    assert sum(ds.dropped.values()) == 4 and len(ds) == len(rec) - 4
    assert ds.dropped["π1 ≤ 0 (δ1 not positive)"] == 1
    assert np.isfinite(ds.pi_target).all() and np.isfinite(ds.log_delta).all()
    with pytest.raises(KeyError, match="reference rows"):
        DeltaDataset.from_recordings(bad, PI1, INPUTS, reference_index=[20], warn=False)


def test_static_targets_keep_finite_features() -> None:
    rec = synthetic_recordings(rest_steps=5, exponents=STATIC_EXPONENTS)
    assert (rec["a1"] == 0).sum() > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        moving_ref = DeltaDataset.from_recordings(rec, PI1, INPUTS, reference_index=[10])
        static_ref = DeltaDataset.from_recordings(rec, PI1, INPUTS, reference_index=[0])
    for ds in (moving_ref, static_ref):
        assert len(ds) == len(rec) and not ds.dropped
        g = LogDistortion().fit(np.vstack([ds.pi_source, ds.pi_target])).transform(ds.pi_source, ds.pi_target)
        assert np.isfinite(g).all()
    assert np.isinf(moving_ref.distortions()).any()  # raw d_n = π^s/0 is infinite there (explicit request only)


def test_unlabelled_pairs_predict_target(rec: pd.DataFrame) -> None:
    src = rec.iloc[2]
    tgt = rec[rec["machine"] == "wa475"]
    ds = DeltaDataset.from_pairs(src, tgt.drop(columns="F21"), PI1, INPUTS)
    assert not ds.labelled
    with pytest.raises(ValueError, match="unlabelled"):
        _ = ds.delta
    delta = prediction_factor(src, tgt, PI1)
    np.testing.assert_allclose(ds.recover(delta), tgt["F21"].to_numpy(), rtol=1e-12)
    with pytest.raises(ValueError, match="single row"):
        DeltaDataset.from_pairs(rec.iloc[:2], tgt, PI1, INPUTS)


def test_the_data_set_lives_in_delta_dataset_only() -> None:
    """No redirect: :mod:`scaling.dimensions.factors` is the layer below the data set and does not re-export it."""
    assert DeltaDataset.__module__ == concat_datasets.__module__ == "scaling.data.delta_dataset"
    assert not hasattr(factors, "DeltaDataset") and not hasattr(factors, "concat_datasets")
