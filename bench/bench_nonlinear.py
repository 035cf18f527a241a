"""A nonlinear plant written elsewhere: the Van der Pol oscillator FMU of modelica/Reference-FMUs.

Usage::

    python bench/bench_nonlinear.py --vdp PATH [--out DIR] [--pythonfmu]

PATH is the third-party FMU ``VanDerPol.fmu`` (FMI 2.0), or a Reference-FMUs build folder or
checkout holding it (``fmus/``, ``build/fmus/``). It is not shipped here; build it from the public
source (cmake and a C compiler, nothing downloaded; measured at commit 1258711a41e2)::

    git clone https://github.com/modelica/Reference-FMUs ref-fmus    # or a fetched snapshot:
    #   git --git-dir=SNAPSHOT archive HEAD | tar -x -C ref-fmus
    cmake -S ref-fmus -B ref-fmus/build-fmi2 -DFMI_VERSION=2 -DCMAKE_BUILD_TYPE=Release
    cmake --build ref-fmus/build-fmi2 --target VanDerPol    # -> build-fmi2/fmus/VanDerPol.fmu
    python bench/bench_nonlinear.py --vdp ref-fmus/build-fmi2/fmus/VanDerPol.fmu

The plant (``VanDerPol/model.c``): ``der(x0) = x1``, ``der(x1) = mu (1 - x0^2) x1 - x0``, mu = 1,
x(0) = (2, 0), no input, outputs x0 and x1; its co-simulation steps forward Euler at a fixed 10 ms
(``FIXED_SOLVER_STEP``), so the communication step is 10 ms (a shorter one sees a staircase).
The estimators are designed from ``bench/vanderpol.toml``: the linearisation at the origin,
``A = [[0, 1], [-1, mu]]``, ``y = x0``, the nonlinearity ``q = -mu x0^2 x1`` an unknown input
through ``E = [0; 1]``, disturbance_order 2 (q modelled as a ramp); u = 0.

Estimators (FMUs built here, native by default, ``--pythonfmu`` for the pythonfmu builds): the
filtering homogeneous observer with the disturbance model (observer.fmu), the Luenberger
observer (luenberger.fmu, no disturbance model), and the steady-state Kalman filter of the same
disturbance model (kalman.fmu, Ts = 10 ms, measurement std 0.01), twice: with the process
intensity W tuned noise-free and with W tuned on noisy data. All start at zero.

Runs (20 s, the FMU's default experiment):

- tuning: the oscillator from x(0) = (-1, 1) (fmpy), the Kalman filter run in-process
  (:class:`fhobs.core.kalman_filter.KalmanObserver`, the code inside kalman.fmu) for each W of the
  grid 10^(j/2), 1e-2 .. 1e8; the tuned W minimises the RMS of ``||x - x_hat||`` over the steady
  window, noise-free and with the noise of seed 10. The homogeneous observer's order (1 or 2) is
  compared on the same tuning data.
- evaluation, noise-free: the harness couples VanDerPol.fmu (``x0 -> y`` of every estimator,
  ``u = 0`` as a start value) with the estimators; fixed-step Jacobi, 10 ms.
- evaluation, noisy: the harness cannot add noise to a third-party FMU's output (no summing
  block; the gain block would delay y by one step; the signal block draws no white noise), so
  the oscillator's x0 recorded in the noise-free harness run plus Gaussian noise of std 0.01
  (numpy ``default_rng(seed)``, seeds 0..4) is fed to the estimator FMUs through fmpy in the
  harness's sequence (y_k set, then doStep(t_k, h)). With u = 0 nothing feeds back, so this is
  the coupled run; the same replay without noise is checked against the harness run.

Figures (as ``harness plant``): transient window [0, T_s], T_s the larger of the requested and the
predicted settling time; steady window [T_s, 20]; max and RMS of ``||x - x_hat||`` and
``|q - q_hat|`` (q_hat[1]); the noisy ones are means over the five seeds. Printed: the Kalman
tuning grid, the order comparison, the noise-free and the noisy tables, and the oscillator's
Euler half-step (h/2)|dx1/dt| (what its x1 samples differ from the velocity a continuous model
sees in its x0 samples: the noise-free floor of the continuous-time observers). Every draw is
seeded: the same command prints the same numbers (about 30 s on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tomllib
from pathlib import Path

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.runtime import FilteringObserver
from fhobs.design.kalman import with_kalman
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import PlantSpec, spec_from_dict
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave

from harness.master import CoSimResult, run_system
from harness.own_plant import transient_end
from harness.results import window_mask
from harness.system import load_system, resolve_system

SPEC = Path(__file__).with_name("vanderpol.toml")
STEP = 1e-2
STOP_TIME = 20.0
NOISE_STD = 0.01
TUNING_SEED = 10
EVAL_SEEDS = (0, 1, 2, 3, 4)
TUNING_X0 = (-1.0, 1.0)
INTENSITIES = 10.0 ** np.arange(-2.0, 8.25, 0.5)
ORDERS = (1, 2)
FIGURES = ("x_max_tr", "x_rms_tr", "x_max_st", "x_rms_st",
           "q_max_tr", "q_rms_tr", "q_max_st", "q_rms_st")
BUILD_HELP = (
    "build it from modelica/Reference-FMUs (see this script's docstring):\n"
    "  cmake -S ref-fmus -B ref-fmus/build-fmi2 -DFMI_VERSION=2 -DCMAKE_BUILD_TYPE=Release\n"
    "  cmake --build ref-fmus/build-fmi2 --target VanDerPol\n"
    "then pass --vdp ref-fmus/build-fmi2/fmus/VanDerPol.fmu"
)


@dataclasses.dataclass(frozen=True)
class Data:
    """One run of the oscillator: times, true states (x0, x1), true q, measured y."""

    t: np.ndarray
    x: np.ndarray
    q: np.ndarray
    y: np.ndarray


def find_vdp(path: Path | None) -> Path:
    """The VanDerPol.fmu at ``path`` (the file, or a build folder or checkout holding it)."""
    if path is None:
        sys.exit("bench_nonlinear: no third-party FMU given (--vdp PATH to VanDerPol.fmu);\n"
                 + BUILD_HELP)
    candidates = [path] if path.suffix == ".fmu" else [
        path / "VanDerPol.fmu", path / "fmus" / "VanDerPol.fmu",
        path / "build" / "fmus" / "VanDerPol.fmu", path / "build-fmi2" / "fmus" / "VanDerPol.fmu"]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    sys.exit(f"bench_nonlinear: no VanDerPol.fmu at {path} (looked for "
             f"{', '.join(str(c) for c in candidates)});\n" + BUILD_HELP)


def oscillator_mu(fmu: Path) -> float:
    """mu of the FMU (its start value), after checking it is the FMI 2.0 oscillator expected."""
    md = read_model_description(str(fmu))
    names = {v.name: v for v in md.modelVariables}
    if md.fmiVersion != "2.0" or md.coSimulation is None or not {"x0", "x1", "mu"} <= set(names):
        sys.exit(f"bench_nonlinear: {fmu} is not the FMI 2.0 co-simulation VanDerPol FMU "
                 "(outputs x0, x1, parameter mu); build it with -DFMI_VERSION=2.\n" + BUILD_HELP)
    return float(names["mu"].start)


def true_q(x: np.ndarray, mu: float) -> np.ndarray:
    """The unknown input of the linearisation: q = -mu x0^2 x1."""
    return -mu * x[:, 0] ** 2 * x[:, 1]


def euler_floor(data: Data, mu: float, t_s: float) -> tuple[float, float]:
    """Max and RMS over the steady window of (STEP / 2) |dx1/dt|: how far the oscillator's
    forward-Euler x1 sample lies from the velocity its x0 samples show a continuous model."""
    x0, x1 = data.x[:, 0], data.x[:, 1]
    e = 0.5 * STEP * np.abs(mu * (1.0 - x0**2) * x1 - x0)[windows(data.t, t_s)["st"]]
    return float(np.max(e)), float(np.sqrt(np.mean(e**2)))


def noisy(y: np.ndarray, seed: int) -> np.ndarray:
    """``y`` plus Gaussian noise of std NOISE_STD from numpy's default_rng(seed)."""
    return y + NOISE_STD * np.random.default_rng(seed).standard_normal(y.shape)


def record_oscillator(fmu: Path, x0: tuple[float, float], mu: float) -> Data:
    """The oscillator alone from ``x0`` (fmpy's simulate_fmu, output every STEP), noise-free."""
    r = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=STOP_TIME,
                     output_interval=STEP, start_values={"x0": x0[0], "x1": x0[1]},
                     output=["x0", "x1"])
    x = np.column_stack([r["x0"], r["x1"]])
    return Data(np.asarray(r["time"]), x, true_q(x, mu), x[:, 0].copy())


def design(order: int | None = None) -> tuple[PlantSpec, ObserverDesign]:
    """The spec of bench/vanderpol.toml (with another disturbance order if given), its design."""
    data = tomllib.loads(SPEC.read_text())
    if order is not None:
        data["observer"]["disturbance_order"] = data["noise"]["disturbance_order"] = order
    spec = spec_from_dict(data, source=str(SPEC))
    return spec, design_for_spec(spec)


def with_intensity(spec: PlantSpec, gains: ObserverDesign, intensity: float,
                   tuning: str) -> ObserverDesign:
    """``gains`` with the spec's Kalman filter at process intensity ``intensity``."""
    noise = dataclasses.replace(spec.noise, process_intensity=float(intensity))
    return with_kalman(gains, noise, tuning=tuning)


def run_in_process(estimator: FilteringObserver | KalmanObserver, y: np.ndarray) -> np.ndarray:
    """Model states z (x_hat, then q_hat) at every sample, y_k held over [t_k, t_k + STEP)."""
    z = [estimator.z]
    zero = np.zeros(1)
    for value in y[:-1]:
        estimator.step(np.array([value]), zero, STEP)
        z.append(estimator.z)
    return np.array(z)


def windows(t: np.ndarray, t_s: float) -> dict[str, np.ndarray]:
    """Masks of the transient window [0, t_s] and the steady window [t_s, end]."""
    return {"tr": window_mask(t, 0.0, t_s), "st": window_mask(t, t_s, float(t[-1]))}


def figures(data: Data, z: np.ndarray, q_hat: bool, t_s: float) -> dict[str, float]:
    """Max and RMS of ||x - x_hat|| (and |q - q_hat[1]|) over both windows."""
    errors = {"x": np.linalg.norm(data.x - z[:, :2], axis=1)}
    if q_hat:
        errors["q"] = np.abs(data.q - z[:, 2])
    out = {}
    for key, mask in windows(data.t, t_s).items():
        for name, e in errors.items():
            out[f"{name}_max_{key}"] = float(np.max(e[mask]))
            out[f"{name}_rms_{key}"] = float(np.sqrt(np.mean(e[mask] ** 2)))
    return out


def tune_kalman(spec: PlantSpec, gains: ObserverDesign, tuning: Data,
                t_s: float) -> tuple[dict[str, float], list[tuple[float, float, float]]]:
    """The W of INTENSITIES with the least steady RMS on the tuning data, noise-free and noisy
    (seed TUNING_SEED); returns ``{"clean": W, "noisy": W}`` and the grid's (W, rms, rms)."""
    measured = {"clean": tuning.y, "noisy": noisy(tuning.y, TUNING_SEED)}
    grid = []
    for w in INTENSITIES:
        g = with_intensity(spec, gains, w, "grid")
        rms = [figures(tuning, run_in_process(KalmanObserver(g.kalman), measured[key]), False,
                       t_s)["x_rms_st"] for key in ("clean", "noisy")]
        grid.append((float(w), rms[0], rms[1]))
    best = {key: min(grid, key=lambda row: row[col])[0]
            for col, key in ((1, "clean"), (2, "noisy"))}
    return best, grid


def compare_orders(tuning: Data, t_s: float) -> dict[int, dict[str, dict[str, float]]]:
    """The homogeneous observer of each order of ORDERS on the tuning data, clean and noisy."""
    measured = {"clean": tuning.y, "noisy": noisy(tuning.y, TUNING_SEED)}
    out = {}
    for order in ORDERS:
        _, gains = design(order)
        out[order] = {key: figures(tuning, run_in_process(FilteringObserver(gains.filtering), y),
                                   True, t_s)
                      for key, y in measured.items()}
    return out


def build(gains: ObserverDesign, out: Path, kinds: list[str], native: bool) -> dict[str, Path]:
    """The FMUs ``kinds`` of ``gains`` in ``out`` (native or pythonfmu)."""
    if native:
        from fhobs.native.build import build_native_fmus

        return build_native_fmus(gains, out, kinds=kinds, steps=[STEP])
    from fhobs.build import build_fmus

    return build_fmus(gains, out, kinds=kinds)


def build_estimators(spec: PlantSpec, gains: ObserverDesign, tuned: dict[str, float], out: Path,
                     native: bool) -> dict[str, Path]:
    """observer, luenberger and the two tuned Kalman filters; ``{estimator name: fmu}``."""
    if out.exists():
        shutil.rmtree(out)
    fmus = build(gains, out / "observers", ["observer", "luenberger"], native)
    paths = {"homogeneous": fmus["observer"], "luenberger": fmus["luenberger"]}
    for key, w in tuned.items():
        g = with_intensity(spec, gains, w, f"bench_nonlinear: tuned {key}, W = {w:g}")
        paths[f"kalman_{key}"] = build(g, out / f"kalman_{key}", ["kalman"], native)["kalman"]
    return paths


def system_toml(vdp: Path, estimators: dict[str, Path], record: list[str]) -> str:
    """The harness system: the oscillator's x0 into every estimator's y, u = 0."""
    lines = ['name = "vanderpol_nonlinear"', "[run]", f"step = {STEP!r}",
             f"stop_time = {STOP_TIME!r}", f"record = {json.dumps(record)}",
             "[fmus.vdp]", f"path = {json.dumps(str(vdp))}"]
    for name, path in estimators.items():
        lines += [f"[fmus.{name}]", f"path = {json.dumps(str(path))}", 'start = { "u[1]" = 0.0 }']
    for name in estimators:
        lines += ["[[connections]]", 'from = "vdp.x0"', f'to = "{name}.y"']
    return "\n".join(lines) + "\n"


def has_q_hat(fmu: Path) -> bool:
    """Whether the FMU has the output q_hat[1]."""
    return any(v.name == "q_hat[1]" for v in read_model_description(str(fmu)).modelVariables)


def model_states(result: CoSimResult, name: str, q_hat: bool) -> np.ndarray:
    """x_hat (and q_hat[1]) of estimator ``name`` from a harness result."""
    z = result.vector(f"{name}.x_hat")
    return np.column_stack([z, result.signal(f"{name}.q_hat[1]")]) if q_hat else z


def run_harness(vdp: Path, estimators: dict[str, Path], out: Path,
                mu: float) -> tuple[Data, dict[str, np.ndarray]]:
    """The noise-free coupled run through the harness; the oscillator's data and the estimates."""
    q_names = [n for n, p in estimators.items() if has_q_hat(p)]
    record = ["vdp.x1"] + [f"{n}.x_hat" for n in estimators] + [f"{n}.q_hat" for n in q_names]
    path = out / "vanderpol_nonlinear.toml"
    path.write_text(system_toml(vdp, estimators, record))
    result = run_system(resolve_system(load_system(path)))
    x = np.column_stack([result.signal("vdp.x0"), result.signal("vdp.x1")])
    data = Data(result.time, x, true_q(x, mu), x[:, 0].copy())
    return data, {n: model_states(result, n, n in q_names) for n in estimators}


def unpack(estimators: dict[str, Path], scratch: Path) -> dict[str, Path]:
    """Each estimator FMU extracted once (a loaded FMU's library is never overwritten)."""
    if scratch.exists():
        shutil.rmtree(scratch)
    return {name: Path(extract(str(fmu), str(scratch / name))) for name, fmu in estimators.items()}


def replay_fmu(unpacked: Path, y: np.ndarray) -> np.ndarray:
    """An extracted estimator FMU fed ``y`` through fmpy in the harness's sequence (y_k set,
    then doStep(t_k, STEP)); its model states at every sample."""
    md = read_model_description(str(unpacked / "modelDescription.xml"))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [vr["x_hat[1]"], vr["x_hat[2]"]] + ([vr["q_hat[1]"]] if "q_hat[1]" in vr else [])
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unpacked),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=unpacked.name)
    slave.instantiate()
    try:
        slave.setupExperiment(startTime=0.0, stopTime=STOP_TIME)
        slave.setReal([vr["u[1]"]], [0.0])
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        z = [slave.getReal(outputs)]
        for k, value in enumerate(y[:-1]):
            slave.setReal([vr["y[1]"]], [float(value)])
            slave.doStep(currentCommunicationPoint=k * STEP, communicationStepSize=STEP)
            z.append(slave.getReal(outputs))
        slave.terminate()
    finally:
        slave.freeInstance()
    return np.array(z)


def replay_all(unpacked: dict[str, Path], y: np.ndarray) -> dict[str, np.ndarray]:
    """Every estimator FMU fed the same ``y``."""
    return {name: replay_fmu(path, y) for name, path in unpacked.items()}


def mean_figures(per_seed: list[dict[str, float]]) -> dict[str, float]:
    """The mean over seeds of each figure."""
    return {key: float(np.mean([f[key] for f in per_seed])) for key in per_seed[0]}


def table(rows: dict[str, dict[str, float]]) -> str:
    """A markdown table of FIGURES per row ('-': no q_hat)."""
    head = "| estimator | " + " | ".join(FIGURES) + " |"
    lines = [head, "|---" * (len(FIGURES) + 1) + "|"]
    for name, f in rows.items():
        cells = [f"{f[k]:.3g}" if k in f else "-" for k in FIGURES]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def tuning_table(grid: list[tuple[float, float, float]], tuned: dict[str, float]) -> str:
    """The Kalman grid: steady RMS on the tuning run per W, the tuned ones marked."""
    lines = ["| W | steady RMS, noise-free | steady RMS, noisy (seed 10) |", "|---|---|---|"]
    for w, clean, noise in grid:
        mark = {key: " *" if tuned[key] == w else "" for key in tuned}
        lines.append(f"| {w:.3g} | {clean:.4g}{mark['clean']} | {noise:.4g}{mark['noisy']} |")
    return "\n".join(lines)


def order_table(orders: dict[int, dict[str, dict[str, float]]]) -> str:
    """The homogeneous observer's order comparison on the tuning data."""
    lines = ["| order | x_max_tr | x_rms_st clean | q_rms_st clean | x_rms_st noisy | "
             "q_rms_st noisy |", "|---|---|---|---|---|---|"]
    for order, f in orders.items():
        lines.append(f"| {order} | {f['clean']['x_max_tr']:.3g} | {f['clean']['x_rms_st']:.3g} | "
                     f"{f['clean']['q_rms_st']:.3g} | {f['noisy']['x_rms_st']:.3g} | "
                     f"{f['noisy']['q_rms_st']:.3g} |")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vdp", type=Path, help="VanDerPol.fmu, or a Reference-FMUs build "
                        "folder or checkout holding it")
    parser.add_argument("--out", type=Path, default=Path("out/nonlinear"),
                        help="work folder (FMUs, system file); default out/nonlinear")
    parser.add_argument("--pythonfmu", action="store_true",
                        help="the pythonfmu FMUs instead of the native ones")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    vdp = find_vdp(args.vdp)
    mu = oscillator_mu(vdp)
    spec, gains = design()
    if gains.plant.A[1, 1] != mu:
        sys.exit(f"bench_nonlinear: {SPEC.name} linearises at mu = {gains.plant.A[1, 1]:g}, "
                 "the FMU "
                 f"has mu = {mu:g}")
    t_s = transient_end(gains, spec.settling_time, STEP, STOP_TIME)
    print(f"third-party FMU: {vdp} (mu = {mu:g}); step {STEP:g} s, {STOP_TIME:g} s; "
          f"disturbance_order {gains.model.disturbance_order}, nu = {gains.model.nu:g}, "
          f"rho = {gains.filtering.rho:g}; "
          f"windows [0, {t_s:g}] and [{t_s:g}, {STOP_TIME:g}] s")

    tuning = record_oscillator(vdp, TUNING_X0, mu)
    tuned, grid = tune_kalman(spec, gains, tuning, t_s)
    print(f"\nKalman tuning (oscillator from x(0) = {TUNING_X0}, in-process filter):\n"
          + tuning_table(grid, tuned))
    print(f"tuned W: noise-free {tuned['clean']:.3g}, noisy {tuned['noisy']:.3g}"
          + ("  (at the grid's edge)" if {INTENSITIES[0], INTENSITIES[-1]} & set(tuned.values())
             else ""))
    print("\nhomogeneous observer, disturbance order (tuning data):\n"
          + order_table(compare_orders(tuning, t_s)))

    out = args.out.resolve()
    estimators = build_estimators(spec, gains, tuned, out / "fmus", not args.pythonfmu)
    data, coupled = run_harness(vdp, estimators, out, mu)
    clean = {n: figures(data, z, z.shape[1] > 2, t_s) for n, z in coupled.items()}
    unpacked = unpack(estimators, out / "replay")
    check = replay_all(unpacked, data.y)
    gap = max(float(np.max(np.abs(check[n] - coupled[n]))) for n in estimators)
    print(f"\nnoise-free, coupled in the harness ({'pythonfmu' if args.pythonfmu else 'native'} "
          f"FMUs; fmpy replay of the recorded x0 equals it to {gap:.1e}):\n" + table(clean))
    print("Euler half-step of the oscillator, (h/2)|dx1/dt| over the steady window: "
          "max {:.3g}, RMS {:.3g}".format(*euler_floor(data, mu, t_s)))

    per_seed = [{n: figures(data, z, z.shape[1] > 2, t_s) for n, z in
                 replay_all(unpacked, noisy(data.y, seed)).items()}
                for seed in EVAL_SEEDS]
    noisy_rows = {n: mean_figures([s[n] for s in per_seed]) for n in estimators}
    print(f"\nnoisy (Gaussian std {NOISE_STD:g} on x0; mean over seeds {EVAL_SEEDS}):\n"
          + table(noisy_rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
