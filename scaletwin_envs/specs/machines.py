"""A loader by name, by size or from a spec: the presets, a length ratio λ on a scaling law, and distortions on top.

The one place that knows both the spec types (:mod:`scaletwin_envs.specs.loader`) and the presets built from them
(:mod:`scaletwin_envs.specs.presets`), so neither imports the other back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from scaletwin_envs.specs.laws import DISTORTION_KEYS, PRODUCT_LINE, ScalingLaw, make_law
from scaletwin_envs.specs.loader import SCALE_RANGE, LoaderSpec, scale_spec
from scaletwin_envs.specs.presets import PRESETS


def make_loader(scale: float | str | LoaderSpec = 1.0, law: str | ScalingLaw = PRODUCT_LINE,
                distortion: Mapping[str, float] | None = None) -> LoaderSpec:
    """A loader from a preset name, a :class:`LoaderSpec`, or a length ratio λ relative to the ER12.

    Args:
        scale: ``"mini"``, ``"er12"``, ``"wa475"``, a LoaderSpec, or a float in [0.05, 3.0].
        law: ``"product_line"`` (default, how real lines scale) or ``"froude"`` (exact similarity); floats only.
        distortion: extra factors on top of the law, keys in ``DISTORTION_KEYS``; floats only.
    """
    distortion = dict(distortion or {})
    bad = sorted(set(distortion) - set(DISTORTION_KEYS))
    if bad:
        raise ValueError(f"unknown distortion keys {bad}; accepted: {list(DISTORTION_KEYS)}")
    for k, v in distortion.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"distortion[{k!r}] must be a finite number > 0, got {v!r}")
    if isinstance(scale, LoaderSpec):
        return _distort(scale, distortion)
    if isinstance(scale, str):
        if scale not in PRESETS:
            raise ValueError(f"scale must be a preset name {sorted(PRESETS)}, a LoaderSpec or a float, got {scale!r}")
        return _distort(PRESETS[scale], distortion)
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise ValueError(f"scale must be a preset name {sorted(PRESETS)}, a LoaderSpec or a float, got {scale!r}")
    lo, hi = SCALE_RANGE
    if not (math.isfinite(scale) and lo <= scale <= hi):
        raise ValueError(f"scale must be a finite length ratio in [{lo}, {hi}] (relative to the ER12), got {scale}")
    law = make_law(law)
    f = law.factors(float(scale))
    for k, v in distortion.items():
        f[k] *= v
    tag = f"{law.name}(scale={scale:g}" + "".join(f", {k}={v:g}" for k, v in sorted(distortion.items())) + ")"
    return scale_spec(PRESETS["er12"], f, tag, float(scale))


def _distort(spec: LoaderSpec, distortion: Mapping[str, float]) -> LoaderSpec:
    if not distortion:
        return spec
    f = {k: 1.0 for k in ("length", *DISTORTION_KEYS)}
    f.update(distortion)
    name = spec.name + "+" + ",".join(f"{k}={v:g}" for k, v in sorted(distortion.items()))
    return scale_spec(spec, f, name, spec.scale)


def preset_names() -> list[str]:
    return sorted(PRESETS)
