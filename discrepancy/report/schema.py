"""Validation of the report document against ``schemas/report.schema.json`` with the ``jsonschema`` library.

The validator class is the one the schema declares in ``$schema`` (Draft 2020-12). JSON has no NaN or infinity,
so a document holding one is refused as well, before the schema is applied.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import jsonschema

SCHEMA_PATH = Path(__file__).with_name("schemas") / "report.schema.json"


class SchemaError(ValueError):
    """A document that does not follow the schema; the message lists every violation with its JSON path."""


@lru_cache(maxsize=1)
def report_schema() -> dict[str, Any]:
    """The diagnosis report's schema (``discrepancy/report/schemas/report.schema.json``)."""
    return json.loads(SCHEMA_PATH.read_text())


@lru_cache(maxsize=1)
def _validator() -> jsonschema.protocols.Validator:
    schema = report_schema()
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)  # a broken schema file is a bug here, not a bad document
    return cls(schema)


def validate(doc: Any) -> None:
    """Check ``doc`` against the report schema.

    Raises:
        SchemaError: listing every violation as ``<JSON path>: <message>``; or a value JSON cannot hold (NaN,
            infinity, a non-JSON type).
    """
    try:
        json.dumps(doc, allow_nan=False)
    except (TypeError, ValueError) as exc:  # NaN/infinity, or an object JSON cannot hold
        raise SchemaError(f"report is not a JSON document ({exc}): it holds NaN, infinity or a non-JSON value"
                          ) from None
    problems = sorted(_validator().iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path])
    if problems:
        lines = [f"{e.json_path}: {e.message}" for e in problems]
        raise SchemaError("report does not follow its schema:\n  " + "\n  ".join(lines))
