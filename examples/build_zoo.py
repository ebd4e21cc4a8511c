"""Rebuild every δ1 checkpoint of the zoo from scratch: simulate the data (or reuse it), fit through the public
scaling pipeline, evaluate on held-out data, write the cards and update ``zoo/registry.json``.

    python examples/build_zoo.py [--data runs/zoo-data] [--only ffnn-eq10 ...] [--seed 0] [--workers 2]

Same data and seed give the same weights (one torch thread, seeded fits). This is ``scaletwin zoo build``.
"""

from __future__ import annotations

import sys

from scaletwin.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["zoo", "build", *sys.argv[1:]]))
