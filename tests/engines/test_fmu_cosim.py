"""The pendulum's plant.fmu and observer.fmu coupled in libcosim (libcosimpy) and via fmpy.

The loop of the paper: y = plant output -> observer; u = K x_hat -> plant and observer;
q = a sin(w t) -> plant (the paper's perturbation). In libcosim, u comes from the harness's
matrix-gain FMU and q from its sine FMU. libcosim exchanges values only at communication
points, so the path through the gain block carries one step of delay: u_k = K x_hat_{k-1}
(x_hat_{-1} = x_hat_0). The in-process loop below (numpy runtime + numpy plant) follows
exactly that sequence.
"""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import SCHEMES, FilteringObserver
from fhobs.paper import K_PAPER, PAPER_SCENARIOS
from fmu_fixtures import NOISE_AMPLITUDE, NOISE_SEED, PENDULUM_X0, H, names

pytestmark = pytest.mark.slow  # three engines, each loading the FMUs afresh


K = K_PAPER
DT = 1e-3
STEPS = 300
Q_AMPLITUDE = PAPER_SCENARIOS["perturbed"].q_amplitude
Q_OMEGA = PAPER_SCENARIOS["perturbed"].q_frequency


def in_process_loop(gains) -> tuple[np.ndarray, np.ndarray]:
    """x and x_hat at t_1..t_N from the numpy runtime, with the gain block's delay."""
    plant = LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C, gains.plant.E, x0=PENDULUM_X0,
                     noise_amplitude=NOISE_AMPLITUDE, seed=NOISE_SEED)
    obs = FilteringObserver(gains.filtering, h=H, scheme=SCHEMES[0])
    z_delayed = obs.x_hat
    xs, zs = [], []
    for k in range(STEPS):
        y, u = plant.y, K @ z_delayed
        q = np.array([Q_AMPLITUDE * np.sin(Q_OMEGA * k * DT)])
        z_delayed = obs.x_hat
        plant.step(u, q, DT)
        obs.step(y, u, DT)
        xs.append(plant.x)
        zs.append(obs.x_hat)
    return np.array(xs), np.array(zs)


def fmpy_loop(open_fmu, gains) -> tuple[np.ndarray, np.ndarray]:
    """The same loop with plant.fmu and observer.fmu through fmpy (u, q computed here)."""
    plant, obs = open_fmu("plant", "plant"), open_fmu("observer", "observer")
    plant.start()
    obs.start()
    z_delayed = obs.get("x_hat", (gains.plant.n,))
    xs, zs = [], []
    for k in range(STEPS):
        y, u = plant.get("y", (gains.plant.k,)), K @ z_delayed
        z_delayed = obs.get("x_hat", (gains.plant.n,))
        plant.set("u", u)
        plant.set("q", [Q_AMPLITUDE * np.sin(Q_OMEGA * k * DT)])
        obs.set("y", y)
        obs.set("u", u)
        plant.fmu.doStep(k * DT, DT)
        obs.fmu.doStep(k * DT, DT)
        xs.append(plant.get("x", (gains.plant.n,)))
        zs.append(obs.get("x_hat", (gains.plant.n,)))
    return np.array(xs), np.array(zs)


def libcosim_loop(fmus: dict, block_dir, gains) -> tuple[np.ndarray, np.ndarray]:
    """The loop in libcosim: plant, observer, harness gain and sine blocks, fixed step DT."""
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    from harness.blocks.build import block_fmu

    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_step_size(step_size=int(round(DT * 1e9)))
    paths = {"plant": fmus["plant"], "observer": fmus["observer"],
             "gain": block_fmu("gain", (1, gains.plant.n), block_dir),
             "sine": block_fmu("sine", (1,), block_dir)}
    index, vr = {}, {}
    for name, path in paths.items():
        index[name] = execution.add_local_slave(
            CosimLocalSlave(fmu_path=str(path), instance_name=name))
        vr[name] = {v.name.decode(): v.reference for v in execution.slave_variables(index[name])}

    def connect(src: str, src_var: str, dst: str, dst_var: str) -> None:
        status = execution.connect_real_variables(
            index[src], vr[src][src_var], index[dst], vr[dst][dst_var])
        assert status == 0  # libcosim's success code

    k, n = gains.plant.k, gains.plant.n
    for out_name, in_name in zip(names("y", (k,)), names("y", (k,)), strict=True):
        connect("plant", out_name, "observer", in_name)
    for out_name, in_name in zip(names("x_hat", (n,)), names("u", (n,)), strict=True):
        connect("observer", out_name, "gain", in_name)
    connect("gain", "y[1]", "plant", "u[1]")
    connect("gain", "y[1]", "observer", "u[1]")
    connect("sine", "y[1]", "plant", "q[1]")
    for name, value in zip(names("K", K.shape), K.ravel(), strict=True):
        assert execution.real_initial_value(index["gain"], vr["gain"][name], float(value))
    assert execution.real_initial_value(index["sine"], vr["sine"]["amplitude[1]"], Q_AMPLITUDE)
    assert execution.real_initial_value(index["sine"], vr["sine"]["omega[1]"], Q_OMEGA)

    recorder = CosimObserver.create_time_series(buffer_size=STEPS + 2)
    execution.add_observer(recorder)
    signals = [("plant", n) for n in names("x", (gains.plant.n,))]
    signals += [("observer", n) for n in names("x_hat", (gains.plant.n,))]
    for slave, name in signals:
        recorder.start_time_series(index[slave], vr[slave][name], CosimVariableType.REAL)
    assert execution.step(STEPS)
    columns = []
    for slave, name in signals:
        t_ns, _, samples = recorder.time_series_real_samples(
            index[slave], vr[slave][name], 1, STEPS)
        columns.append(samples)
    np.testing.assert_allclose(np.asarray(t_ns) * 1e-9, DT * np.arange(1, STEPS + 1),
                               rtol=0, atol=1e-12)
    execution.stop()
    data = np.column_stack(columns)
    return data[:, : gains.plant.n], data[:, gains.plant.n:]


def test_fmpy_coupled_loop_equals_in_process(open_fmu, tuned_design):
    x_ref, z_ref = in_process_loop(tuned_design)
    x_fmu, z_fmu = fmpy_loop(open_fmu, tuned_design)
    assert np.max(np.abs(z_ref)) > 0.1  # the estimate moved
    np.testing.assert_allclose(x_fmu, x_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(z_fmu, z_ref, rtol=0, atol=1e-12)


def test_libcosim_coupled_loop_equals_in_process(pendulum_fmus, tuned_design, tmp_path):
    x_ref, z_ref = in_process_loop(tuned_design)
    x_cosim, z_cosim = libcosim_loop(pendulum_fmus, tmp_path / "blocks", tuned_design)
    np.testing.assert_allclose(x_cosim, x_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(z_cosim, z_ref, rtol=0, atol=1e-9)


def ecos_loop(fmus: dict, block_dir, gains) -> tuple[np.ndarray, np.ndarray]:
    """The same system in Ecos (ecospy), sampled after every step."""
    from ecospy import EcosSimulation, EcosSimulationStructure

    from harness.blocks.build import block_fmu

    structure = EcosSimulationStructure()
    structure.add_model("plant", str(fmus["plant"]))
    structure.add_model("observer", str(fmus["observer"]))
    structure.add_model("gain", str(block_fmu("gain", (1, gains.plant.n), block_dir)))
    structure.add_model("sine", str(block_fmu("sine", (1,), block_dir)))
    pairs = [(f"plant::{a}", f"observer::{a}") for a in names("y", (gains.plant.k,))]
    pairs += [(f"observer::{a}", f"gain::{b}")
              for a, b in zip(names("x_hat", (gains.plant.n,)), names("u", (gains.plant.n,)),
                              strict=True)]
    pairs += [("gain::y[1]", "plant::u[1]"), ("gain::y[1]", "observer::u[1]"),
              ("sine::y[1]", "plant::q[1]")]
    for source, sink in pairs:
        structure.make_real_connection(source, sink)
    start = {f"gain::{n}": float(v) for n, v in zip(names("K", K.shape), K.ravel(), strict=True)}
    start |= {"sine::amplitude[1]": Q_AMPLITUDE, "sine::omega[1]": Q_OMEGA}
    structure.add_parameter_set("start", start)
    signals = [f"plant::{n}" for n in names("x", (gains.plant.n,))]
    signals += [f"observer::{n}" for n in names("x_hat", (gains.plant.n,))]
    rows = []
    with EcosSimulation(structure=structure, step_size=DT) as sim:
        sim.init(parameter_set="start")
        for _ in range(STEPS):
            sim.step()
            rows.append([sim.get_real(s) for s in signals])
        sim.terminate()
    data = np.array(rows)
    return data[:, : gains.plant.n], data[:, gains.plant.n:]


def test_ecos_coupled_loop_equals_in_process(pendulum_fmus, tuned_design, tmp_path):
    x_ref, z_ref = in_process_loop(tuned_design)
    x_ecos, z_ecos = ecos_loop(pendulum_fmus, tmp_path / "blocks", tuned_design)
    np.testing.assert_allclose(x_ecos, x_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(z_ecos, z_ref, rtol=0, atol=1e-9)
