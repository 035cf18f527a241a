"""Shared fixtures (the bundled pendulum example, its tuned design and the paper's design)
and the layer markers: every test is marked with its folder (unit, fmu, harness, engines,
cli), so ``pytest -m fmu`` runs one layer; ``slow`` marks the long runs."""

import dataclasses
from pathlib import Path

import pytest
from fhobs.core.gains import ObserverGains
from fhobs.design import design_for_spec, paper_gains
from fhobs.kalman import with_kalman
from fhobs.paper import PENDULUM_SPEC
from fhobs.spec import PlantSpec, load_spec

LAYERS = ("unit", "fmu", "harness", "engines", "cli")

pytest_plugins = ("fmu_fixtures", "host_runner")
"""The shared FMU fixtures (tests/fmu_fixtures.py) and the C test host (tests/host_runner.py),
registered once for the session: a module that assigned them to names of its own would get
its own copies, so each "session" build would run once per module."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each test with its layer, the folder under tests/ that holds it."""
    root = Path(__file__).resolve().parent
    for item in items:
        layer = Path(item.fspath).resolve().relative_to(root).parts[0]
        if layer in LAYERS:
            item.add_marker(getattr(pytest.mark, layer))


@pytest.fixture(scope="session")
def pendulum_spec() -> PlantSpec:
    """The paper's pendulum, as shipped in examples/pendulum.toml."""
    return load_spec(PENDULUM_SPEC)


@pytest.fixture(scope="session")
def tuned_gains(pendulum_spec: PlantSpec) -> ObserverGains:
    """Our observer design for the pendulum (default objective), without the Kalman filter of
    its [noise] table (``kalman_gains`` has it)."""
    return design_for_spec(dataclasses.replace(pendulum_spec, noise=None))


@pytest.fixture(scope="session")
def kalman_gains(tuned_gains: ObserverGains, pendulum_spec: PlantSpec) -> ObserverGains:
    """The pendulum design with the Kalman filter of examples/pendulum.toml's [noise] table."""
    return with_kalman(tuned_gains, pendulum_spec.noise)


@pytest.fixture(scope="session")
def paper_design() -> ObserverGains:
    """The paper's published gains, certified."""
    return paper_gains()
