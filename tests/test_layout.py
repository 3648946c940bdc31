"""docs/layout.md is the map of the package: every module of every layer named in its layer's entry,
and no module importing from a layer after its own."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
LAYERS = ("models", "analysis", "reports")
"""The layers in import order: each imports only from those before it."""


def modules(layer: str) -> list[str]:
    return sorted(p.stem for p in (ROOT / layer).glob("*.py") if p.stem not in ("__init__", "__main__"))


def layer_entry(layer: str) -> str:
    """The bullet of docs/layout.md that describes ``layer/`` (up to the next bullet)."""
    text = (ROOT / "docs" / "layout.md").read_text()
    match = re.search(rf"^- `{layer}/`.*?(?=^- |\Z)", text, flags=re.S | re.M)
    assert match, f"docs/layout.md has no entry for {layer}/"
    return match.group(0)


@pytest.mark.parametrize("layer", LAYERS)
def test_the_layout_names_every_module_of_its_layer(layer):
    entry = layer_entry(layer)
    missing = [m for m in modules(layer) if f"`{m}`" not in entry]
    assert not missing, f"docs/layout.md's {layer}/ entry does not name {missing}"


@pytest.mark.parametrize("layer", LAYERS)
def test_no_module_imports_a_later_layer(layer):
    later = LAYERS[LAYERS.index(layer) + 1 :]
    found = []
    for path in (ROOT / layer).glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])  # fmt: skip
            found += [f"{path.name}: {n}" for n in names if any(n.startswith(f"dvfc.{x}") for x in later)]
    assert not found, found
