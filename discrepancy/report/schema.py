"""A small JSON Schema validator for the subset the report schema uses (no dependency on ``jsonschema``).

Supported keywords: ``type`` (one or a list), ``enum``, ``properties``, ``required``, ``additionalProperties``
(boolean or schema), ``items``, ``minItems``, ``maxItems``, ``minimum``, ``maximum``. Unknown keywords are
ignored, as JSON Schema prescribes for annotations.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

SCHEMA_PATH = Path(__file__).with_name("schemas") / "report.schema.json"
_TYPES = {
    "object": lambda v: isinstance(v, dict), "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str), "null": lambda v: v is None,
    "boolean": lambda v: isinstance(v, bool),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v),
}


class SchemaError(ValueError):
    """A document that does not follow the schema; the message lists every violation with its path."""


@lru_cache(maxsize=1)
def report_schema() -> dict[str, Any]:
    """The diagnosis report's schema (``discrepancy/report/schemas/report.schema.json``)."""
    return json.loads(SCHEMA_PATH.read_text())


def errors(doc: Any, schema: dict[str, Any], path: str = "$") -> list[str]:
    """Every violation of ``schema`` by ``doc`` (empty when valid)."""
    out: list[str] = []
    kinds = schema.get("type")
    if kinds is not None:
        kinds = [kinds] if isinstance(kinds, str) else kinds
        if not any(_TYPES[k](doc) for k in kinds):
            return [f"{path}: expected {' or '.join(kinds)}, got {type(doc).__name__} {doc!r:.60}"]
    if "enum" in schema and doc not in schema["enum"]:
        out.append(f"{path}: {doc!r} is not one of {schema['enum']}")
    if isinstance(doc, int | float) and not isinstance(doc, bool):
        if "minimum" in schema and doc < schema["minimum"]:
            out.append(f"{path}: {doc} < minimum {schema['minimum']}")
        if "maximum" in schema and doc > schema["maximum"]:
            out.append(f"{path}: {doc} > maximum {schema['maximum']}")
    if isinstance(doc, dict):
        out += _object(doc, schema, path)
    if isinstance(doc, list):
        out += _array(doc, schema, path)
    return out


def _object(doc: dict[str, Any], schema: dict[str, Any], path: str) -> list[str]:
    out = [f"{path}: missing required key {k!r}" for k in schema.get("required", []) if k not in doc]
    props = schema.get("properties", {})
    extra = schema.get("additionalProperties", True)
    for key, value in doc.items():
        if key in props:
            out += errors(value, props[key], f"{path}.{key}")
        elif extra is False:
            out.append(f"{path}: unexpected key {key!r}")
        elif isinstance(extra, dict):
            out += errors(value, extra, f"{path}.{key}")
    return out


def _array(doc: list[Any], schema: dict[str, Any], path: str) -> list[str]:
    out = []
    if "minItems" in schema and len(doc) < schema["minItems"]:
        out.append(f"{path}: {len(doc)} items < minItems {schema['minItems']}")
    if "maxItems" in schema and len(doc) > schema["maxItems"]:
        out.append(f"{path}: {len(doc)} items > maxItems {schema['maxItems']}")
    if "items" in schema:
        for i, item in enumerate(doc):
            out += errors(item, schema["items"], f"{path}[{i}]")
    return out


def validate(doc: Any, schema: dict[str, Any] | None = None) -> None:
    """Raise :class:`SchemaError` listing every violation (the report schema by default)."""
    problems = errors(doc, schema or report_schema())
    if problems:
        raise SchemaError("report does not follow its schema:\n  " + "\n  ".join(problems))
