"""The mutation harness stays runnable: every mutation's patterns still match the code the stated
number of times, and the tests it names exist (``make mutate`` would otherwise stop on a harness
error long after the change that broke it)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
_spec = importlib.util.spec_from_file_location("harness", ROOT / "tests" / "mutation" / "harness.py")
harness = importlib.util.module_from_spec(_spec)
sys.modules["harness"] = harness  # its dataclasses look their module up there
_spec.loader.exec_module(harness)


def test_mutation_names_are_unique():
    names = [m.name for m in harness.MUTATIONS]
    assert len(names) == len(set(names))


@pytest.mark.parametrize("mutation", harness.MUTATIONS, ids=lambda m: m.name)
def test_each_pattern_matches_the_code_as_stated(mutation):
    text = (ROOT / mutation.path).read_text()
    for old, new in mutation.substitutions:
        assert old != new
        assert text.count(old) == mutation.count, old


@pytest.mark.parametrize("mutation", harness.MUTATIONS, ids=lambda m: m.name)
def test_each_named_test_exists(mutation):
    for selection in mutation.tests:
        path, _, name = selection.partition("::")
        source = (ROOT / path).read_text()
        assert not name or f"def {name.split('[')[0]}(" in source, selection
