"""design_observer(A, B, C, ...): arrays, python-control systems, and argument checks naming
the argument; the same design as the spec file's path."""

import control
import numpy as np
import pytest
from fhobs.design.observer import design_for_spec, design_observer
from fhobs.design.spec import load_spec
from fhobs.errors import SpecError
from fhobs.fmu.kinds import record_field

A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
C = [[1.0, 0.0]]


def same_design(first, second):
    for path in ("model.L0", "model.G_d", "filtering.L_tilde", "filtering.L", "filtering.P_bar",
                 "prescribed_time.L_pt", "prescribed_time.P_pt", "luenberger.L_lin"):
        np.testing.assert_array_equal(record_field(first, path), record_field(second, path),
                                      err_msg=path)
    for path in ("model.nu", "filtering.rho", "filtering.gamma", "prescribed_time.rho"):
        assert record_field(first, path) == record_field(second, path), path


@pytest.fixture(scope="module")
def reference():
    return design_observer(A, B, C, rho=2.0, gamma=3.0)


def test_arrays_lists_and_tuples_give_one_design(reference):
    same_design(design_observer(np.array(A), np.array(B), np.array(C), rho=2.0, gamma=3.0),
                reference)
    same_design(design_observer(tuple(map(tuple, A)), B, C, rho=2.0, gamma=3.0), reference)


def test_state_space_gives_the_same_design(reference):
    system = control.ss(np.array(A), np.array(B), np.array(C), np.zeros((1, 1)))
    same_design(design_observer(system, rho=2.0, gamma=3.0), reference)


def test_the_spec_file_path_gives_the_same_design(tmp_path, reference):
    path = tmp_path / "plant.toml"
    path.write_text("A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]\nC = [[1.0, 0.0]]\n"
                    "[observer]\nrho = 2.0\ngamma = 3.0\n")
    same_design(design_for_spec(load_spec(path)), reference)


def test_tuning_keywords_reach_the_design():
    E = [[0.0], [1.0]]
    gains = design_observer(A, B, C, E=E, disturbance_order=1, rho=3.0, gamma=2.0,
                            filter_scale=2.0, objective="min_gain")
    assert gains.model.disturbance_order == 1 and gains.model.n_model == 3
    assert gains.filtering.gamma == 2.0
    assert gains.filtering.rho < 3.0  # the certified rho of the scaled filter gain
    for record in (gains.filtering, gains.prescribed_time, gains.luenberger):
        assert record.certificate["objective"] == "min_gain"
    np.testing.assert_array_equal(gains.plant.E, np.array(E))


@pytest.mark.parametrize("call, message", [
    (lambda: design_observer(A, B, [[1.0, 0.0, 0.0]]), "C has 3 columns, expected 2"),
    (lambda: design_observer([[0.0, 1.0]], B, C), "A must be square, got 1 x 2"),
    (lambda: design_observer([[0.0, np.nan], [0.0, 0.0]], B, C), "A[1,2] = nan is not finite"),
    (lambda: design_observer(A, [[0.0], [1.0], [2.0]], C), "B has 3 rows, expected 2"),
    (lambda: design_observer(A, B, C, rho=-1.0), "rho = -1.0 must be > 0"),
    (lambda: design_observer(A, B, C, rho=1.0, gamma=3.0), "rho = 1.0 must be > gamma/2"),
    (lambda: design_observer(A, B, C, nu=0.5), "nu = 0.5 is outside"),
    (lambda: design_observer(A, B, C, settling_time=0.0), "settling_time = 0.0 must be > 0"),
    (lambda: design_observer(A, B, C, state_scale=[1.0, 2.0, 3.0]),
     "state_scale has 3 entries, expected 1 or 2"),
    (lambda: design_observer(A, B, C, filter_scale=0.5), "filter_scale = 0.5 must be >= 1"),
    (lambda: design_observer(A, B, C, objective="fast"), "objective = 'fast' is not one of"),
    (lambda: design_observer(A, B, C, disturbance_order=1), "disturbance_order = 1 needs E"),
    (lambda: design_observer(A, B, [[0.0, 1.0]]), "(A, C) is not observable"),
    (lambda: design_observer(A, B), "give A, B and C, or a python-control StateSpace alone"),
    (lambda: design_observer(control.ss(A, B, C, [[1.0]])), "D must be zero"),
    (lambda: design_observer(control.ss(A, B, C, [[0.0]], 0.1)), "discrete-time (dt = 0.1)"),
    (lambda: design_observer("plant"), "A must be a matrix or a StateSpace, got str"),
])
def test_bad_arguments_are_named(call, message):
    with pytest.raises(SpecError) as info:
        call()
    assert str(info.value).startswith("design_observer: ")
    assert message in str(info.value)


def test_the_solver_status_is_reported(reference):
    """Each LMI's status as the solver gave it, in the record it made: optimal here (a double
    integrator)."""
    for record in (reference.filtering, reference.prescribed_time, reference.luenberger):
        assert record.certificate["solver_status"] == "optimal"


def test_an_inaccurate_solve_is_reported_as_such(monkeypatch):
    """A solve that stops short of the solver's tolerances is kept (it passes the certificate)
    and reported ``optimal_inaccurate``, not ``optimal``."""
    from fhobs.design import lmi

    monkeypatch.setitem(lmi.CLARABEL_STATUS, "Solved", "optimal_inaccurate")  # as AlmostSolved
    monkeypatch.setenv("FHOBS_NO_DESIGN_CACHE", "1")  # the solver runs, the cache aside
    gains = design_observer(A, B, C, rho=2.0, gamma=3.0)
    for record in (gains.filtering, gains.prescribed_time, gains.luenberger):
        assert record.certificate["solver_status"] == "optimal_inaccurate"
    gains = design_observer(A, B, C, rho=2.0, gamma=3.0, L_lin=[[-2.0], [-1.0]])
    for record in (gains.filtering, gains.prescribed_time):
        assert record.certificate["solver_status"] == "optimal_inaccurate"
    assert set(gains.luenberger.certificate) == {"checks"}  # given, not solved


def test_the_extended_model_is_built_once_per_record(reference):
    import dataclasses

    for record in (reference.filtering, reference.prescribed_time):
        assert record.model_matrices is record.model_matrices and record.A0 is record.A0
        A_model, _, C_model = record.model_matrices
        np.testing.assert_array_equal(record.A0, A_model + reference.model.L0 @ C_model)
        model = dataclasses.replace(reference.model, L0=2.0 * reference.model.L0)
        edited = dataclasses.replace(record, model=model)
        A_model, _, C_model = edited.model_matrices
        np.testing.assert_array_equal(edited.A0, A_model + 2.0 * reference.model.L0 @ C_model)


def test_the_public_api_is_listed_and_lazy():
    """fhobs exposes the design record, the runtime estimators, paper_gains and the errors:
    listed in __all__ and dir(), each the object of its module, none imported by
    ``import fhobs`` itself (checked in a fresh interpreter)."""
    import subprocess
    import sys

    import fhobs
    from fhobs.core.gains import ObserverDesign
    from fhobs.core.runtime import FilteringObserver

    assert {"ObserverDesign", "PlantModel", "HomogeneousModel", "FilteringGains",
            "PrescribedTimeGains", "LuenbergerGains", "KalmanGains", "FilteringObserver",
            "KalmanObserver", "paper_gains", "FhobsError", "CertificateError"} <= set(fhobs.__all__)
    assert set(fhobs.__all__) <= set(dir(fhobs))
    assert fhobs.ObserverDesign is ObserverDesign and fhobs.FilteringObserver is FilteringObserver
    assert all(isinstance(getattr(fhobs, name), type) or callable(getattr(fhobs, name))
               for name in fhobs.__all__)
    light = subprocess.run([sys.executable, "-c", "import sys, fhobs; print(sorted(m for m in "
                            "('fhobs.design.observer', 'cvxpy', 'scipy') if m in sys.modules))"],
                           capture_output=True, text=True, check=True).stdout.strip()
    assert light == "[]"
