"""Building the zoo through the pipeline: entries, specs and (slow) a deterministic rebuild from scratch."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

import zoo
from scaling.runs.reproduce import QUICK
from zoo.build import ENTRIES, FFNN_GRID_BEST, BuildConfig, build_zoo, entries, zoo_specs


def test_entries_and_specs():
    assert [e.name for e in entries()] == ["ffnn-eq10", "gru-eq10", "gru-eq23", "ffnn-pose", "ensemble-eq10"]
    with pytest.raises(ValueError, match="unknown zoo entries"):
        entries(["nope"])
    specs = {s.name: s for s in zoo_specs(ENTRIES, FFNN_GRID_BEST)}
    assert specs["ffnn"].cls == "FFNN" and specs["ffnn"].groups == "eq10"
    assert all(specs["ffnn"].config[k] == v for k, v in FFNN_GRID_BEST.items())
    assert specs["gru-eq23"].groups == "eq23" and specs["deep-ensemble"].cls == "DeepEnsemble"
    assert specs["ffnn-pose"].groups == "eq10+pose" and specs["ffnn-pose"].config["units"] == 64


@pytest.mark.slow
def test_build_from_scratch_is_deterministic(tmp_path: Path):
    """Simulate a tiny data set, build the FFNN twice: identical weights, a complete card, a loadable model."""
    cfg = BuildConfig(data_dir=tmp_path / "data", names=("ffnn-eq10",), train=QUICK.train, held_out=QUICK.held_out,
                      out_root=tmp_path / "a", registry=tmp_path / "registry.json", executor="serial",
                      progress=False, ffnn={**FFNN_GRID_BEST, "epochs": 30})
    first = build_zoo(cfg)["ffnn-eq10"]
    second = build_zoo(replace(cfg, out_root=tmp_path / "b"))["ffnn-eq10"]
    card_a, card_b = zoo.card(first), zoo.card(second)
    assert card_a["files"]["weights.safetensors"] == card_b["files"]["weights.safetensors"]
    assert card_a["metrics"]["mini"] == card_b["metrics"]["mini"]
    assert card_a["training"]["data_hashes"] == card_b["training"]["data_hashes"]
    model = zoo.load("ffnn-eq10", registry=tmp_path / "registry.json")
    assert isinstance(model, zoo.ScalingModel) and model.card == card_b
