"""Shared fixtures (the bundled pendulum example, its tuned design and the paper's design)
and the layer markers: every test is marked with its folder (unit, fmu, harness, engines,
cli), so ``pytest -m fmu`` runs one layer; ``slow`` marks the long runs."""

import dataclasses
import os
from pathlib import Path

import pytest
from fhobs.core.gains import ObserverDesign
from fhobs.design.spec import PlantSpec, load_spec
from fhobs.paper import PENDULUM_SPEC

LAYERS = ("unit", "fmu", "harness", "engines", "cli")

pytest_plugins = ("fmu_fixtures", "host_runner")
"""The shared FMU fixtures (tests/fmu_fixtures.py) and the C test host (tests/host_runner.py),
registered once for the session: a module that assigned them to names of its own would get
its own copies, so each "session" build would run once per module."""


def pytest_configure(config: pytest.Config) -> None:
    """One BLAS thread per process (unless the environment says otherwise): the pytest-xdist
    workers, started after this, inherit it (as do the tests' child processes), so that two
    workers on two cores do not run four OpenBLAS threads that spin while they wait (the fast
    subset on 2 cores: 95 s -> 75 s; the tests' matrices are too small to gain from threads).
    This process's numpy has its threads already; a run without workers keeps them."""
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the xdist_group marks
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each test with its layer, the folder under tests/ that holds it, and, when it uses a
    module-scoped fixture, with its module's ``xdist_group``."""
    root = Path(__file__).resolve().parent
    for item in items:
        relative = Path(item.fspath).resolve().relative_to(root)
        layer = relative.parts[0]
        if layer in LAYERS:
            item.add_marker(getattr(pytest.mark, layer))
        if uses_module_fixture(item) and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(relative.as_posix()))


def uses_module_fixture(item: pytest.Item) -> bool:
    """Whether ``item`` requests (directly or through other fixtures) a fixture of module
    scope. Under ``--dist loadgroup`` (pyproject.toml) the tests of one group run on one
    worker, so a module's expensive fixture (an FMU build, a closed-loop run) is made once,
    not once per worker. A module whose tests take such a fixture through
    ``request.getfixturevalue`` declares its group itself (``pytestmark``, the group named by
    its path under tests/, as here)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    return any(definition.scope == "module"
               for definitions in info.name2fixturedefs.values() for definition in definitions)


@pytest.fixture(scope="session")
def pendulum_spec() -> PlantSpec:
    """The paper's pendulum, as shipped in examples/pendulum.toml."""
    return load_spec(PENDULUM_SPEC)


@pytest.fixture(scope="session")
def tuned_design(pendulum_spec: PlantSpec) -> ObserverDesign:
    """Our observer design for the pendulum (default objective), without the Kalman filter of
    its [noise] table (``kalman_design`` has it)."""
    from fhobs.design.observer import design_for_spec  # here: the xdist controller runs no test

    return design_for_spec(dataclasses.replace(pendulum_spec, noise=None))


@pytest.fixture(scope="session")
def kalman_design(tuned_design: ObserverDesign, pendulum_spec: PlantSpec) -> ObserverDesign:
    """The pendulum design with the Kalman filter of examples/pendulum.toml's [noise] table."""
    from fhobs.design.kalman import with_kalman

    return with_kalman(tuned_design, pendulum_spec.noise)


@pytest.fixture(scope="session")
def paper_design() -> ObserverDesign:
    """The paper's published gains, certified."""
    from fhobs.design.observer import paper_gains

    return paper_gains()
