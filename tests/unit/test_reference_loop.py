"""The reference loop in C (harness/reference_loop.c) against the same loop stepped from Python:
the same kernel steps in the same order. The products C x and K z are summed left to right in
C, in BLAS's order in numpy: on this machine the pendulum's (n = 4) trajectories are equal bit
for bit, larger plants' y and u differ in the last bits (measured <= 3.5e-16 relative over
0.3 s), which the filtering observer amplifies as it amplifies any round-off of y (measured
<= 3.9e-13 on z and xi): the data are held to 1e-14, the observer's trajectories to the
kernel's 1e-12, on any BLAS. Plants of every shape the zoo has (a disturbance model, MIMO,
n = 10), the Kalman filter replayed, the feedback on the state, the Euler scheme with
substeps, several calls of the loop; a non-finite state refused by both loops; a model handed
to a loop in C keeps its state."""

from __future__ import annotations

import ctypes
import subprocess

import numpy as np
import pytest
from designs import random_design, zoo_design
from fhobs.core.kernel import HEADER as KERNEL_HEADER
from fhobs.core.kernel import StepperHandle
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fhobs.design.feedback import state_feedback

from harness import reference
from harness.native import REFERENCE_SOURCE, ReferenceLoop, ReferenceRecord, reference_library

pytestmark = pytest.mark.skipif(reference_library() is None,
                                reason="the reference loop is compiled with cc on linux")

FIELDS = ("x", "z", "z_lin", "z_kalman", "psi", "xi", "sigma", "q_hat", "y", "u")
DATA = ("x", "z_lin", "y", "u")
"""The trajectories that do not pass through the filtering observer's amplification (the
Kalman filter's, replayed on the recorded (y, u), sums its innovations over the whole run: its
two loops differ by 1.05e-14 of its size on the paper's nominal loop with AVX-512 kernels, so it
is held to the filtering observer's 1e-12)."""


def c_loop(monkeypatch, *args, **kwargs) -> reference.SimulationResult:
    """:func:`reference.simulate` with its loop in C (the Python loop refused), in calls of
    1000 steps."""
    def refused(*_args):
        raise AssertionError("the loop ran in Python")

    with monkeypatch.context() as patch:
        patch.setattr(reference, "_loop_in_python", refused)
        patch.setattr(reference, "C_CHUNK", 1000)
        return reference.simulate(*args, **kwargs)


def python_loop(monkeypatch, *args, **kwargs) -> reference.SimulationResult:
    """:func:`reference.simulate` with its loop stepped from Python (the kernel's steps)."""
    with monkeypatch.context() as patch:
        patch.setattr(reference, "reference_library", lambda: None)
        return reference.simulate(*args, **kwargs)


def assert_same(a: reference.SimulationResult, b: reference.SimulationResult) -> None:
    """Every trajectory of a and b within 1e-14 relative (norm-wise) for :data:`DATA`, 1e-12
    for the filtering observer's."""
    for name in FIELDS:
        left, right = getattr(a, name), getattr(b, name)
        assert (left is None) == (right is None), name
        if left is None:
            continue
        assert left.shape == right.shape, name
        scale = max(np.linalg.norm(right), 1e-300)
        limit = 1e-14 if name in DATA else 1e-12
        assert np.linalg.norm(left - right) <= limit * scale, name


@pytest.mark.parametrize("scenario", ["nominal", "perturbed_noisy"])
def test_paper_loop_with_a_kalman_filter(kalman_design, monkeypatch, scenario):
    in_c = c_loop(monkeypatch, kalman_design, scenario, t_end=0.5)
    assert in_c.z_kalman is not None and in_c.error[-1] < 0.2 * in_c.error[0]
    assert_same(in_c, python_loop(monkeypatch, kalman_design, scenario, t_end=0.5))


@pytest.mark.parametrize("design", [
    lambda: zoo_design("random_mimo10"),
    lambda: zoo_design("quarter_car"),
    lambda: random_design(2, 8, 2, 1),
], ids=["random_mimo10", "quarter_car", "random_8_2_order_1"])
@pytest.mark.parametrize(("scheme", "dt", "h"), [("split", 1e-3, None), ("euler", 2e-3, 5e-4)])
def test_other_plants_feedback_on_the_state(design, monkeypatch, scheme, dt, h):
    design = design()
    plant = design.plant
    kwargs = dict(t_end=0.3, dt=dt, h=h, scheme=scheme, K=state_feedback(plant.A, plant.B),
                  x0=np.linspace(1.0, -1.0, plant.n), feedback="state")
    in_c = c_loop(monkeypatch, design, "perturbed_noisy", **kwargs)
    assert np.all(np.isfinite(in_c.z)) and in_c.u.shape == (round(0.3 / dt), plant.m)
    assert_same(in_c, python_loop(monkeypatch, design, "perturbed_noisy", **kwargs))


def test_feedback_on_the_estimate_of_a_disturbance_model(monkeypatch):
    """The estimate that closes the loop is the first n entries of the model's state."""
    design = random_design(4, 10, 3, 1)
    plant = design.plant
    kwargs = dict(t_end=0.2, dt=1e-3, K=0.1 * state_feedback(plant.A, plant.B),
                  x0=np.ones(plant.n))
    in_c = c_loop(monkeypatch, design, "perturbed", **kwargs)
    assert in_c.q_hat.shape[1] == 1
    assert_same(in_c, python_loop(monkeypatch, design, "perturbed", **kwargs))


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_a_state_that_overflows_is_refused(paper_design, monkeypatch):
    """A feedback of 1e300 overflows the plant in the first steps: ValueError from either
    loop, the C loop naming the plant."""
    K = np.full((1, 4), 1e300)
    with pytest.raises(ValueError, match="plant"):
        c_loop(monkeypatch, paper_design, "nominal", t_end=0.01, K=K)
    with pytest.raises(ValueError, match="plant"):
        python_loop(monkeypatch, paper_design, "nominal", t_end=0.01, K=K)


def test_a_model_handed_to_a_loop_in_c_keeps_its_state(paper_design):
    """A plant and an observer that stepped (their state in the stepper's buffers), then
    handed to a loop in C whose step writes those buffers: each keeps its state, and its next
    steps are those of a twin that was never handed over."""
    design = paper_design
    plant = design.plant
    make = {"plant": lambda: LTIPlant(plant.A, plant.B, plant.C, plant.E, x0=np.ones(plant.n)),
            "observer": lambda: FilteringObserver(design.filtering)}
    advance = {"plant": lambda model: model.advance(np.array([0.3]), np.array([0.1]), 1e-3),
               "observer": lambda model: model.advance(np.array([0.2, -0.1]), np.array([0.3]),
                                                      1e-3)}
    state = {"plant": lambda model: model.x, "observer": lambda model: model.get_state()}
    for name in make:
        handed, twin = make[name](), make[name]()
        for model in (handed, twin):
            advance[name](model)
        before = state[name](handed)
        handle = handed.kernel_handle(1e-3)
        step = ctypes.cast(handle.step, ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p))
        for side in (0, 1, 0):  # the loop's steps write both buffers
            assert step(handle.calls[side]) == 0
        assert np.array_equal(state[name](handed), before), name
        for model in (handed, twin):
            advance[name](model)
        assert np.array_equal(state[name](handed), state[name](twin)), name


def test_the_ctypes_structures_have_the_c_layout(tmp_path):
    """StepperHandle (kernel.h), ReferenceLoop and ReferenceRecord (reference_loop.c): every
    field at the offset the C compiler gives it, and the same sizes."""
    structures = {"StepperHandle": StepperHandle, "ReferenceLoop": ReferenceLoop,
                  "ReferenceRecord": ReferenceRecord}
    lines = [f'#include "{REFERENCE_SOURCE}"', "#include <stdio.h>", "int main(void) {"]
    for name, structure in structures.items():
        lines.append(f'printf("{name} %zu\\n", sizeof({name}));')
        lines += [f'printf("{name}.{field} %zu\\n", offsetof({name}, {field}));'
                  for field, _ in structure._fields_]
    program, binary = tmp_path / "layout.c", tmp_path / "layout"
    program.write_text("\n".join([*lines, "return 0;", "}"]) + "\n")
    subprocess.run(["cc", f"-I{KERNEL_HEADER.parent}", "-o", str(binary), str(program)],
                   check=True, capture_output=True)
    printed = dict(line.split() for line in subprocess.run(
        [str(binary)], check=True, capture_output=True, text=True).stdout.splitlines())
    expected = {}
    for name, structure in structures.items():
        expected[name] = str(ctypes.sizeof(structure))
        expected |= {f"{name}.{field}": str(getattr(structure, field).offset)
                     for field, _ in structure._fields_}
    assert printed == expected
