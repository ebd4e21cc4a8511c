"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def scale_arg(text: str) -> float | str:
    """A preset name or a float length ratio (validated by the env, which lists what is accepted)."""
    try:
        return float(text)
    except ValueError:
        return text


def add_machine_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scale", type=scale_arg, default="er12",
                   help="preset (mini, er12, wa475) or length ratio vs the ER12 in [0.05, 3] (default er12)")
    p.add_argument("--law", default="product_line", choices=("product_line", "froude"),
                   help="scaling law for float scales (default product_line)")
    p.add_argument("--soil", default="gravel", help="gravel, sand, sandy_loam or clay_loam (default gravel)")
    p.add_argument("--seed", type=int, default=0, help="reset seed (default 0)")


def write_json(path: str | Path, payload: Any) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True, default=str))
    tmp.replace(path)
