"""The JSON report validates against its schema; Markdown, plots and the rerun file are written."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import jsonschema
import pytest

from discrepancy import Effect, ReportedEffect
from discrepancy.effects import UNEXPLAINED
from discrepancy.pipeline import _unexplained
from discrepancy.report.document import markdown, text_report, to_json, warnings, write_json, write_markdown
from discrepancy.report.rerun_out import write_rrd
from discrepancy.report.schema import SchemaError, report_schema, validate
from discrepancy.search.fit import NORMALISER_NEAR_ZERO, WORSE, Comparison, entry_flags
from discrepancy.search.identify import Identification, Round
from discrepancy.search.screen import Trial
from discrepancy.stats.locate import Located

from .test_identify import CLEAR


@pytest.fixture(scope="module")
def diagnosis(scales, diagnosed):
    target, pis, candidates = CLEAR["sensor_bias"]
    return diagnosed([Effect.from_pi("sensor_bias", target, pis, scales)], candidates)


def test_json_validates(diagnosis, tmp_path) -> None:
    doc = to_json(diagnosis)
    validate(doc)
    assert set(doc) == {"located", "effects", "fit", "alignment"}  # an in-memory recording: no "input" section
    assert doc["alignment"]["start"] is None and doc["alignment"]["offset_applied"] is False  # it has its seed
    assert set(doc["effects"][0]) == {"effect", "target", "parameters", "interval", "units", "confidence",
                                      "explained_fraction", "confounded_with", "alternatives", "separated_by"}
    assert set(doc["fit"]) == {"held_out", "before", "after", "by_phase", "normaliser", "scale", "flags",
                               "phase_flags", "worse_overall"}
    effect = doc["effects"][0]
    assert 0.0 <= effect["confidence"] <= 1.0 and 0.0 < effect["explained_fraction"] <= 1.0
    assert effect["units"] == {"bias": "N"} and effect["alternatives"] == []
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


BREAKAGES = {  # what is broken → the JSON path the error names
    "missing": "$", "extra": "$.effects[0]", "type": "$.located[0].t_start", "enum": "$.effects[0].effect",
    "range": "$.located[0].p_value", "confidence_on_unexplained": "$.effects[0].confidence",
    "flag": "$.fit.flags.x_b[0]", "nan": "NaN",
}


@pytest.mark.parametrize("breakage", list(BREAKAGES))
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
    elif breakage == "range":
        doc["located"][0]["p_value"] = 1.5
    elif breakage == "confidence_on_unexplained":  # a number on `unexplained`: "confidence" means one thing
        doc["effects"][0]["effect"] = UNEXPLAINED
    elif breakage == "flag":
        doc["fit"]["flags"] = {"x_b": ["dubious"]}
    else:
        doc["located"][0]["t_start"] = float("nan")
    with pytest.raises(SchemaError) as err:
        validate(doc)
    assert BREAKAGES[breakage] in str(err.value)


def test_schema_is_checked_by_jsonschema() -> None:
    """The schema is a valid Draft 2020-12 schema, and a keyword the old hand-written validator ignored (``if``/
    ``then``) is enforced; the error message is jsonschema's."""
    schema = report_schema()
    assert jsonschema.validators.validator_for(schema) is jsonschema.Draft202012Validator
    jsonschema.Draft202012Validator.check_schema(schema)
    doc = {"located": [], "effects": [{"effect": UNEXPLAINED, "target": None, "parameters": {}, "interval": {},
                                       "units": {}, "confidence": 0.4, "explained_fraction": 0.6,
                                       "confounded_with": [], "alternatives": []}],
           "fit": {"held_out": False, "before": {}, "after": {}, "by_phase": {}, "normaliser": {}, "scale": {},
                   "flags": {}, "phase_flags": {}, "worse_overall": False}}
    with pytest.raises(SchemaError, match=r"0\.4 is not of type 'null'"):
        validate(doc)
    doc["effects"][0]["confidence"] = None
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


LONG = ["coulomb_friction[lift_barrel_hinge]", "viscous_damping[tilt_barrel_hinge]", "coulomb_friction[lift_cylinder]",
        "viscous_damping[bell_crank_hinge]", "coulomb_friction[tilt_cylinder]"]


def _named() -> ReportedEffect:
    return ReportedEffect("coulomb_friction", "lift_barrel_hinge", {"friction": 1234.5}, {"friction": (1100.0, 1400.0)},
                          {"pi_friction": 0.0125}, 0.97, LONG[1:4], explained_fraction=0.93,
                          alternatives=["coulomb_friction[lift_cylinder] (separated by p_lift if recorded)"])


def _unexplained_row() -> ReportedEffect:
    """``unexplained`` as the pipeline builds it: the closest candidate removed 40 % of the excess."""
    closest = Effect.make("viscous_damping", "bell_crank_hinge", {"damping": 50.0})
    rnd = Round(base_cost=100.0, trials=[], winner=Trial(closest, 60.0), confounded=LONG[:2], confidence=0.9,
                gain_fraction=0.4)
    ident = Identification(effects=[], rounds=[rnd], unexplained=True)
    found = SimpleNamespace(located=[Located("F31", "curl", 1.0, 2.0, 0.5, 1e-4), Located("F21", "curl", 1.0, 2.0,
                                                                                           0.9, 1e-5)])
    return _unexplained(ident, found)


def test_unexplained_has_no_confidence_but_an_explained_fraction(diagnosis) -> None:
    row = _unexplained_row()
    assert row.effect == UNEXPLAINED and row.target == "F21"
    assert row.confidence is None and row.explained_fraction == pytest.approx(0.4)
    d = dataclasses.replace(diagnosis, effects=[_named(), row])
    doc = to_json(d)
    assert doc["effects"][1]["confidence"] is None and doc["effects"][1]["explained_fraction"] == pytest.approx(0.4)
    assert doc["effects"][0]["confidence"] == pytest.approx(0.97)
    assert doc["effects"][0]["explained_fraction"] == pytest.approx(0.93)
    block = text_report(d, width=80).split("2. unexplained")[1]
    assert "confidence —" in block and "explained fraction 0.40" in block
    assert "confidence —" in markdown(d).split("unexplained, shows most on F21")[1]


def test_text_and_markdown_show_full_targets_intervals_and_units(diagnosis) -> None:
    """No name is cut at 80 columns: every rival's and alternative's full label is on one line."""
    d = dataclasses.replace(diagnosis, effects=[_named(), _unexplained_row()])
    text = text_report(d, width=80)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80
    for label in LONG[:4]:
        assert any(label in line for line in lines), label
    assert "coulomb_friction[lift_cylinder] (separated by p_lift if recorded)" in " ".join(text.split())
    assert "1. coulomb_friction on lift_barrel_hinge" in text
    assert "friction = 1234 N*m, 95 % interval [1100, 1400]" in text
    assert "cannot be told apart from: coulomb_friction[lift_cylinder]" in text
    md = markdown(d)
    for label in LONG[:4]:
        assert label in md
    assert "friction = 1234 N*m, 95 % interval [1100, 1400]" in md
    assert doc_alternatives(d) == [_named().alternatives, []]


def doc_alternatives(d) -> list[list[str]]:
    return [e["alternatives"] for e in to_json(d)["effects"]]


def _comparison(f21_after: float) -> Comparison:
    """x_b: 1.80 → 1879 dividing by a spread of 0.1 mm on a 2 m signal (the reported case); F21 improves or not."""
    return Comparison(before={"x_b": 1.80, "F21": 0.5, "p_lift": 0.3},
                      after={"x_b": 1879.0, "F21": f21_after, "p_lift": 0.3001},
                      by_phase={"F21": {"curl": (0.2, 0.9), "lift": (0.4, 0.1)}}, held_out=True,
                      normaliser={"x_b": 1e-4, "F21": 1e4, "p_lift": 1e6},
                      phase_normaliser={"F21": {"curl": 1e4, "lift": 1e4}},
                      scale={"x_b": 2.0, "F21": 3e4, "p_lift": 5e6})


def test_entry_flags() -> None:
    assert entry_flags(0.5, 0.1) == [] and entry_flags(0.3, 0.3001) == []  # better, or noise-level change
    assert entry_flags(0.5, 0.6) == [WORSE]
    assert entry_flags(0.5, float("inf")) == [WORSE]
    assert entry_flags(1.8, 1.0, normaliser=1e-4, scale=2.0) == [NORMALISER_NEAR_ZERO]
    assert entry_flags(1.8, 1.0, normaliser=0.5, scale=2.0) == []


def test_worse_held_out_comparison_is_flagged(diagnosis) -> None:
    c = _comparison(f21_after=0.1)  # F21 improved; x_b blew up on a near-zero normaliser
    assert c.flagged == {"x_b": [WORSE, NORMALISER_NEAR_ZERO]}
    assert c.phase_flagged == {"F21": {"curl": [WORSE]}}
    assert c.worse == ["x_b"] and not c.worse_overall  # 1879 × 0.1 mm is small against the improvement of F21
    d = dataclasses.replace(diagnosis, effects=[_named()], comparison=c)
    doc = to_json(d)
    assert doc["fit"]["flags"] == {"x_b": ["worse", "normaliser near zero"]} and not doc["fit"]["worse_overall"]
    assert warnings(d)[0].startswith("Note: 1 signal(s) fit worse") and "x_b 1.8 → 1879" in warnings(d)[0]
    assert "x_b 1.8 → 1879 (worse, normaliser near zero)" in text_report(d, width=200)
    assert "F21 in curl 0.2 → 0.9 (worse)" in text_report(d, width=200)
    assert "| x_b | 1.8 | 1879 | worse, normaliser near zero |" in markdown(d)

    worse = dataclasses.replace(d, comparison=_comparison(f21_after=1.5))  # F21 worse too: worse overall
    assert worse.comparison.worse_overall and to_json(worse)["fit"]["worse_overall"]
    text, md = text_report(worse, width=200), markdown(worse)
    assert text.index("WARNING: the correction made the fit worse") < text.index("1. coulomb_friction")
    assert md.index("WARNING: the correction made the fit worse") < md.index("### 1. coulomb_friction")

    fine = dataclasses.replace(d, comparison=Comparison(before={"F21": 0.5}, after={"F21": 0.1}, held_out=True))
    assert warnings(fine) == [] and to_json(fine)["fit"]["flags"] == {}


def test_compare_records_normalisers(diagnosis) -> None:
    """The pipeline's comparison carries a normaliser and a scale per signal, and the planted bias, once
    corrected, does not make the fit worse."""
    c = diagnosis.comparison
    assert set(c.normaliser) == set(c.scale) == set(c.before) == set(diagnosis.names)
    assert all(v > 0 for v in c.normaliser.values())
    assert not c.worse_overall and "F31" not in c.worse
    assert c.residual(True) < c.residual(False)


def test_a_residual_put_down_to_drift_is_said_so(diagnosis) -> None:
    """Where the identification puts what was located down to the sensors' drift (``Identification.drift``), the
    terminal summary, the Markdown report and the JSON document (``drift``, validated) say so and name the
    channels; without it the document has no ``drift`` key and the summary puts faint windows down to chance."""
    ident = dataclasses.replace(diagnosis.identification, effects=[], unexplained=False, drift=("F31", "F31_x"))
    drifted = dataclasses.replace(diagnosis, effects=[], identification=ident)
    assert drifted.located  # something was located, and nothing is named
    for text in (text_report(drifted, width=200), markdown(drifted)):
        assert "put down to those sensors' drift" in text and "F31, F31_x" in text
    doc = to_json(drifted)
    assert doc["drift"] == ["F31", "F31_x"]
    quiet = dataclasses.replace(drifted, identification=dataclasses.replace(ident, drift=()))
    assert "drift" not in to_json(quiet) and "put down to chance" in text_report(quiet, width=200)
