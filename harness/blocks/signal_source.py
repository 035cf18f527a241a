"""The signal block's pythonfmu slave (FMI 2.0 co-simulation): a step, ramp, sine or random walk.

:class:`SignalSource` has the outputs ``y[1..n]`` and the parameters ``shape`` (Integer: 0 step,
1 ramp, 2 sine, 3 random walk, the order of :data:`SIGNAL_SHAPES`), ``size[i]``, ``start`` (s),
``frequency`` (Hz) and ``seed`` (Integer). Every output is 0 before ``start``; from it on::

    step         y[i](t) = size[i]
    ramp         y[i](t) = size[i] (t - start)
    sine         y[i](t) = size[i] sin(2 pi frequency (t - start))
    random_walk  y(t_k + h) = y(t_k) + size sqrt(h) w_k   for t_k >= start,
                 w_k ~ N(0, I) drawn in turn from numpy's default_rng(seed), one per doStep

After ``doStep(t, h)`` the outputs are the signal at ``t + h``; after ``setupExperiment(t0)``
they are the signal at ``t0`` (as the sine block's): under the Jacobi convention the value read
at ``t_k`` is the signal at ``t_k``, held by its reader over ``[t_k, t_k + h)``. A time counts as
reached ``start`` within 1e-9 of ``max(1, start)``. The random walk is a Wiener process of
intensity ``size`` (its variance grows by ``size^2`` per second) sampled at the communication
step; it is no FMU state: no rollback.

The module is self-contained (pythonfmu shares ``sys.modules`` between FMUs:
:mod:`harness.blocks.build` bakes the dimensions into a uniquely named copy of it).
"""

from __future__ import annotations

import math

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real

SIGNAL_SHAPES = ("step", "ramp", "sine", "random_walk")
START_TOLERANCE = 1e-9


class SignalSource(Fmi2Slave):
    """A vector signal of one shape from ``start`` on (module docstring)."""

    author = "fhobs harness"
    description = "Signal source: a step, ramp, sine or seeded random walk from t = start on"

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.n_outputs = n_outputs
        self.time = 0.0
        self.size = [0.0] * n_outputs
        self.reals = {"start": 0.0, "frequency": 0.0}
        self.integers = {"shape": 0, "seed": 0}
        self.walk = [0.0] * n_outputs
        self.rng = None
        for i in range(n_outputs):
            self._register_real(f"size[{i + 1}]", self.size, i)
        for name in self.reals:
            self._register_real(name, self.reals, name)
        for name in self.integers:
            self._register_integer(name)
        for i in range(n_outputs):
            self.register_variable(Real(
                f"y[{i + 1}]", causality=Fmi2Causality.output,
                variability=Fmi2Variability.continuous, initial=Fmi2Initial.exact,
                getter=lambda i=i: self.value(i)))

    def _register_real(self, name: str, store, key) -> None:
        def setter(v: float) -> None:
            store[key] = float(v)

        self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed,
                                    getter=lambda: store[key], setter=setter))

    def _register_integer(self, name: str) -> None:
        def setter(v: int) -> None:
            self.integers[name] = int(v)

        self.register_variable(Integer(name, causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed,
                                       getter=lambda: self.integers[name], setter=setter))

    @property
    def shape(self) -> str:
        """The shape's name; ValueError for an index outside :data:`SIGNAL_SHAPES`."""
        index = self.integers["shape"]
        if not 0 <= index < len(SIGNAL_SHAPES):
            raise ValueError(f"shape = {index} is not one of 0..{len(SIGNAL_SHAPES) - 1} "
                             f"({', '.join(SIGNAL_SHAPES)})")
        return SIGNAL_SHAPES[index]

    def _started(self, t: float) -> bool:
        start = self.reals["start"]
        return t >= start - START_TOLERANCE * max(1.0, abs(start))

    def value(self, i: int) -> float:
        """Output ``i`` (0-based) at the block's current time."""
        shape = self.shape
        if shape == "random_walk":
            return self.walk[i]
        if not self._started(self.time):
            return 0.0
        elapsed = self.time - self.reals["start"]
        if shape == "step":
            return self.size[i]
        if shape == "ramp":
            return self.size[i] * elapsed
        return self.size[i] * math.sin(2.0 * math.pi * self.reals["frequency"] * elapsed)

    def setup_experiment(self, start_time: float, stop_time, tolerance) -> None:
        self.time = float(start_time)

    def exit_initialization_mode(self) -> None:
        self.shape  # noqa: B018 - checks the shape index (ValueError: fmi2Error)
        if self.integers["seed"] < 0:
            raise ValueError(f"seed = {self.integers['seed']} must be >= 0")
        self.rng = np.random.default_rng(self.integers["seed"])
        self.walk = [0.0] * self.n_outputs

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.shape == "random_walk" and self._started(current_time):
            scale = math.sqrt(step_size)
            w = self.rng.standard_normal(self.n_outputs)
            self.walk = [v + s * scale * float(x)
                         for v, s, x in zip(self.walk, self.size, w, strict=True)]
        self.time = current_time + step_size
        return True
