"""Third-party models linearised by ``harness linearize`` against their Jacobians derived by
hand.

Usage::

    python bench/bench_linearize.py DCMOTOR.SSP [--vanderpol VANDERPOL.FMU]

- ``DCMOTOR.SSP``: OMSimulator's test DC motor (testsuite/tests/resources/dcmotor/: the SSD
  and Dymola 2024x's ``edrive_mass.fmu``, ``emachine_model.fmu``, ``stimuli_model.fmu``, ME +
  CS with linux64 binaries and directional derivatives) packed as an SSP (the SSD at the top,
  the FMUs under ``resources/``), linearised as ``--system DC-Motor.SuT --input U
  --unknown-input M_load --output phiB``. By hand, from the SSD's bindings (R, L, k of the
  electrical FMU, J, d of the mechanical one), in the motor's coordinates (i, phi, w):
  L di/dt = U - R i - k w, dphi/dt = w, J dw/dt = k i - d w + M_load, y = phi. The model's
  states are (damper.phi_rel, damper.w_rel, inductor.i) = (-phi, -w, i) (the damper's
  relative angle runs against the motor's), so the hand-derived matrices are compared in
  those coordinates, and the transfer functions U -> phiB and M_load -> phiB (which no
  change of coordinates alters) at s = 0.1j, 1j, 3+10j, 100j, 1000j.
- ``--vanderpol``: Reference-FMUs' VanDerPol.fmu (FMI 2.0 build), no input: linearised with
  no inputs at x = (1.5, -0.7), mu = 2 (``--set``), output x0, against
  A = [[0, 1], [-2 mu x0 x1 - 1, mu (1 - x0^2)]], C = [[1, 0]].

Each model with the default method and with each method forced; the table: model, n, method,
the largest relative error against the hand-derived matrices (max |difference| / max |entry|
over A, B, C, E) and of the transfer functions, and the wall time of the linearisation.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from harness.linearize import linearize
from harness.ssd import find_system, read_ssp, wiring

FREQUENCIES = np.array([0.1j, 1.0j, 3.0 + 10.0j, 100.0j, 1e3j])
DYMOLA_STATES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
"""x_model = T x_hand: (phi_rel, w_rel, i) = (-phi, -w, i)."""


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def transfer(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    n = A.shape[0]
    return np.array([C @ np.linalg.solve(s * np.eye(n) - A, B) for s in FREQUENCIES])


def dc_motor_hand(path: Path) -> dict[str, np.ndarray]:
    """The hand-derived A, B, C, E in the model's coordinates, from the SSD's bindings."""
    components = wiring(find_system(read_ssp(path), "DC-Motor.SuT")).components
    electrical = components["emachine_model"].parameters
    mechanical = components["edrive_mass"].parameters
    R, L, k = electrical["resistor.R"], electrical["inductor.L"], electrical["emf.k"]
    J, d = mechanical["inertia.J"], mechanical["damper.d"]
    A = np.array([[-R / L, 0.0, -k / L], [0.0, 0.0, 1.0], [k / J, 0.0, -d / J]])
    B = np.array([[1.0 / L], [0.0], [0.0]])
    C = np.array([[0.0, 1.0, 0.0]])
    E = np.array([[0.0], [0.0], [1.0 / J]])
    T = DYMOLA_STATES
    Ti = np.linalg.inv(T)
    return {"A": T @ A @ Ti, "B": T @ B, "C": C @ Ti, "E": T @ E,
            "parameters": {"R": R, "L": L, "k": k, "J": J, "d": d}}


def row(model: str, asked: str | None, run, hand: dict[str, np.ndarray], names: str) -> dict:
    start = time.perf_counter()
    lin = run()
    elapsed = time.perf_counter() - start
    matrices = max(relative(getattr(lin, name), hand[name]) for name in names)
    tf = max((relative(transfer(lin.A, getattr(lin, name), lin.C),
                       transfer(hand["A"], hand[name], hand["C"]))
              for name in names if name in "BE"), default=float("nan"))
    return {"model": model, "asked": asked or "default", "n": len(lin.states),
            "method": lin.method, "matrices": matrices,
            "tf": tf, "time": elapsed, "lin": lin}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ssp", type=Path, help="the DC motor SSP")
    parser.add_argument("--vanderpol", type=Path, help="Reference-FMUs' VanDerPol.fmu (FMI 2)")
    args = parser.parse_args()
    hand = dc_motor_hand(args.ssp)
    print("DC motor bindings:", hand.pop("parameters"))
    rows = []
    for method in (None, "directional", "differences"):
        rows.append(row("DC-Motor.SuT (Dymola 2024x)", method, lambda m=method: linearize(
            args.ssp, ["U"], ["phiB"], ["M_load"], system="DC-Motor.SuT", method=m),
            hand, "ABCE"))
    if args.vanderpol is not None:
        x0, x1, mu = 1.5, -0.7, 2.0
        A = np.array([[0.0, 1.0], [-2.0 * mu * x0 * x1 - 1.0, mu * (1.0 - x0 * x0)]])
        vdp = {"A": A, "C": np.array([[1.0, 0.0]])}
        for method in (None, "directional", "differences"):
            rows.append(row("VanDerPol (Reference-FMUs)", method, lambda m=method: linearize(
                args.vanderpol, [], ["x0"], start={"x0": x0, "x1": x1, "mu": mu}, method=m),
                vdp, "AC"))
    print("| model | n | asked | method used | max rel. error (A, B, C, E) "
          "| max rel. error (transfer) | time (s) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        tf = f"{r['tf']:.1e}" if np.isfinite(r["tf"]) else "-"
        print(f"| {r['model']} | {r['n']} | {r['asked']} | {r['method']} "
              f"| {r['matrices']:.1e} | {tf} | {r['time']:.3f} |")
    lin = rows[0]["lin"]
    print("\nDC motor, default method: states", lin.states)
    print("A =", lin.A.tolist(), "\nB =", lin.B.tolist(), "\nC =", lin.C.tolist(),
          "\nE =", lin.E.tolist())


if __name__ == "__main__":
    main()
