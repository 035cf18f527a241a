"""The FMU kinds' declaration of where each output comes from (fhobs.fmu.kinds): every output
is a slice of the runtime model's state or one of its attributes, and the slave's reads give
the quantities the paper defines, checked against formulas written here."""

import math

import fhobs.fmu.kinds
import numpy as np
import pytest
from fhobs.core.gains import ESTIMATORS
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fhobs.core.supervisor import MODE_HOMOGENEOUS, MODE_KALMAN, SupervisedObserver
from fhobs.design.kalman import with_kalman
from fhobs.design.spec import NoiseSpec
from fhobs.design.supervised import design_supervised, with_supervised
from fhobs.fmu.kinds import KINDS, LABELS
from fhobs.fmu.options import fmu_options
from fhobs.fmu.slave_base import output_reads

from tests.designs import random_design


def _noise(design):
    """A [noise] table of std 1e-3, Ts = 1e-3 s for ``design``."""
    return NoiseSpec(np.full(design.plant.k, 1e-3), 1e-3, 1.0, design.model.disturbance_order)


def _supervised(design):
    """A supervised record of ``design`` (of :func:`_noise`)."""
    return design_supervised(design, _noise(design))


def _declared_model(design, kind):
    """The kind's declared runtime model (:attr:`fhobs.fmu.kinds.Kind.model`) of the record of
    ``design`` with the records of :func:`_noise` attached, at the default build options."""
    design = with_supervised(with_kalman(design, _noise(design)), _noise(design))
    options = fmu_options(design, [kind], h=1e-4, x0=np.ones(design.plant.n))
    return KINDS[kind].model(KINDS[kind].runs(design),
                             lambda name: options[KINDS[kind].variable(name).option])


def _flat_outputs(kind, model, sizes):
    arrays = {name: np.zeros(size) for name, size in sizes.items()}
    state = model.get_state()
    values = []
    for attribute, start, stop in output_reads(KINDS[kind], arrays):
        values += (np.ravel(getattr(model, attribute)) if attribute else state[start:stop]).tolist()
    return values


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_output_has_a_source(kind):
    """A declared attribute source exists on the kind's runtime model, and every kind has an
    output that is part of the model state (the slaves read the state at every step; the C
    table of state outputs cannot be empty)."""
    model = _declared_model(random_design(3, 3, 2, 1), kind)
    for variable in KINDS[kind].variables:
        if variable.role == "output" and variable.source != "state":
            assert hasattr(model, variable.source), (kind, variable.name)
        elif variable.role != "output":
            assert variable.source == "state", (kind, variable.name)
    assert any(KINDS[kind].variable(name).source == "state" for name in KINDS[kind].outputs)


def test_observer_outputs_are_the_papers_quantities():
    """x_hat, q_hat, psi, xi of the state z, psi, xi after some steps; sigma from psi and xi."""
    design = random_design(5, 3, 2, 1)
    n, N, k = design.plant.n, design.model.n_model, design.plant.k
    model = FilteringObserver(design.filtering, h=1e-4)
    rng = np.random.default_rng(5)
    for _ in range(20):
        model.advance(rng.normal(size=k), rng.normal(size=design.plant.m), 1e-3)
    sizes = {"x_hat": n, "q_hat": N - n, "psi": k, "xi": 1, "sigma": 1}
    values = _flat_outputs("observer", model, sizes)
    z, psi, xi = model.z, model.get_state()[N:N + k], model.get_state()[N + k]
    sigma = math.sqrt(max(xi, float(psi @ psi) / 2))
    assert values == [*z[:n], *z[n:], *psi, xi, sigma]


def test_supervised_outputs_are_the_statistic_the_mode_then_the_modes_estimate():
    """statistic and mode of the state, x_hat and q_hat of the output estimator's z, also in
    mode K (after the switch of a consistent run)."""
    design = random_design(5, 3, 2, 1)
    model = SupervisedObserver(_supervised(design), h=1e-4)
    n, N = design.plant.n, design.model.n_model
    rng = np.random.default_rng(5)
    sizes = {"statistic": 1, "mode": 1, "x_hat": n, "q_hat": N - n}
    modes = set()
    for _ in range(400):
        model.advance(rng.normal(scale=1e-3, size=design.plant.k), np.zeros(design.plant.m),
                      1e-3)
        values = _flat_outputs("supervised", model, sizes)
        estimator = model.kalman if model.mode == MODE_KALMAN else model.homogeneous
        assert values == [model.statistic, model.mode, *estimator.z]
        modes.add(model.mode)
    assert modes == {MODE_KALMAN, MODE_HOMOGENEOUS}


def test_plant_outputs_are_y_then_x():
    design = random_design(7, 3, 2, 0)
    plant = LTIPlant(design.plant.A, design.plant.B, design.plant.C, design.plant.B,
                     x0=np.arange(1.0, design.plant.n + 1))
    values = _flat_outputs("plant", plant, {"y": design.plant.k, "x": design.plant.n})
    x = np.arange(1.0, design.plant.n + 1)
    assert values == [*(design.plant.C @ x), *x]


def test_the_labels_are_one_per_estimator_record():
    """LABELS (FMU kind -> the harness's label) has one kind per estimator record of the design
    (fhobs.core.gains.ESTIMATORS), each label its own; the kinds module has no second
    ESTIMATORS of another meaning."""
    assert sorted(KINDS[kind].record for kind in LABELS) == sorted(ESTIMATORS)
    assert all(LABELS.values()) and len(set(LABELS.values())) == len(LABELS)
    assert not hasattr(fhobs.fmu.kinds, "ESTIMATORS")
