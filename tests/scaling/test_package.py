"""The package's public face (``scaling.__all__``): each name is taken from the module that defines it, never
through a redirect; the eager imports of ``scaling/__init__.py`` and its lazy table (:data:`scaling._LAZY`) alike."""

from __future__ import annotations

import ast
import importlib
import importlib.util
from pathlib import Path

import pytest

import scaling


def homes() -> dict[str, str]:
    """Public name -> the module ``scaling/__init__.py`` takes it from."""
    tree = ast.parse(Path(scaling.__file__).read_text(encoding="utf-8"))
    eager = {alias.asname or alias.name: node.module for node in tree.body
             if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("scaling.")
             for alias in node.names}
    return {**eager, **scaling._LAZY}


@pytest.mark.parametrize("name", scaling.__all__)
def test_public_name_comes_from_its_defining_module(name: str) -> None:
    # a name that is also a submodule's would turn into that module once the submodule is imported
    assert importlib.util.find_spec(f"scaling.{name}") is None, f"scaling.{name} is a module"
    home = homes()[name]
    obj = getattr(scaling, name)
    assert obj is getattr(importlib.import_module(home), name)
    defined_in = getattr(obj, "__module__", None)  # constants such as EQ10 (a dict) carry none
    assert defined_in is None or defined_in == home or defined_in.startswith(home + "."), (name, home, defined_in)
