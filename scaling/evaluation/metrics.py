"""Building blocks of the pipeline: scaling domain, reference row, episode split and metrics.

δ1 convention (:mod:`scaling.dimensions.factors`): source = one reference row of the calibrated ER12 twin (paper:
"model"), target = any other row or machine (paper: "prototype"); δ1 = π1(source)/π1(target), π1 = F21/F31, and
F21_target = F31_target · π1(source) / δ1 (Eq. 22).

* Domain (:func:`in_domain`): rows with π1 = F21/F31 below ``min_pi1`` (default 0.1) are outside the scaling
  domain and left out of training and of the headline metrics. There F21 is an order of magnitude below the
  concurrent pin force F31 (it passes through zero when the load's weight line crosses O, and in the jolt as the
  bucket leaves the pile), δ1 ∝ 1/F21 is ill-conditioned (one such row can hold >99 % of the squared δ1 error
  of a test set) and a relative error on a near-zero force is meaningless. Metrics on *all* rows are reported
  beside the in-domain ones.
* Start-up (:func:`after_settling`): the first ``settle_steps`` control steps of every episode are left out too:
  the machine settles from its reset pose onto its cylinders there, a start-up transient of the simulator in which
  the cylinder forces swing through zero, not part of the dig cycle. Control steps are Froude-scaled (the env's
  time step scales with √λ), so the window is the same fraction of every machine's cycle (10 steps: 1 s on the
  ER12, about 9 % of its cycle).
* Reference (:func:`pick_reference`): the paper draws one random ER12 row. ``"static"`` (default) draws it, seeded,
  among ER12 rows *at rest* (inertial groups m_b·a1/F31 and m_b·α1·|x_b|/F31 below 1e-3, i.e. inertia under 0.1 %
  of the pin force) inside the domain, because the miniature is validated at rest; ``"random"`` draws any
  in-domain ER12 row as the paper did.
* Stroke end (:func:`at_stroke_end`): rows whose tilt cylinder sits at an end of its stroke, where its end stop
  carries load that no pressure sees and F21 is not the linkage statics of ``Pf_tilt``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from scaling.data.delta_dataset import DeltaDataset
from scaling.models import DeepEnsemble, DeltaModel, r2_score

AT_REST_TOLERANCE = 1e-3
#: Distance from either end of the tilt stroke (fraction of the stroke) within which a row counts as at the end: the
#: simulated cylinder runs up to 0.33 % of its stroke past its closed length under load (the joint limit's
#: softness; seed-0 layout, rows as in :func:`at_stroke_end`): 5235 of that layout's rows lie within 0.5 % of an end,
#: 5162 within 0.2 %.
STROKE_END_MARGIN = 0.005


def pi1(frame: pd.DataFrame) -> np.ndarray:
    """π1 = F21/F31 per row."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return frame["F21"].to_numpy(float) / frame["F31"].to_numpy(float)


def in_domain(frame: pd.DataFrame, min_pi1: float = 0.1) -> np.ndarray:
    """Boolean mask of rows inside the scaling domain (finite π1 ≥ ``min_pi1``)."""
    p = pi1(frame)
    return np.isfinite(p) & (p >= min_pi1)


def after_settling(frame: pd.DataFrame, settle_steps: int = 10) -> np.ndarray:
    """Rows from the ``settle_steps``-th control step of their episode on (rows in time order per episode)."""
    order = frame.groupby("episode", sort=False)["t"].rank(method="first").to_numpy()
    return order > settle_steps


def at_rest(frame: pd.DataFrame, tolerance: float = AT_REST_TOLERANCE) -> np.ndarray:
    """Rows whose inertial groups m_b·a1/F31 and m_b·α1·|x_b|/F31 are both below ``tolerance``."""
    f31 = frame["F31"].to_numpy(float)
    m_b, x_b = frame["m_b"].to_numpy(float), np.abs(frame["x_b"].to_numpy(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        lin = m_b * frame["a1"].to_numpy(float) / f31
        ang = m_b * frame["alpha1"].to_numpy(float) * x_b / f31
    return np.isfinite(lin) & np.isfinite(ang) & (lin < tolerance) & (ang < tolerance)


def at_stroke_end(frame: pd.DataFrame, margin: float = STROKE_END_MARGIN) -> np.ndarray:
    """Mask of the rows whose tilt cylinder is within ``margin`` (fraction of its stroke) of either end of its
    stroke (``tilt_stroke``, a design signal of :func:`scaling.data.product_line.add_design_signals`); all False
    without that column.

    There the cylinder's end stop carries what the oil does not: the pin force is set by the load on the bucket
    and the stop, not by the cylinder's pressure, and F21 = tilt_ratio · |Pf_tilt| (``F21_linkage``, the normaliser
    of :data:`scaling.data.product_line.PI1_LINKAGE`) no longer holds. Measured on the seed-0 layout (65 machines,
    its rows with F21 above 5 % of the machine's peak after the first second, 2026-11-28): 3.8 % of the rows are at
    an end (all at the retracted one; up to 59 % of a machine's dig rows), and every one of the 3746 rows where the
    linkage statics err by more than 10 % is among them (4780 of the 4784 beyond 3 %), each with the bucket
    pressed on the ground or the pile (a vertical soil force of at least 1.8 kN); at the end the statics err 17 %
    (median), 55 % (90th percentile).
    """
    if "tilt_stroke" not in frame.columns:
        return np.zeros(len(frame), dtype=bool)
    stroke = frame["tilt_stroke"].to_numpy(float)
    return (stroke <= margin) | (stroke >= 1.0 - margin)


def pick_reference(frame: pd.DataFrame, machine: str = "er12", mode: str = "static", seed: int = 0,
                   min_pi1: float = 0.1) -> Any:
    """Index label of the source row (see module docstring for ``mode``: ``"static"`` or ``"random"``).

    Raises:
        ValueError: unknown mode, or no candidate row.
    """
    if mode not in ("static", "random"):
        raise ValueError(f"reference mode must be 'static' or 'random', got {mode!r}")
    mask = (frame["machine"].astype(str) == machine).to_numpy() & in_domain(frame, min_pi1)
    if mode == "static":
        mask &= at_rest(frame)
    pool = frame.index[mask]
    if len(pool) == 0:
        raise ValueError(f"no {mode} reference row of machine {machine!r} in the data")
    return pool[int(np.random.default_rng(seed).integers(len(pool)))]


def split_episodes(frame: pd.DataFrame, test_fraction: float = 0.2, seed: int = 0) -> set[str]:
    """Test episode keys (``"machine/episode"``, as :meth:`DeltaDataset.episode_keys`): within each (machine, kind),
    a seeded ``test_fraction`` of the episodes, at least one where there are two or more."""
    if not 0 < test_fraction < 1:
        raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
    rng = np.random.default_rng(seed)
    test: set[str] = set()
    kinds = frame["kind"] if "kind" in frame.columns else pd.Series("dig", index=frame.index)
    for (machine, _), part in frame.groupby([frame["machine"].astype(str), kinds], sort=True):
        episodes = np.unique(part["episode"].to_numpy())
        if len(episodes) < 2:
            continue
        n = min(len(episodes) - 1, max(1, round(test_fraction * len(episodes))))
        test.update(f"{machine}/{e}" for e in rng.permutation(episodes)[:n])
    if not test:
        raise ValueError("need two or more episodes of some machine to hold episodes out")
    return test


def episode_mask(dataset: DeltaDataset, keys: set[str]) -> np.ndarray:
    return np.isin(dataset.episode_keys(), sorted(keys))


def kinds_of(dataset: DeltaDataset, frame: pd.DataFrame) -> np.ndarray:
    """``kind`` (dig/hold) of every pair, looked up from the recordings by episode."""
    if "kind" not in frame.columns:
        return np.full(len(dataset), "dig")
    lookup = frame.groupby("episode")["kind"].first()
    return lookup.reindex(dataset.episode).to_numpy().astype(str)


def ape(predicted: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """Absolute percentage error, %."""
    return 100.0 * np.abs(np.asarray(predicted, float) - actual) / np.abs(actual)


def delta_metrics(model: DeltaModel, test: DeltaDataset, kinds: np.ndarray | None = None) -> dict[str, Any]:
    """Held-out metrics: R² of δ1 (paper), of ln δ1, per kind, and the F21 error through Eq. (22)."""
    pred = model.predict(test)
    f21 = test.target_values()
    out: dict[str, Any] = {"n_test": len(test), "r2": r2_score(test.delta, pred),
                           "r2_log": r2_score(test.log_delta, np.log(pred)),
                           "f21_mape_pct": float(np.mean(ape(test.recover(pred), f21))),
                           "f21_median_ape_pct": float(np.median(ape(test.recover(pred), f21)))}
    if kinds is not None:
        for kind in sorted(set(kinds)):
            sel = kinds == kind
            out[f"r2_{kind}"] = r2_score(test.delta[sel], pred[sel])
            out[f"n_test_{kind}"] = int(sel.sum())
    return out


def machine_metrics(model: DeltaModel, pairs: DeltaDataset, coverage: float = 0.9) -> dict[str, Any]:
    """Scaled-F21 error on one machine's pairs and, for an ensemble, the coverage of its ``coverage`` interval."""
    pred = model.predict(pairs)
    f21 = pairs.target_values()
    err = ape(pairs.recover(pred), f21)
    out: dict[str, Any] = {"n": len(pairs), "f21_mape_pct": float(np.mean(err)),
                           "f21_median_ape_pct": float(np.median(err)), "r2": r2_score(pairs.delta, pred)}
    if isinstance(model, DeepEnsemble):
        lo, hi = model.predict_target_interval(pairs, coverage)
        out[f"coverage_{round(100 * coverage)}"] = float(np.mean((f21 >= lo) & (f21 <= hi)))
        out["interval_rel_width_median"] = float(np.median((hi - lo) / np.abs(f21)))
    return out


def machines(frame: pd.DataFrame) -> Sequence[str]:
    return sorted(frame["machine"].astype(str).unique())
