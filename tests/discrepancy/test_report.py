"""The JSON report validates against its schema; Markdown, plots and the rerun file are written."""

from __future__ import annotations

import json

import pytest

from discrepancy import Effect
from discrepancy.report.document import to_json, write_json, write_markdown
from discrepancy.report.rerun_out import write_rrd
from discrepancy.report.schema import SchemaError, report_schema, validate

from .test_identify import CLEAR


@pytest.fixture(scope="module")
def diagnosis(scales, diagnosed):
    target, pis, candidates = CLEAR["sensor_bias"]
    return diagnosed([Effect.from_pi("sensor_bias", target, pis, scales)], candidates)


def test_json_validates(diagnosis, tmp_path) -> None:
    doc = to_json(diagnosis)
    validate(doc)
    assert set(doc) == {"located", "effects", "fit"}
    assert set(doc["effects"][0]) == {"effect", "target", "parameters", "interval", "confidence", "confounded_with"}
    assert doc["located"] and set(doc["located"][0]) == {"signal", "phase", "t_start", "t_end", "effect_size",
                                                         "p_value"}
    assert "pi_bias" in doc["effects"][0]["parameters"]
    path = write_json(diagnosis, tmp_path / "d.json")
    validate(json.loads(path.read_text()))


def test_json_values_are_the_planted_effect(diagnosis, scales) -> None:
    """The document's parameter and its group bracket the planted bias (SI and Π) inside their intervals."""
    target, pis, _ = CLEAR["sensor_bias"]
    planted = Effect.from_pi("sensor_bias", target, pis, scales).params["bias"]
    effect = to_json(diagnosis)["effects"][0]
    assert (effect["effect"], effect["target"]) == ("sensor_bias", target)
    params, interval = effect["parameters"], effect["interval"]
    assert params["bias"] == pytest.approx(planted, rel=0.05)
    assert params["pi_bias"] == pytest.approx(pis["bias"], rel=0.05)
    for key, truth in (("bias", planted), ("pi_bias", pis["bias"])):
        lo, hi = interval[key]
        assert lo < params[key] < hi and lo <= truth <= hi, (key, params[key], truth, (lo, hi))
    # the Π interval is the SI interval over the same unit
    unit = params["bias"] / params["pi_bias"]
    assert interval["pi_bias"] == pytest.approx([interval["bias"][0] / unit, interval["bias"][1] / unit])


@pytest.mark.parametrize("breakage", ["missing", "extra", "type", "enum", "range"])
def test_schema_rejects_bad_documents(diagnosis, breakage: str) -> None:
    doc = to_json(diagnosis)
    if breakage == "missing":
        del doc["fit"]
    elif breakage == "extra":
        doc["effects"][0]["note"] = "x"
    elif breakage == "type":
        doc["located"][0]["t_start"] = "soon"
    elif breakage == "enum":
        doc["effects"][0]["effect"] = "gremlins"
    else:
        doc["located"][0]["p_value"] = 1.5
    with pytest.raises(SchemaError):
        validate(doc)


def test_schema_file_lists_the_catalogue() -> None:
    names = report_schema()["properties"]["effects"]["items"]["properties"]["effect"]["enum"]
    assert len(names) == 13 and "unexplained" in names


def test_markdown_and_rerun(diagnosis, tmp_path) -> None:
    md = write_markdown(diagnosis, tmp_path / "report.md")
    text = md.read_text()
    assert "sensor_bias" in text and "Linkage redundancy" in text and "_traces.png" in text
    assert (tmp_path / "report_traces.png").stat().st_size > 0
    rrd = write_rrd(diagnosis, tmp_path / "d.rrd")
    assert rrd.stat().st_size > 0
