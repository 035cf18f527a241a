"""Shared fixtures: the bundled pendulum example, its tuned design and the paper's design."""

from pathlib import Path

import pytest
from fhobs.core.gains import ObserverGains
from fhobs.design import design_for_spec, paper_gains
from fhobs.spec import PlantSpec, load_spec

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"


@pytest.fixture(scope="session")
def pendulum_spec() -> PlantSpec:
    """The paper's pendulum, as shipped in examples/pendulum.toml."""
    return load_spec(EXAMPLES / "pendulum.toml")


@pytest.fixture(scope="session")
def tuned_gains(pendulum_spec: PlantSpec) -> ObserverGains:
    """Our design for the pendulum (default objective)."""
    return design_for_spec(pendulum_spec)


@pytest.fixture(scope="session")
def paper_design() -> ObserverGains:
    """The paper's published gains, certified."""
    return paper_gains(EXAMPLES / "pendulum-paper.json")
