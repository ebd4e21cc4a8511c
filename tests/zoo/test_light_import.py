"""What serving loads: ``zoo.serving`` and ``zoo.load("ffnn-eq10")`` stay off MuJoCo, matplotlib and the
simulator-facing side of :mod:`scaling` (checked in a fresh interpreter, since this test process has imported
everything)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

#: Prints the loaded modules after ``import zoo.serving.model``, then after loading a served checkpoint.
CHECK = """
import json, sys
import zoo.serving.model
served = sorted(sys.modules)
import zoo
zoo.load("ffnn-eq10")
print(json.dumps({"import zoo.serving.model": served, "zoo.load('ffnn-eq10')": sorted(sys.modules)}))
"""
#: Modules of :mod:`scaling` that build on the simulator or plot (validation, data generation, pipeline, figures).
HEAVY_SCALING = ("scaling.evaluation.miniature", "scaling.runs.plots", "scaling.data.recordings", "scaling.data.holds",
                 "scaling.runs.pipeline")


@pytest.fixture(scope="module")
def loaded() -> dict[str, list[str]]:
    out = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2], timeout=300)
    return json.loads(out.stdout.strip().splitlines()[-1])


def tops(modules: list[str], names: tuple[str, ...]) -> list[str]:
    return sorted({m.split(".")[0] for m in modules} & set(names))


def test_serving_loads_no_plotting_and_no_simulator_side_of_scaling(loaded: dict[str, list[str]]) -> None:
    for step, modules in loaded.items():
        assert tops(modules, ("matplotlib",)) == [], step
        assert sorted(set(modules) & set(HEAVY_SCALING)) == [], step


def test_serving_loads_no_simulator(loaded: dict[str, list[str]]) -> None:
    """MuJoCo stays out: units come from :mod:`scaletwin_envs.signal_units` and the recording modules that build
    or replay the simulator load on first use. (gymnasium is imported: ``import scaletwin_envs`` registers the env,
    a registry entry that costs no simulator.)"""
    for step, modules in loaded.items():
        assert tops(modules, ("mujoco",)) == [], step
