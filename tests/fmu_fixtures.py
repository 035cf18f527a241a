"""Shared FMU test fixtures: the FMUs built once per session and a small fmpy FMU2Slave
driver (imported by the FMU, kernel and Kalman tests). tests/conftest.py registers this module
as a plugin (``pytest_plugins``), so each session fixture is built once for the whole run: a
test module uses them by name and must not assign them to names of its own (that would give
the module its own copy, built again).
Variable names are formatted here independently of :mod:`fhobs.fmu.slave_base`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.core.gains import ObserverDesign
from fhobs.core.plant import LTIPlant
from fhobs.design.spec import load_spec
from fhobs.fmu.fmu_state import fnv1a64, state_from_bytes, state_to_bytes
from fhobs.fmu.kinds import kinds_where
from fhobs.native.build import build_native_fmus
from fhobs.paper import EXAMPLES, H_PAPER, PAPER_SCENARIOS, X0_PAPER
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    calloc,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Error,
    free,
)

PENDULUM_X0 = tuple(X0_PAPER.tolist())
NOISE_AMPLITUDE = PAPER_SCENARIOS["perturbed_noisy"].noise_amplitude
NOISE_SEED = 7
H = H_PAPER
FMI_ERROR = fmi2Error
UNREADABLE = ("np.float64", "nan (required", "(required > nan)", "(required < nan)")
"""Fragments that make an FMU's error message unreadable (numpy reprs, NaN comparisons)."""


def names(base: str, shape: tuple[int, ...]) -> list[str]:
    """FMI names of an array's elements, row-major and 1-based, as the contract specifies."""
    if len(shape) == 0:
        return [base]
    if len(shape) == 1:
        return [f"{base}[{i + 1}]" for i in range(shape[0])]
    return [f"{base}[{i + 1},{j + 1}]" for i in range(shape[0]) for j in range(shape[1])]


class FmuDriver:
    """One FMU instance driven through fmpy's ``FMU2Slave``, its log messages captured.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file.
    unzip_dir : str
        Where it was extracted (several instances may share one extraction).
    instance_name : str
    logging_on : bool
        fmi2Instantiate's loggingOn.
    """

    def __init__(self, path: Path, unzip_dir: str, instance_name: str = "instance",
                 logging_on: bool = True) -> None:
        self.description = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.description.modelVariables}
        self.messages: list[tuple[int, str]] = []
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = fmi2CallbackLoggerTYPE(self._on_log)
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu = FMU2Slave(
            guid=self.description.guid,
            unzipDirectory=unzip_dir,
            modelIdentifier=self.description.coSimulation.modelIdentifier,
            instanceName=instance_name,
        )
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)

    def _on_log(self, env, instance, status, category, message) -> None:  # noqa: ANN001
        self.messages.append((int(status), message.decode()))

    def start(self, parameters: dict[str, np.ndarray | float] | None = None) -> None:
        """setupExperiment, set parameter values, enter and exit initialisation mode."""
        self.fmu.setupExperiment(startTime=0.0)
        for name, value in (parameters or {}).items():
            self.set(name, value)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def set(self, base: str, value: np.ndarray | float) -> None:
        """Set an array variable (all its elements)."""
        value = np.asarray(value, dtype=float)
        refs = [self.vr[name] for name in names(base, value.shape)]
        self.fmu.setReal(refs, value.ravel().tolist())

    def get(self, base: str, shape: tuple[int, ...]) -> np.ndarray:
        """Read an array variable."""
        return np.array(self.fmu.getReal([self.vr[n] for n in names(base, shape)])).reshape(shape)


@pytest.fixture(scope="session")
def pendulum_fmus(tmp_path_factory: pytest.TempPathFactory, kalman_design: ObserverDesign):
    """observer.fmu, luenberger.fmu, kalman.fmu and plant.fmu of the pendulum design (the
    Kalman filter of its [noise] table), built once."""
    return build_fmus(
        kalman_design,
        tmp_path_factory.mktemp("pendulum_fmus"),
        x0=PENDULUM_X0,
        noise_amplitude=NOISE_AMPLITUDE,
        noise_seed=NOISE_SEED,
        h=H,
    )


@pytest.fixture(scope="session")
def paper_design_fmus(tmp_path_factory: pytest.TempPathFactory,
                      paper_design: ObserverDesign) -> dict[str, Path]:
    """observer.fmu, prescribed_time.fmu and plant.fmu of the paper's gains (default start
    values), built once."""
    return build_fmus(paper_design, tmp_path_factory.mktemp("paper_design_fmus"),
                      kinds=("observer", "prescribed_time", "plant"))


SHARED_KINDS = kinds_where(lambda kind: kind.record != "supervised")
"""The kinds of the shared pendulum design (``kalman_design``), read from the declaration so
that a new kind is built and tested here: every kind but the supervised estimator, whose record
that design lacks (tests/fmu/test_supervised_fmu.py builds its own)."""
COMPARED_KINDS = kinds_where(lambda kind: kind.name in SHARED_KINDS
                             and kind.family != "prescribed_time")
"""The kinds whose native FMU the generic comparisons run with the pythonfmu one: those of
:data:`SHARED_KINDS` but the prescribed_time family (its start needs T0 and it runs the split
scheme only: tests/fmu/test_native_prescribed_time.py compares it)."""


@pytest.fixture(scope="session")
def native_fmus(tmp_path_factory: pytest.TempPathFactory,
                kalman_design: ObserverDesign) -> dict[str, Path]:
    """The native FMUs of :data:`SHARED_KINDS`, of the design and options of
    ``pendulum_fmus``, built once (needs linux and cc: the modules that use it skip without).
    Their modelDescriptions are those of the default options but for the plant's start values
    (x0, noise): a test of another kind, or one that sets the plant's start values, can take
    them."""
    return build_native_fmus(kalman_design, tmp_path_factory.mktemp("native"), kinds=SHARED_KINDS,
                             x0=PENDULUM_X0, noise_amplitude=NOISE_AMPLITUDE,
                             noise_seed=NOISE_SEED, h=H)


@pytest.fixture(scope="session")
def chain_design() -> ObserverDesign:
    """A second design with other dimensions (n = 3, k = 1): the triple integrator."""
    from fhobs.design.observer import design_for_spec  # here: the xdist controller runs no test

    return design_for_spec(load_spec(EXAMPLES / "triple_integrator.toml"))


@pytest.fixture(scope="session")
def chain_observer(tmp_path_factory: pytest.TempPathFactory, chain_design: ObserverDesign) -> Path:
    """observer.fmu of the triple integrator."""
    built = build_fmus(chain_design, tmp_path_factory.mktemp("chain_fmus"), kinds=("observer",))
    return built["observer"]


@pytest.fixture(scope="session")
def unzipped(pendulum_fmus: dict[str, Path], chain_observer: Path) -> dict[str, str]:
    """Each FMU extracted once: kind (or ``chain``) -> directory."""
    dirs = {kind: extract(str(path)) for kind, path in pendulum_fmus.items()}
    dirs["chain"] = extract(str(chain_observer))
    return dirs


@pytest.fixture
def open_fmu(pendulum_fmus: dict[str, Path], chain_observer: Path, unzipped: dict[str, str]):
    """Factory ``open_fmu(kind, name)`` of FMU instances, all freed after the test."""
    paths = dict(pendulum_fmus, chain=chain_observer)
    opened: list[FmuDriver] = []

    def factory(kind: str, instance_name: str = "instance") -> FmuDriver:
        driver = FmuDriver(paths[kind], unzipped[kind], instance_name)
        opened.append(driver)
        return driver

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def random_walk(seed: int, steps: int, size: int, scale: float) -> np.ndarray:
    """A seeded input sequence: a Gaussian random walk, ``steps`` x ``size``."""
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(scale=scale, size=(steps, size)), axis=0)


def plant_measurements(gains: ObserverDesign, seed: int, steps: int, dt: float,
                       scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(ys, us): a seeded random run of the design's plant (numpy, noise 1e-3 relative) under
    random-walk inputs, the observers' inputs."""
    rng = np.random.default_rng(seed)
    plant = LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C,
                     x0=scale * rng.standard_normal(gains.plant.n),
                     noise_amplitude=1e-3 * scale, seed=seed, kernel=False)
    us = scale * random_walk(seed, steps, gains.plant.m, 0.3)
    ys = []
    for u in us:
        ys.append(plant.y)
        plant.step(u, None, dt)
    return np.array(ys), us


def assert_error(driver: FmuDriver, call, *args, words: str) -> str:  # noqa: ANN001
    """``call(*args)`` answers fmi2Error and logs a readable message containing ``words``;
    return that message."""
    with pytest.raises(FMICallException) as err:
        call(*args)
    assert err.value.status == FMI_ERROR
    status, message = driver.messages[-1]
    assert status == FMI_ERROR and words in message, message
    assert not any(word in message for word in UNREADABLE), message
    return message


def steps_until_error(driver: FmuDriver, step_size: float, before: Callable[[], Any],
                      limit: int = 100) -> tuple[int, Any]:
    """Step ``driver`` by ``step_size`` until a doStep answers fmi2Error (with a logged error);
    return that step's index and what ``before()`` gave just before it."""
    for k in range(limit):
        saved = before()
        try:
            driver.fmu.doStep(k * step_size, step_size)
        except FMICallException as err:
            assert err.status == FMI_ERROR and driver.messages[-1][0] == FMI_ERROR
            return k, saved
    pytest.fail(f"none of {limit} steps was an error")


def serialized(driver: FmuDriver) -> bytes:
    """The instance's serialized FMU state (the state object freed again)."""
    state = driver.fmu.getFMUstate()
    data = bytes(driver.fmu.serializeFMUstate(state))
    driver.fmu.freeFMUstate(state)
    return data


NATIVE_TAIL = 8  # the native serialized state ends with its 64-bit FNV-1a checksum


def forged(driver: FmuDriver, build: str, data: bytes, edit) -> bytes:  # noqa: ANN001
    """``data`` (a serialized state of ``driver``'s FMU) with its model state edited by
    ``edit`` (on a list of floats, in place) and its checksum recomputed: a checksum proves
    nothing. The native layout: header (8), format (4), GUID (48), FMI state (4), time (8), the
    Real (8 each) and Integer (4 each) variables, the model state, the checksum (8)."""
    if build == "pythonfmu":
        state = state_from_bytes(data)
        edit(state["model"])
        return state_to_bytes(state)
    body = bytearray(data[:-NATIVE_TAIL])
    start = 8 + 4 + 48 + 4 + 8 + 12 * len(driver.description.modelVariables)
    size = (len(body) - start) // 8
    model = list(struct.unpack_from(f"<{size}d", body, start))
    edit(model)
    struct.pack_into(f"<{size}d", body, start, *model)
    return bytes(body) + struct.pack("<Q", fnv1a64(bytes(body)))
