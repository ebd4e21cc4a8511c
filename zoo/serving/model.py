"""``ScalingModel``: a verified δ1 checkpoint that scales the bucket force F21 from a source machine to a target.

δ1 convention (:mod:`scaling.dimensions.factors`): source = the calibrated machine (the paper's "model"; by default the
ER12 twin row the checkpoint was trained against, ``model.reference``), target = the machine to predict (the paper's
"prototype"). The model predicts δ1 = π1(source)/π1(target) from the target's distortions, then

    F21_target = F31_target · π1(source) / δ1          (Eq. 22, π1 = F21/F31)

so the target needs only measurable quantities (F31, cylinder forces, bucket mass and centre of mass, bucket
accelerations or speeds; ``model.target_variables``), never F21 itself. The interval comes from the card
(``card["interval"]``): held-out residual quantiles of ln δ1 for FFNN and GRU models, the ensemble's predictive
spread for the deep ensemble, or (``learned-scale``, product-line checkpoints) a per-row width learned from what
the served model knows of the row (:class:`scaling.evaluation.conformal.RowInterval`; batch path with the risk computed,
the pooled residual quantiles otherwise). Targets whose distortion features fall outside the training range stored on
the card raise an :class:`ExtrapolationWarning` (the prediction is still returned, flagged per row).

Three paths share the same arithmetic: :meth:`ScalingModel.scale_force` (any table with units, batch),
:meth:`ScalingModel.predict_row` (one row as floats in SI, the lean path) and :meth:`ScalingModel.stream`
(row by row with the GRU's hidden state carried; see :mod:`zoo.serving.stream`).

Models fitted with ``include_source=True`` (e.g. the product-line models of :mod:`scaling.data.product_line`, trained on
one matched source row per target row) also take the source's own features ``s_n·asinh(π_n^s/2ε_n)``: the served
features are then 2k wide, as are the card's training range, and each target row is best given its own source row
(n source rows for n targets in the batch path, ``source=`` on the row path). Such a model learnt δ1 as a function
of the source too, so a source other than the reference raises no :class:`SourceWarning`; a source outside the
training range of the source features flags the rows as extrapolated instead.
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np
import pandas as pd

from scaling.dimensions.factors import LogDistortion, scaled_variable
from scaling.dimensions.groups import PiGroup
from scaling.evaluation.conformal import IntervalRisk, RowInterval, RowRisk
from scaling.evaluation.metrics import at_rest, at_stroke_end
from scaling.models import DeltaModel
from scaling.models.fitted import STATIC_STEPS, model_groups
from zoo.loading import load
from zoo.serving.inputs import InputError, Rows, split_header, to_matrix
from zoo.serving.kernels import (
    CHUNK,
    BoundMLPRow,
    EnsembleKernel,
    Features,
    GroupPlan,
    GRUKernel,
    MLPKernel,
    kernel_for,
    normal_quantile,
)
from zoo.serving.parallel import map_ordered, resolve_threads
from zoo.serving.stream import Prediction, Stream


def served_variables(output: PiGroup, inputs: Sequence[PiGroup], variable: str
                     ) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(source variables, target variables) of a model: every variable of its groups, the scaled ``variable``
    (e.g. F21) only on the source side; the target order is the order of :meth:`ScalingModel.predict_row`."""
    source = tuple(dict.fromkeys(v for g in (output, *inputs) for v in g.variables))
    target = [v for g in (*inputs, output) for v in g.variables if v != variable]
    return source, tuple(dict.fromkeys(target))


def _bounds(force: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) = force·e^(∓half) (SI); a width beyond floating point is reported as [0, inf]."""
    with np.errstate(over="ignore"):
        return force * np.exp(-half), force * np.exp(half)


class ExtrapolationWarning(UserWarning):
    """The target's distortions lie outside the range the model was trained on: the prediction is extrapolated."""


class EndStopWarning(UserWarning):
    """Target rows with the tilt cylinder at an end of its stroke (:func:`scaling.evaluation.metrics.at_stroke_end`):
    its end stop carries load that no pressure shows, so F21 there is not the linkage statics of ``Pf_tilt`` the
    product-line models scale, and neither the prediction nor its interval can be trusted (``ScaledForce.stroke_end``
    per row). On the seed-0 product line every row whose linkage statics err by more than 10 % is such a row."""


class SourceWarning(UserWarning):
    """The source row differs from the calibrated reference row the model learnt δ1 against (``model.reference``):
    δ1 = π1(source)/π1(target) was only ever learnt for that source, so predictions from another one are biased.
    Never raised for models fitted with ``include_source=True``, which take the source's features as inputs."""


@dataclass
class ScaledForce:
    """Scaled force per target row (SI): ``force`` (e.g. F21, N) with its ``lower``/``upper`` interval at
    ``coverage``, the predicted ``delta1``, whether each row was ``extrapolated`` (outside the training range of
    the features) and, for checkpoints that carry an error score, the ``risk`` that the row is more than 10 % off
    (:class:`~scaling.evaluation.conformal.RowRisk`; None otherwise)."""

    variable: str
    unit: str
    force: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    delta1: np.ndarray
    extrapolated: np.ndarray
    coverage: float
    interval_method: str
    risk: np.ndarray | None = None
    #: the rows whose risk is above the error score's calibrated threshold (the warning counts them); None
    #: where no risk was computed
    warned: np.ndarray | None = None
    #: an ensemble's σ of ln δ1 per row (the spread of its members' mixture, 1); None for a point model
    sigma: np.ndarray | None = None
    #: the rows whose tilt cylinder sits at a stroke end (:class:`EndStopWarning`); None for a model that does not
    #: take the tilt stroke
    stroke_end: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.force)

    @property
    def interval(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) bounds of the force at :attr:`coverage` (SI)."""
        return self.lower, self.upper

    def to_frame(self) -> pd.DataFrame:
        """Columns ``F21 [N]``, ``F21_lower [N]``, ``F21_upper [N]``, ``delta1 [1]``, ``extrapolated`` and, where
        computed, ``risk [1]`` and ``stroke_end``."""
        v, u = self.variable, self.unit
        out = pd.DataFrame({f"{v} [{u}]": self.force, f"{v}_lower [{u}]": self.lower,
                            f"{v}_upper [{u}]": self.upper, "delta1 [1]": self.delta1,
                            "extrapolated": self.extrapolated})
        if self.risk is not None:
            out["risk [1]"] = self.risk
        if self.stroke_end is not None:
            out["stroke_end"] = self.stroke_end
        return out


class ScalingModel:
    """A δ1 model from the zoo, ready to serve (see the module docstring).

    Attributes:
        model: the rebuilt :class:`~scaling.models.DeltaModel`.  card: its card.  ref: name or path it came from.
        variable, unit: the scaled quantity (``"F21"``, ``"N"``).
        target_variables: what a target row needs (SI order of :meth:`predict_row`).
        source_variables: what a source row needs (F21 included).
        coverage: the default interval level.
    """

    def __init__(self, model: DeltaModel, card: Mapping[str, Any], ref: str, risk: RowRisk | None = None) -> None:
        self.model, self.card, self.ref = model, dict(card), ref
        self.risk = risk
        output, inputs = model_groups(model)
        self.output_group, self.input_groups = output, inputs
        self.variable, exponent = scaled_variable(output)
        self.unit = str(card["predicts"]["unit"])
        self._inv_exp = 1.0 / float(exponent)
        rest = {k: e for k, e in output.exponents.items() if k != self.variable}
        self.source_variables, self.target_variables = served_variables(output, inputs, self.variable)
        rest_group = PiGroup(rest) if rest else PiGroup({self.target_variables[0]: Fraction(1)})  # unused if no rest
        self._plan_t = GroupPlan.build([*inputs, rest_group], self.target_variables)
        self._has_rest = bool(rest)
        self._plan_s = GroupPlan.build([*inputs, output], self.source_variables)
        self.kernel = kernel_for(model)
        transform = model.transform_
        if transform is None:
            raise ValueError(f"{model.name} is not fitted")
        self._transform: LogDistortion = transform
        names = [g.expression() for g in inputs]
        self._group_names = names
        # one name per feature: the distortions g_n, then (include_source) the source's own features
        self._feature_names = names + ([f"{n} of the source" for n in names] if transform.include_source else [])
        interval = card["interval"]
        self.coverage = float(interval["coverage"])
        self.interval_method = str(interval["method"])
        self._row_interval: RowInterval | None = None
        if self.interval_method == "learned-scale":
            if risk is None:
                raise ValueError("a learned-scale interval needs the checkpoint's risk (its novelty rows)")
            # the risk reads this interval (zoo.scaling_kind rebuilt it from the same state)
            self._row_interval = (risk.score.interval if risk.score is not None
                                  else RowInterval.from_state(interval["learned_scale"]))
        self._quantiles = {float(c): (float(q[0]), float(q[1]))
                           for c, q in interval.get("log_delta_residual_quantiles", {}).items()}
        #: (sources, interval, risk or None where none was calibrated) of :meth:`scale_force_sources`, where the
        #: card calibrates one
        self._multi: tuple[int, RowInterval, IntervalRisk | None] | None = None
        if "multi_source" in interval:
            if risk is None:
                raise ValueError("a multi-source interval needs the checkpoint's risk (its novelty rows)")
            multi = interval["multi_source"]
            learned = RowInterval.from_state(multi["learned_scale"])
            self._multi = (int(multi["sources"]), learned,
                           None if multi.get("risk") is None else IntervalRisk.from_state(multi["risk"], learned))
        rng = card["training_range"]
        g_min, g_max = np.asarray(rng["min"], dtype=float), np.asarray(rng["max"], dtype=float)
        n_features = transform.n_features(len(inputs))
        if g_min.shape != (n_features,) or g_max.shape != (n_features,):
            raise ValueError(f"training_range min/max have shapes {g_min.shape}/{g_max.shape}; the model takes "
                             f"{n_features} features ({len(inputs)} groups"
                             f"{' and their source values' if transform.include_source else ''})")
        self._margin = float(rng.get("margin", 0.0)) * (g_max - g_min)
        self._g_lo, self._g_hi = g_min - self._margin, g_max + self._margin
        self._row_spread = self._spread(None)
        self._h_reference: np.ndarray | None = None
        self.bind(self.reference)
        self._h_reference, self._pi1_reference = self._features.h_source, self._pi1_source

    # ------------------------------------------------------------------------------------------------ source

    @property
    def name(self) -> str:
        return str(self.card["name"])

    @property
    def recurrent(self) -> bool:
        return isinstance(self.kernel, GRUKernel)

    @property
    def reference(self) -> pd.Series:
        """The calibrated source row the model was trained against (SI), the default source."""
        src = self.card["source"]
        return pd.Series({k: float(v) for k, v in src["row"].items()}, name=src.get("index"))

    @property
    def include_source(self) -> bool:
        """Whether the model takes the source's own features too (fitted with ``include_source=True``)."""
        return self._transform.include_source

    def bind(self, source: Rows) -> ScalingModel:
        """Use ``source`` (one row, or n rows paired with n targets) as the source from now on; returns self."""
        x = to_matrix(source, self.source_variables, "source")
        vals = self._plan_s.values(x)
        pi1 = vals[:, -1]
        if not (np.all(np.isfinite(vals)) and np.all(pi1 > 0)):
            raise InputError(f"source: groups must be finite and π1 = {self.output_group.expression()} > 0; got "
                             f"π1 = {pi1[:3].tolist()}")
        one = len(x) == 1
        self._features = Features.build(self._transform, vals[0, :-1] if one else vals[:, :-1])
        kernel = self.kernel
        self._bound_row = (BoundMLPRow.build(kernel, self._features, self._g_lo, self._g_hi)
                           if isinstance(kernel, MLPKernel) else None)  # None for several sources too
        self._pi1_source = float(pi1[0]) if one else pi1
        self._n_source = len(x)
        if self._h_reference is not None:
            self._check_source(np.atleast_2d(self._features.h_source), pi1)
        return self

    def _check_source(self, h: np.ndarray, pi1: np.ndarray, stacklevel: int = 4) -> None:
        """Warn when sources (features ``h`` (n, k) = s·asinh(π^s/2ε), π1 (n,)) differ from the reference's
        (features beyond the range margin, π1 by 0.1 %); never for an ``include_source`` model."""
        if self.include_source:
            return
        off = (np.abs(h - self._h_reference) > self._margin).any(axis=0)
        pi1_off = np.abs(pi1 / self._pi1_reference - 1.0) > 1e-3
        if off.any() or pi1_off.any():
            names = [n for n, o in zip(self._group_names, off, strict=True) if o] + (["π1"] if pi1_off.any() else [])
            warnings.warn(f"{self.name}: the source differs from the calibrated reference row the model was trained "
                          f"against (model.reference; groups {', '.join(names)}): δ1 was learnt relative to that row "
                          "only, so predictions from this source are biased; pass source=None to use it",
                          SourceWarning, stacklevel=stacklevel)

    def _row_source(self, source: Sequence[float]) -> tuple[Features, float]:
        """(features, π1) of one source row given as SI floats in :attr:`source_variables` order (row path)."""
        if len(source) != len(self.source_variables):
            raise InputError(f"a source row needs {len(self.source_variables)} SI values "
                             f"({', '.join(self.source_variables)}), got {len(source)}")
        try:
            vals = self._plan_s.row(source)
        except ZeroDivisionError:
            raise InputError("source row: a divisor (e.g. F31 or y_b) is 0") from None
        pi1 = vals[-1]
        if not (all(math.isfinite(v) for v in vals) and pi1 > 0):
            raise InputError(f"source row: groups must be finite and π1 = {self.output_group.expression()} > 0; "
                             f"got π1 = {pi1}")
        features = self._features.with_source(np.array(vals[:-1]))
        self._check_source(features.h_source[None], np.array([pi1]), stacklevel=5)
        return features, pi1

    def nearest_source_row(self, rows: Rows) -> int:
        """Position of the row of ``rows`` (e.g. a whole source recording) closest to :attr:`reference` in the
        model's features (max-norm of the asinh group coordinates; π1 > 0 and finite groups only)."""
        x = to_matrix(rows, self.source_variables, "source")
        vals = self._plan_s.values(x)
        ok = np.all(np.isfinite(vals), axis=1) & (vals[:, -1] > 0)
        if not ok.any():
            raise InputError("source: no row has finite groups and π1 > 0")
        h = self._features.h(vals[:, :-1])
        dist = np.where(ok, np.max(np.abs(h - self._h_reference), axis=1), np.inf)
        return int(np.argmin(dist))

    def with_source(self, source: Rows) -> ScalingModel:
        """A copy bound to another source (this model keeps its own)."""
        return copy.copy(self).bind(source)

    # ------------------------------------------------------------------------------------------------ batch

    def scale_force(self, source: Rows | None, target: Rows, *, coverage: float | None = None,
                    hold: int | None = None, threads: int | None = None, risk: bool = True) -> ScaledForce:
        """F21 of every target row with its interval (SI), from the source's F21 through δ1 (Eq. 22).

        Args:
            source: the source machine's row (one row, or one per target row); ``None``: :attr:`reference`.
            target: the target machine's measurable quantities (:attr:`target_variables`), any accepted form
                (:mod:`zoo.serving.inputs`).
            coverage: interval level (default the card's; residual-quantile intervals exist at the card's levels).
            hold: recurrent models only: treat each target row as the machine held still for ``hold`` steps and
                report the last step. Otherwise a recurrent model runs the rows as time series: one per ``episode``
                (sorted by ``t``) if the target has those columns, else one. A target made only of lone rows (every
                episode one row long, as in :func:`scaling.evaluation.miniature.static_rows`) has no history to run, so
                each row is held for :data:`~scaling.models.fitted.STATIC_STEPS` steps, as in the miniature validation.
            threads: cores for a large batch (default every usable core; see :meth:`predict_array`).
            risk: compute the per-row error score where the checkpoint has one (``out.risk``; None where it has
                none, :attr:`risk_unavailable` says why; a nearest-neighbour
                query per row, about 20 000 rows/s per core); ``False`` skips it for throughput, and a
                ``learned-scale`` interval then falls back to the pooled residual quantiles
                (``out.interval_method`` says which).

        Raises:
            InputError: missing quantities, bad units, non-finite values, or a source/target size mismatch.
        """
        x = to_matrix(target, self.target_variables, "target")
        model = self
        if source is not None:
            model = self.with_source(source)
        if model._n_source not in (1, len(x)):
            raise InputError(f"source has {model._n_source} rows; give one row (e.g. the one "
                             f"model.nearest_source_row(source) picks) or one per target row ({len(x)})")
        seqs = self._sequences(target, len(x)) if self.recurrent and hold is None else None
        if seqs is not None and all(len(s) == 1 for s in seqs):
            hold = STATIC_STEPS
        if hold is not None:
            if not self.recurrent:
                raise InputError("hold applies to recurrent (GRU) models only")
            if model._n_source > 1:
                raise InputError("hold needs a single source row")
            return model.predict_array(np.repeat(x, hold, axis=0), coverage=coverage,
                                       sequences=np.arange(len(x) * hold).reshape(len(x), hold), pick=hold,
                                       threads=threads)
        return model.predict_array(x, coverage=coverage, sequences=seqs, threads=threads, risk=risk)

    @property
    def risk_unavailable(self) -> str | None:
        """Why this checkpoint serves no per-row risk (``ScaledForce.risk`` None), or None where it serves one. A
        product-line checkpoint reads its risk off its interval calibrated on held-out machines
        (:class:`scaling.evaluation.conformal.IntervalRisk`); a card without one says why
        (``metrics.risk_unavailable``) and its interval is served as usual. Checkpoints of a kind that never has a
        risk (the paper's) say so too."""
        if self.risk is None:
            return "this checkpoint has no error score (its warnings come from the training range)"
        return None if self.risk.score is not None else (self.risk.unavailable or "no risk was calibrated")

    def sources_risk_unavailable(self) -> str | None:
        """As :attr:`risk_unavailable`, for :meth:`scale_force_sources` (None: it serves a risk)."""
        if self._multi is None:
            return "this checkpoint has no multi-source calibration"
        if self._multi[2] is not None:
            return None
        multi = self.card["interval"]["multi_source"]
        return str(multi.get("risk_unavailable") or "no error score was learnt for several sources")

    @property
    def calibrated_sources(self) -> int | None:
        """How many source machines :meth:`scale_force_sources` is calibrated for (None: the card has no
        multi-source interval; use :meth:`scale_force`)."""
        return None if self._multi is None else self._multi[0]

    def scale_force_sources(self, sources: Sequence[Rows], target: Rows, *, coverage: float | None = None,
                            threads: int | None = None) -> ScaledForce:
        """F21 of every target row from several calibrated machines: the geometric mean of the F21 each source
        gives (:meth:`scale_force`), with the interval and error score the card calibrated for that many sources
        (on held-out machines, each predicted from its nearest training machines the same way).

        One calibrated machine's matched rows carry its own transients; over several, those the target does not
        share cancel in part, and a source row that is ill-conditioned for this target (a near-zero tilt load) is
        outvoted. The error score and interval take the served features of the first source's rows, with the ln δ1
        of that source which recovers the mean; list the source nearest the target in design first.

        Args:
            sources: one entry per source machine (:attr:`calibrated_sources` of them), each one row or one
                matched row per target row (:func:`scaling.data.product_line.match_rows`), any accepted form.
            target, coverage, threads: as for :meth:`scale_force` (the risk is always computed, where the card
                has an error score for several sources: :meth:`sources_risk_unavailable`).

        Raises:
            InputError: the card has no multi-source calibration, or for another number of sources; bad inputs.
        """
        if self._multi is None or self.recurrent:
            raise InputError(f"{self.name} has no interval calibrated for several sources; use scale_force with one")
        k, interval, score = self._multi
        if isinstance(sources, pd.DataFrame | pd.Series | np.ndarray) or len(sources) != k:
            raise InputError(f"{self.name} is calibrated for {k} sources: give a list of {k} (each one row or one "
                             "matched row per target row); with one source use scale_force")
        x = to_matrix(target, self.target_variables, "target")
        bound = [self.with_source(s) for s in sources]
        outs = []
        with warnings.catch_warnings():  # each source's own warnings are replaced by the combined error score's
            warnings.simplefilter("ignore", ExtrapolationWarning)
            warnings.simplefilter("ignore", EndStopWarning)  # said once below
            for model in bound:
                if model._n_source not in (1, len(x)):
                    raise InputError(f"a source has {model._n_source} rows; give one row or one per target row "
                                     f"({len(x)})")
                outs.append(model.predict_array(x, coverage=coverage, threads=threads, risk=False))
        logs = np.log(np.abs(np.stack([o.force for o in outs])))
        force = np.sign(outs[0].force) * np.exp(logs.mean(axis=0))
        # recover() gives F ∝ δ1^(−1/exponent): the δ1 of the first source that recovers the mean force
        delta = outs[0].delta1 * np.exp((logs[0] - np.log(np.abs(force))) / self._inv_exp)
        # the sources' σ combined as the judge does (scaling.evaluation.generalisation.combine_sources): RMS
        sigma = (None if outs[0].sigma is None
                 else np.sqrt(np.mean([o.sigma**2 for o in outs if o.sigma is not None], axis=0)))
        features = bound[0]._risk_features(x, delta)
        cov = self._spread(coverage)[0]
        try:
            half = interval.half_width(features, cov) * abs(self._inv_exp)
        except ValueError as exc:
            raise InputError(f"{self.name}: {exc}") from None
        risk = warned = None
        if score is not None:
            risk, warned = self._scored(score, features, f" from {k} sources", stacklevel=3)
        extrapolated = np.logical_or.reduce([o.extrapolated for o in outs])
        lo, hi = _bounds(force, half)
        return ScaledForce(self.variable, self.unit, force, lo, hi, delta, extrapolated, cov,
                           f"learned-scale, {k} sources", risk, warned, sigma, self._stroke_end(x, 3))

    def predict_array(self, x: np.ndarray, *, coverage: float | None = None,
                      sequences: Sequence[np.ndarray] | np.ndarray | None = None,
                      pick: int | None = None, threads: int | None = None, risk: bool = True) -> ScaledForce:
        """Batch path on a raw SI matrix ``x`` (n, len(target_variables)); no unit handling.

        ``sequences`` (recurrent models): index arrays run as separate time series (default: all rows, one series);
        ``pick``: keep only the last row of every ``pick`` rows (used by ``hold``); ``threads``: cores to use
        (default every usable core; rows are cut into :data:`CHUNK`-row chunks run at once, see
        :mod:`zoo.serving.parallel`).
        """
        n = len(x)
        if n == 0:
            raise InputError("target: no rows")
        spread = self._spread(coverage)
        try:
            threads = resolve_threads(threads)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        if isinstance(self.kernel, GRUKernel):
            parts = self._recurrent_parts(x, spread, sequences, pick, threads)
        else:
            parts = map_ordered(lambda start: self._chunk(x, start, spread), range(0, n, CHUNK), threads)
        force, lo, hi, delta, outside, g_out, sigma = (np.concatenate(c) for c in zip(*parts, strict=True))
        spread_of_rows = sigma if isinstance(self.kernel, EnsembleKernel) else None
        if not np.all(np.isfinite(force)):
            raise InputError(f"target: {int((~np.isfinite(force)).sum())} rows give a non-finite {self.variable}")
        row_risk = warned = None
        method = "residual-quantiles" if self._row_interval is not None else self.interval_method
        if self.risk is not None and not isinstance(self.kernel, GRUKernel):  # its warnings replace the range's
            if risk:
                features = self._risk_features(x, delta)
                if self._row_interval is not None:  # δ1·e^(±h) gives F21·e^(∓h/exponent)
                    lo, hi = _bounds(force, self._row_interval.half_width(features, spread[0]) * self._inv_exp)
                    method = self.interval_method
                if self.risk.score is not None:  # else no error score was learnt (risk_unavailable says why)
                    row_risk, warned = self._scored(self.risk.score, features, "", stacklevel=4)
        elif outside.any():
            self._warn(g_out, int(outside.sum()), len(outside))
        return ScaledForce(self.variable, self.unit, force, lo, hi, delta, outside, spread[0], method, row_risk,
                           warned, spread_of_rows, self._stroke_end(x if pick is None else x[pick - 1::pick], 4))

    def _stroke_end(self, x: np.ndarray, stacklevel: int) -> np.ndarray | None:
        """Rows of ``x`` (the rows served, one per prediction) whose tilt cylinder sits at a stroke end, with an
        :class:`EndStopWarning` (at ``stacklevel`` counted from here) where any does; None when the model does not
        take ``tilt_stroke``."""
        if "tilt_stroke" not in self.target_variables:
            return None
        column = x[:, self.target_variables.index("tilt_stroke")]
        end = at_stroke_end(pd.DataFrame({"tilt_stroke": column}))
        if end.any():
            warnings.warn(f"{self.name}: {int(end.sum())} of {len(end)} target rows have the tilt cylinder at a stroke "
                          "end, where its end stop carries load no pressure shows: F21 there is not scaled from the "
                          "tilt pressure and its interval does not hold (ScaledForce.stroke_end per row)",
                          EndStopWarning, stacklevel=stacklevel)
        return end

    def _scored(self, score: IntervalRisk, features: np.ndarray, context: str, stacklevel: int
                ) -> tuple[np.ndarray, np.ndarray]:
        """(risk, warned) of every row by ``score`` on its served ``features``, warning (ExtrapolationWarning, at
        ``stacklevel`` counted from here) when any row's risk reaches the warning probability; ``context`` is added
        to the message after the miss (e.g. " from 3 sources")."""
        risk = score.score(features)
        warned = score.above(risk)
        if warned.any():
            warnings.warn(f"{self.name}: {int(warned.sum())} of {len(warned)} target rows are likely more than "
                          f"{score.miss:.0%} off{context} (P ≥ {score.warn_probability:g} by the interval calibrated "
                          "on held-out machines; ScaledForce.risk per row)", ExtrapolationWarning,
                          stacklevel=stacklevel)
        return risk, warned

    def _risk_features(self, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The served features of every row (:meth:`scaling.evaluation.conformal.RowRisk.features`): the novelty of its
        features g, |ln δ1| and whether the bucket is at rest (:func:`scaling.evaluation.metrics.at_rest` on the
        target's F31, m_b, x_b, a1 and α1; moving when the model does not take them)."""
        assert self.risk is not None
        g = np.concatenate([self._features_of(x[s:s + CHUNK], s)[0] for s in range(0, len(x), CHUNK)])
        col = {v: i for i, v in enumerate(self.target_variables)}
        needed = ("F31", "m_b", "x_b", "a1", "alpha1")
        static = (at_rest(pd.DataFrame({v: x[:, col[v]] for v in needed})) if all(v in col for v in needed)
                  else np.zeros(len(x), dtype=bool))
        return RowRisk.features(self.risk.novelty, g, np.log(delta), static)

    def _chunk(self, x: np.ndarray, start: int, spread: tuple[float, float, float]) -> tuple[np.ndarray, ...]:
        """:meth:`_finish` of feed-forward rows ``start:start + CHUNK``."""
        g, rest = self._features_of(x[start:start + CHUNK], start)
        mu, var = self.kernel.batch(g)
        return self._finish(g, rest, mu, var, self._pi1_rows(start, start + len(g)), spread)

    def _recurrent_parts(self, x: np.ndarray, spread: tuple[float, float, float],
                         sequences: Sequence[np.ndarray] | np.ndarray | None, pick: int | None,
                         threads: int) -> list[tuple[np.ndarray, ...]]:
        """:meth:`_finish` chunks of a recurrent model: features per chunk, the GRU per sequence batch."""
        n = len(x)
        assert isinstance(self.kernel, GRUKernel)
        feats = map_ordered(lambda start: self._features_of(x[start:start + CHUNK], start), range(0, n, CHUNK),
                            threads)
        g, rest = (np.concatenate(c) for c in zip(*feats, strict=True))
        mu = self.kernel.sequences(g, [np.arange(n)] if sequences is None else list(sequences), threads)
        rows = np.arange(n) if pick is None else np.arange(pick - 1, n, pick)
        g, mu, rest = g[rows], mu[rows], rest[rows]
        return map_ordered(lambda s: self._finish(g[s:s + CHUNK], rest[s:s + CHUNK], mu[s:s + CHUNK], None,
                                                  self._pi1_rows(s, s + CHUNK), spread),
                           range(0, len(rows), CHUNK), threads)

    def _pi1_rows(self, start: int, stop: int) -> float | np.ndarray:
        """π1 of the source for target rows ``start:stop`` (one shared value or one per row)."""
        return self._pi1_source if self._n_source == 1 else self._pi1_source[start:stop]

    def _features_of(self, x: np.ndarray, start: int) -> tuple[np.ndarray, np.ndarray]:
        """(features, rest of π1) of target rows ``x`` (rows ``start``… of the batch); the features are the k
        distortions g, followed by the k source features for an ``include_source`` model (:class:`Features`)."""
        vals = self._plan_t.values(x)
        bad = ~np.all(np.isfinite(vals), axis=1)
        if bad.any():
            raise InputError(f"target: {int(bad.sum())} rows give a non-finite group (first row "
                             f"{start + int(np.argmax(bad))}; a divisor such as F31 or y_b is 0)")
        feats = self._features if self._n_source == 1 else self._features.rows(start, start + len(x))
        return feats(vals[:, :-1]), (vals[:, -1] if self._has_rest else np.ones(len(x)))

    def _finish(self, g: np.ndarray, rest: np.ndarray, mu: np.ndarray, var: np.ndarray | None,
                pi1: float | np.ndarray, spread: tuple[float, float, float]) -> tuple[np.ndarray, ...]:
        """(force, lower, upper, δ1, outside, g of the rows outside, σ of ln δ1 (ones without a variance)) from
        ln δ1 ``mu`` (and its variance)."""
        _, a, b = spread
        if var is not None:
            half = a * np.sqrt(var)
            lo_log, hi_log = mu - half, mu + half
        else:
            lo_log, hi_log = mu + a, mu + b
        delta = np.exp(mu)
        force = self._recover(pi1, delta, rest)
        f_a, f_b = self._recover(pi1, np.exp(lo_log), rest), self._recover(pi1, np.exp(hi_log), rest)
        outside = ((g < self._g_lo) | (g > self._g_hi)).any(axis=1)
        sigma = np.sqrt(var) if var is not None else np.ones(len(mu))
        return force, np.minimum(f_a, f_b), np.maximum(f_a, f_b), delta, outside, g[outside], sigma

    # ------------------------------------------------------------------------------------------------ one row

    def predict_row(self, x: Sequence[float], source: Sequence[float] | None = None) -> tuple[float, float, float]:
        """(force, lower, upper) for one target row given as SI floats in :attr:`target_variables` order.

        The lean path for a live loop: no pandas and no unit handling. Feed-forward models only (use
        :meth:`stream` for recurrent ones, which carries the hidden state). ``source``: this row's own source row
        as SI floats in :attr:`source_variables` order (e.g. its matched row for an ``include_source`` model);
        default the bound source (one row).

        Raises:
            InputError: the row gives a non-finite result (NaN input, a zero divisor).
            TypeError: a recurrent model.
        """
        if self.recurrent:
            raise TypeError(f"{self.name} is recurrent: use model.stream() to carry its hidden state row to row")
        return self.row(x, None, source)[:3]

    def row(self, x: Sequence[float], state: Any,
            source: Sequence[float] | None = None) -> tuple[float, float, float, float, bool, Any]:
        """(force, lower, upper, δ1, extrapolated, next state) for one SI row; ``state`` is the GRU hidden state
        (``None`` for feed-forward models), ``source`` this row's own source row (SI floats in
        :attr:`source_variables` order; default the bound source, which must then be one row). Used by
        :meth:`predict_row` and :class:`~zoo.serving.stream.Stream`. A ``learned-scale`` checkpoint gives its
        pooled residual interval here (the per-row width needs a nearest-neighbour query: batch path)."""
        if source is not None:
            features, pi1 = self._row_source(source)
        elif self._n_source != 1:
            raise InputError("row by row serving needs a single source row (bind one with model.bind, or pass the "
                             "row's own source)")
        else:
            features, pi1 = self._features, self._pi1_source
        try:
            vals = self._plan_t.row(x)
        except ZeroDivisionError:
            raise InputError("target row: a divisor (e.g. F31 or y_b) is 0") from None
        rest = vals[-1] if self._has_rest else 1.0
        pi_t = np.array(vals[:-1])
        kernel = self.kernel
        var = 0.0
        if source is None and self._bound_row is not None:  # the bound source folded into the first layer
            mu, outside = self._bound_row(pi_t)
            if outside:
                self._warn(features(pi_t)[None], 1, 1)
        else:
            g = features(pi_t)
            if isinstance(kernel, GRUKernel):
                mu, state = kernel.step(g, kernel.initial_state() if state is None else state)
            elif isinstance(kernel, EnsembleKernel):
                mu, var = kernel.row(g)
            else:
                mu = kernel.row(g)
            outside = bool((g < self._g_lo).any() or (g > self._g_hi).any())
            if outside:
                self._warn(g[None], 1, 1)
        _, a, b = self._row_spread
        if isinstance(kernel, EnsembleKernel):
            half = a * math.sqrt(var)
            lo_log, hi_log = mu - half, mu + half
        else:
            lo_log, hi_log = mu + a, mu + b
        ie = self._inv_exp
        try:
            force = float((pi1 / math.exp(mu) / rest) ** ie)
            a, b = float((pi1 / math.exp(lo_log) / rest) ** ie), float((pi1 / math.exp(hi_log) / rest) ** ie)
        except (ZeroDivisionError, TypeError, OverflowError):
            force = a = b = math.nan
        if not math.isfinite(force):
            raise InputError(f"target row {list(x)}: non-finite {self.variable} (NaN or inf input?)")
        return force, min(a, b), max(a, b), math.exp(mu), outside, state

    # ------------------------------------------------------------------------------------------------ streaming

    def stream(self, *, on_prediction: Callable[[Prediction], Any] | None = None, rerun: Any = None) -> Stream:
        """A :class:`~zoo.serving.stream.Stream` over this model (push rows one at a time)."""
        return Stream(self, on_prediction=on_prediction, rerun=rerun)

    def predict_stream(self, rows: Iterable[Any], **kwargs: Any) -> Iterator[Prediction]:
        """Generator: one :class:`~zoo.serving.stream.Prediction` per row of ``rows`` (state carried)."""
        with self.stream(**kwargs) as s:
            for r in rows:
                yield s.push(r)

    # ------------------------------------------------------------------------------------------------ helpers

    def _recover(self, pi1: float | np.ndarray, delta: np.ndarray, rest: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            base = pi1 / delta / rest
            return base if self._inv_exp == 1.0 else np.power(base, self._inv_exp)

    def _spread(self, coverage: float | None) -> tuple[float, float, float]:
        """(coverage, z, 0) for the ensemble's normal interval, or (coverage, q_lo, q_hi) residual quantiles."""
        cov = self.coverage if coverage is None else float(coverage)
        if not 0 < cov < 1:
            raise InputError(f"coverage must be in (0, 1), got {cov}")
        if self.interval_method == "ensemble":
            return cov, normal_quantile(cov), 0.0
        if cov not in self._quantiles:
            raise InputError(f"{self.name}: residual intervals are stored at coverage {sorted(self._quantiles)}, "
                             f"not {cov}")
        return cov, *self._quantiles[cov]

    def _warn(self, g_out: np.ndarray, n_out: int, n: int) -> None:
        below, above = (g_out < self._g_lo).any(axis=0), (g_out > self._g_hi).any(axis=0)
        groups = [f"{name} ({'below' if lo else ''}{'/' if lo and hi else ''}{'above' if hi else ''})"
                  for name, lo, hi in zip(self._feature_names, below, above, strict=True) if lo or hi]
        warnings.warn(f"{self.name}: {n_out} of {n} target rows have distortions outside the training range "
                      f"(groups {', '.join(groups)}); the scaled {self.variable} is extrapolated",
                      ExtrapolationWarning, stacklevel=4)

    def _sequences(self, target: Rows, n: int) -> list[np.ndarray] | None:
        """One index array per ``episode`` of a target frame, in ``t`` (or ``time``) order; None: one sequence."""
        if not isinstance(target, pd.DataFrame):
            return None
        cols = {split_header(c)[0]: c for c in target.columns}
        if "episode" not in cols:
            return None
        time_col = cols.get("t", cols.get("time"))
        frame = pd.DataFrame({"episode": target[cols["episode"]].to_numpy(), "i": np.arange(n),
                              "t": target[time_col].to_numpy(float) if time_col is not None else np.arange(n)})
        return [part.sort_values("t", kind="stable")["i"].to_numpy() for _, part in frame.groupby("episode")]

    def __repr__(self) -> str:
        return f"ScalingModel({self.name!r}, {self.model.name}, interval={self.interval_method})"

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return load, (self.ref,)
