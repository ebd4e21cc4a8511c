"""Gymnasium ``Box`` spaces to and from JSON (the only space kind the zoo's policies use)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from zoo.errors import CheckpointError

_DTYPES = ("float32", "float64")


def space_to_json(space: spaces.Space, names: list[str] | tuple[str, ...] | None = None) -> dict[str, Any]:
    """A ``Box`` as JSON: shape, dtype, element-wise bounds and optional element names."""
    if not isinstance(space, spaces.Box):
        raise TypeError(f"only Box spaces can be stored, got {type(space).__name__}")
    out = {"type": "Box", "shape": list(space.shape), "dtype": str(space.dtype),
           "low": space.low.ravel().tolist(), "high": space.high.ravel().tolist()}
    if names is not None:
        out["names"] = list(names)
    return out


def space_from_json(data: Any, what: str) -> spaces.Box:
    """The inverse of :func:`space_to_json`; :class:`CheckpointError` if the JSON is not a valid Box."""
    try:
        if data["type"] != "Box" or data["dtype"] not in _DTYPES:
            raise ValueError(f"unsupported space {data['type']!r} / dtype {data['dtype']!r}")
        shape = tuple(int(n) for n in data["shape"])
        low = np.asarray(data["low"], dtype=data["dtype"]).reshape(shape)
        high = np.asarray(data["high"], dtype=data["dtype"]).reshape(shape)
        return spaces.Box(low=low, high=high, shape=shape, dtype=np.dtype(data["dtype"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"malformed card: bad {what} ({exc})") from exc
