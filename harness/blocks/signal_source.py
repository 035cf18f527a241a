"""The seeded sources' pythonfmu slaves (FMI 2.0 co-simulation): the signal and the noise block.

:class:`SignalSource` has the outputs ``y[1..n]`` and the parameters ``shape`` (Integer: 0 step,
1 ramp, 2 sine, 3 random walk, the order of :data:`SIGNAL_SHAPES`), ``size[i]``, ``start`` (s),
``frequency`` (Hz) and ``seed`` (Integer). Every output is 0 before ``start``; from it on::

    step         y[i](t) = size[i]
    ramp         y[i](t) = size[i] (t - start)
    sine         y[i](t) = size[i] sin(2 pi frequency (t - start))
    random_walk  y(t_k + h) = y(t_k) + size sqrt(h) w_j   for t_k >= start,
                 w_j = gaussian(draw j of the seed), j = 0, 1, ... one per doStep from start on

:class:`NoiseSource` has the outputs ``y[1..n]`` and the parameters ``distribution`` (Integer:
0 uniform, 1 gaussian, the order of :data:`NOISE_DISTRIBUTIONS`), ``size[i]`` (the uniform
noise's amplitude, or the Gaussian noise's standard deviation) and ``seed`` (Integer): white
noise, ``y[i] = size[i] u_i`` (uniform in [-size, size)) or ``size[i] w_i`` of draw ``k`` of the
seed, ``k`` the number of doSteps since initialisation (one draw per step, held over it).

The draws are the product's portable generator (the native plant's measurement noise,
``fhobs/native/noise.c``, whose C code the native blocks compile): draw ``k`` is row
``k mod NOISE_BLOCK`` of ``numpy.random.default_rng([seed, k // NOISE_BLOCK]).uniform(-1, 1,
(NOISE_BLOCK, 2 n))``, its first n numbers ``v`` and last n ``v'``: uniform noise takes ``v``,
a Gaussian number is the Box-Muller transform ``sqrt(-2 log((1 - v_i) / 2)) cos(pi v'_i)``.
So the native blocks (:mod:`harness.blocks.native`) draw the same numbers; the random walk's
increments are these Gaussians (they are not numpy's ``default_rng(seed).standard_normal``).

After ``doStep(t, h)`` the outputs are the signal at ``t + h``; after ``setupExperiment(t0)``
they are the signal at ``t0`` (as the sine block's): under the Jacobi convention the value read
at ``t_k`` is the signal at ``t_k``, held by its reader over ``[t_k, t_k + h)``. A time counts as
reached ``start`` within 1e-9 of ``max(1, start)``. The random walk is a Wiener process of
intensity ``size`` (its variance grows by ``size^2`` per second) sampled at the communication
step; neither block has FMU states: no rollback.

The outputs are ``initial="calculated"``, initial unknowns depending on the parameters they
are computed from, as the blocks of :mod:`harness.blocks.slaves`.

The module is self-contained at run time (pythonfmu shares ``sys.modules`` between FMUs:
:mod:`harness.blocks.build` bakes the dimensions into a uniquely named copy of it); only the
build's model description takes a function of :mod:`harness.blocks.slaves`.
"""

from __future__ import annotations

import math
from xml.etree.ElementTree import Element

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real

SIGNAL_SHAPES = ("step", "ramp", "sine", "random_walk")
NOISE_DISTRIBUTIONS = ("uniform", "gaussian")
START_TOLERANCE = 1e-9
NOISE_BLOCK = 1024
"""Draws per generator block (block b of a seed from ``default_rng([seed, b])``), as the plant's
measurement noise."""


def gaussian(v: float, w: float) -> float:
    """A standard normal number from two uniform numbers of [-1, 1) (Box-Muller).

    Examples
    --------
    >>> gaussian(0.0, 0.0) == math.sqrt(2.0 * math.log(2.0))
    True
    """
    return math.sqrt(-2.0 * math.log(0.5 * (1.0 - v))) * math.cos(math.pi * w)


class Draws:
    """The uniform draws of a seed, ``2 width`` numbers of [-1, 1) per draw index (module
    docstring), one generator block held.

    Examples
    --------
    >>> row = Draws(3, 2).row(1500)
    >>> expected = np.random.default_rng([3, 1]).uniform(-1, 1, (NOISE_BLOCK, 4))[1500 - 1024]
    >>> row == expected.tolist()
    True
    """

    def __init__(self, seed: int, width: int) -> None:
        self.seed, self.width = seed, width
        self.block, self.rows = -1, None

    def row(self, k: int) -> list[float]:
        """Draw ``k``: its ``2 width`` uniform numbers."""
        block, index = divmod(k, NOISE_BLOCK)
        if block != self.block:
            rng = np.random.default_rng([self.seed, block])
            self.rows = rng.uniform(-1.0, 1.0, size=(NOISE_BLOCK, 2 * self.width))
            self.block = block
        return self.rows[index].tolist()


class SeededSource(Fmi2Slave):
    """What the two blocks share: fixed parameters, the outputs ``y[i]``, a seed and an
    Integer parameter naming a choice of ``choices`` (its name ``selector``)."""

    author = "fhobs harness"
    selector = ""
    choices: tuple[str, ...] = ()

    def __init__(self, n_outputs: int, reals: tuple[str, ...], **kwargs) -> None:
        super().__init__(**kwargs)
        self.n_outputs = n_outputs
        self.time = 0.0
        self.size = [0.0] * n_outputs
        self.reals = dict.fromkeys(reals, 0.0)
        self.integers = {self.selector: 0, "seed": 0}
        for i in range(n_outputs):
            self._register_real(f"size[{i + 1}]", self.size, i)
        for name in self.reals:
            self._register_real(name, self.reals, name)
        for name in self.integers:
            self._register_integer(name)
        for i in range(n_outputs):
            self.register_variable(Real(
                f"y[{i + 1}]", causality=Fmi2Causality.output,
                variability=Fmi2Variability.continuous, initial=Fmi2Initial.calculated,
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
    def choice(self) -> str:
        """The selected choice's name; ValueError for an index outside :attr:`choices`."""
        index = self.integers[self.selector]
        if not 0 <= index < len(self.choices):
            raise ValueError(f"{self.selector} = {index} is not one of 0..{len(self.choices) - 1}"
                             f" ({', '.join(self.choices)})")
        return self.choices[index]

    @property
    def seed(self) -> int:
        """The seed; ValueError when negative."""
        if self.integers["seed"] < 0:
            raise ValueError(f"seed = {self.integers['seed']} must be >= 0")
        return self.integers["seed"]

    def value(self, i: int) -> float:
        """Output ``i`` (0-based) at the block's current time."""
        raise NotImplementedError

    def knowns_of(self, i: int, inputs: list[str]) -> list[str]:
        """The parameters output ``i`` (0-based) is computed from: all but the other outputs'
        sizes (there are no ``inputs``)."""
        return [f"size[{i + 1}]", *self.reals, *self.integers]

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description with the outputs' dependencies (none) and initial
        unknowns (:meth:`knowns_of`) declared. Only the build calls it, in the harness's
        process, hence the import of :func:`harness.blocks.slaves.declare_structure` here."""
        from harness.blocks.slaves import declare_structure

        root = super().to_xml(model_options if model_options is not None else {})
        return declare_structure(root, lambda i, inputs: [], self.knowns_of)

    def setup_experiment(self, start_time: float, stop_time, tolerance) -> None:
        self.time = float(start_time)


class SignalSource(SeededSource):
    """A vector signal of one shape from ``start`` on (module docstring)."""

    description = "Signal source: a step, ramp, sine or seeded random walk from t = start on"
    selector = "shape"
    choices = SIGNAL_SHAPES

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(n_outputs, ("start", "frequency"), **kwargs)
        self.walk = [0.0] * n_outputs
        self.draws = Draws(0, n_outputs)
        self.steps = 0

    def _started(self, t: float) -> bool:
        start = self.reals["start"]
        return t >= start - START_TOLERANCE * max(1.0, abs(start))

    def value(self, i: int) -> float:
        shape = self.choice
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

    def exit_initialization_mode(self) -> None:
        self.choice  # noqa: B018 - checks the shape index (ValueError: fmi2Error)
        self.draws = Draws(self.seed, self.n_outputs)
        self.walk = [0.0] * self.n_outputs
        self.steps = 0

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.choice == "random_walk" and self._started(current_time):
            scale = math.sqrt(step_size)
            row = self.draws.row(self.steps)
            self.steps += 1
            n = self.n_outputs
            self.walk = [v + s * scale * gaussian(row[i], row[n + i])
                         for i, (v, s) in enumerate(zip(self.walk, self.size, strict=True))]
        self.time = current_time + step_size
        return True


class NoiseSource(SeededSource):
    """Seeded white noise, one draw per doStep (module docstring)."""

    description = "Noise source: seeded uniform or Gaussian white noise, one draw per step"
    selector = "distribution"
    choices = NOISE_DISTRIBUTIONS

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(n_outputs, (), **kwargs)
        self.steps = 0
        self.draws = Draws(0, n_outputs)

    def value(self, i: int) -> float:
        distribution = self.choice
        if self.draws.seed != self.seed:
            self.draws = Draws(self.seed, self.n_outputs)
        row = self.draws.row(self.steps)
        if distribution == "uniform":
            return self.size[i] * row[i]
        return self.size[i] * gaussian(row[i], row[self.n_outputs + i])

    def exit_initialization_mode(self) -> None:
        self.choice  # noqa: B018 - checks the distribution index (ValueError: fmi2Error)
        self.draws = Draws(self.seed, self.n_outputs)
        self.steps = 0

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.steps += 1
        self.time = current_time + step_size
        return True
