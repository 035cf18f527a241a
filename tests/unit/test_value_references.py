"""Value references are stable across additions (docs/fmus.md, "Value references"): every
variable of tests/value_references.json keeps its value reference in every kind, a new
variable takes a value reference after them, and every declared kind is in the contract."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from fhobs.fmu.kinds import KINDS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from value_references import SNAPSHOT, pendulum_design, value_references  # noqa: E402

REGENERATE = "a new kind or variable: python tests/value_references.py --write"


@pytest.fixture(scope="module")
def current() -> dict[str, dict[str, int]]:
    return value_references(pendulum_design())


@pytest.fixture(scope="module")
def contract() -> dict[str, dict[str, int]]:
    return json.loads(SNAPSHOT.read_text())


def test_every_kind_is_in_the_contract(current, contract):
    assert sorted(current) == sorted(KINDS), "the pendulum design builds every kind"
    assert sorted(contract) == sorted(KINDS), REGENERATE


@pytest.mark.parametrize("kind", KINDS)
def test_existing_variables_keep_their_value_references(current, contract, kind):
    moved = {name: (vr, current[kind].get(name)) for name, vr in contract[kind].items()
             if current[kind].get(name) != vr}
    assert not moved, f"{kind}: (contract, now) {moved}: append new variables (Kind.variables)"
    added = set(current[kind]) - set(contract[kind])
    assert all(current[kind][name] >= len(contract[kind]) for name in added), added
