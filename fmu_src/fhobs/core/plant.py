"""Numpy-only LTI plant ``dx/dt = A x + B u + E q``, ``y = C x + eta`` with an exact ZOH step.

The measurement noise ``eta_k`` (uniform in [-a, a] per output) is a function of
``(seed, k)`` only, k being the number of steps taken: a restored state replays the same noise.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import numpy as np

from . import kernel as compiled
from .linalg import ZOH_CACHE_SIZE, zoh_blocks
from .validation import all_finite, as_finite_vector, check_step_size, floating_point_failure

NOISE_BLOCK = 1024
"""Noise samples are drawn in blocks of this many steps, block b from the seed (seed, b)."""

PLANT_SCHEMES = ("zoh", "euler")
"""``zoh``: exact step (default); ``euler``: explicit Euler, only to reproduce the paper's runs."""


def uniform_noise(seed: int, k: int, amplitude: float, size: int) -> np.ndarray:
    """Noise sample ``eta_k``: uniform in [-amplitude, amplitude]^size, a function of (seed, k).

    Parameters
    ----------
    seed : int
        Noise seed (non-negative).
    k : int
        Step index (non-negative).
    amplitude : float
        Half-width a of the uniform distribution; 0 gives zeros.
    size : int
        Number of outputs.
    """
    if amplitude == 0.0:
        return np.zeros(size)
    block, index = divmod(int(k), NOISE_BLOCK)
    draws = _noise_block(int(seed), block, size)
    return amplitude * draws[index]


def noise_samples(seed: int, count: int, amplitude: float, size: int) -> np.ndarray:
    """The noise samples ``eta_0 .. eta_{count - 1}`` (rows), each as :func:`uniform_noise`
    gives it.

    Examples
    --------
    >>> eta = noise_samples(3, 2000, 1e-3, 2)
    >>> eta.shape, bool(np.array_equal(eta[1500], uniform_noise(3, 1500, 1e-3, 2)))
    ((2000, 2), True)
    """
    if amplitude == 0.0:
        return np.zeros((count, size))
    blocks = [_noise_block(int(seed), block, size) for block in range(-(-count // NOISE_BLOCK))]
    return amplitude * np.concatenate(blocks or [np.zeros((0, size))])[:count]


_BLOCK_CACHE: dict[tuple[int, int, int], np.ndarray] = {}


def _noise_block(seed: int, block: int, size: int) -> np.ndarray:
    """Uniform [-1, 1] draws for steps ``block * NOISE_BLOCK ...``, cached (last few blocks)."""
    key = (seed, block, size)
    if key not in _BLOCK_CACHE:
        if len(_BLOCK_CACHE) > 64:
            _BLOCK_CACHE.clear()
        rng = np.random.default_rng([seed, block])
        _BLOCK_CACHE[key] = rng.uniform(-1.0, 1.0, size=(NOISE_BLOCK, size))
    return _BLOCK_CACHE[key]


class LTIPlant:
    """The plant, stepped exactly with u and q held (zero-order hold).

    Parameters
    ----------
    A, B, C : np.ndarray
        Plant matrices (n x n, n x m, k x n).
    E : np.ndarray or None
        Perturbation matrix (n x r); None means no perturbation input (r = 0).
    x0 : array_like or None
        Initial state (zeros if None).
    noise_amplitude : float
        Half-width a of the uniform measurement noise.
    seed : int
        Noise seed.
    scheme : str
        One of ``PLANT_SCHEMES``.
    kernel : bool
        Make the ``zoh`` step in the compiled kernel when it is available
        (:mod:`fhobs.core.kernel`); False: numpy only. The noise is numpy's either way.

    Examples
    --------
    A double integrator pushed by u = 1 for 0.1 s from x = (1, 0):

    >>> import numpy as np
    >>> plant = LTIPlant(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]),
    ...                  np.array([[1.0, 0.0]]), x0=[1.0, 0.0])
    >>> plant.step(u=[1.0], q=None, dt=0.1)
    >>> [round(float(v), 12) for v in plant.x]
    [1.005, 0.1]
    """

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        C: np.ndarray,
        E: np.ndarray | None = None,
        x0: np.ndarray | None = None,
        noise_amplitude: float = 0.0,
        seed: int = 0,
        scheme: str = "zoh",
        kernel: bool = True,
    ) -> None:
        if scheme not in PLANT_SCHEMES:
            raise ValueError(f"unknown plant scheme {scheme!r}; choose one of {PLANT_SCHEMES}")
        self.A = np.array(A, dtype=float, ndmin=2)
        self.B = np.array(B, dtype=float, ndmin=2)
        self.C = np.array(C, dtype=float, ndmin=2)
        n = self.A.shape[0]
        self.E = np.zeros((n, 0)) if E is None else np.array(E, dtype=float, ndmin=2)
        if not (noise_amplitude >= 0.0 and np.isfinite(noise_amplitude)):
            raise ValueError(f"noise_amplitude must be finite and >= 0, got {noise_amplitude}")
        if int(seed) < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self.noise_amplitude = float(noise_amplitude)
        self.seed = int(seed)
        self.scheme = scheme
        self._x = np.zeros(n) if x0 is None else as_finite_vector(x0, n, "x0")
        self._k = 0
        self._zoh: dict[float, list[np.ndarray]] = {}
        self._no_q = np.zeros(self.E.shape[1])
        library = compiled.library() if kernel and scheme == "zoh" else None
        self._stepper = None if library is None else compiled.Stepper(
            library.fhobs_plant_step, (n,), (self.B.shape[1], self.E.shape[1]),
            self._kernel_plan)

    @property
    def x(self) -> np.ndarray:
        """True state (copy)."""
        return self._x.copy()

    @property
    def y(self) -> np.ndarray:
        """Measured output ``C x_k + eta_k`` at the current step index k."""
        eta = uniform_noise(self.seed, self._k, self.noise_amplitude, self.C.shape[0])
        return self.C.dot(self._x) + eta

    def step(self, u: np.ndarray, q: np.ndarray | None, dt: float) -> None:
        """Advance by dt with u and q held; ``q`` may be None when the plant has no E.

        Raises
        ------
        ValueError
            On invalid u, q or dt, or if the state would overflow or the step raises a
            floating-point error (the state is then left unchanged).
        """
        r = self.E.shape[1]
        self.advance(as_finite_vector(u, self.B.shape[1], "u"),
                     None if q is None else as_finite_vector(q, r, "q"), check_step_size(dt))

    def advance(self, u: np.ndarray, q: np.ndarray | None, dt: float) -> None:
        """:meth:`step` without checking its arguments, for a caller that has: u (and q, if
        not None) finite float vectors of the right sizes, dt positive and finite."""
        if q is None:
            q = self._no_q
        stepper = self._stepper
        if stepper is not None:
            if stepper.run(dt, self._x, self._x, u, q) != compiled.OK:
                raise ValueError("the plant state overflowed; state left unchanged")
            self._x = stepper.state[0]
            self._k += 1
            return
        try:
            if self.scheme == "euler":
                x_new = self._x + dt * (self.A @ self._x + self.B @ u + self.E @ q)
            else:
                Phi, Gamma_B, Gamma_E = self._blocks(dt)
                x_new = Phi.dot(self._x) + Gamma_B.dot(u) + Gamma_E.dot(q)
        except ArithmeticError as err:
            raise floating_point_failure("plant", err) from err
        if not all_finite(x_new):
            raise ValueError("the plant state overflowed; state left unchanged")
        self._x = x_new
        self._k += 1

    @property
    def compiled(self) -> bool:
        """Whether the step runs in the compiled kernel (:mod:`fhobs.core.kernel`)."""
        return self._stepper is not None

    def kernel_handle(self, dt: float) -> compiled.StepperHandle:
        """The compiled step of size dt for a loop in C, from the current state
        (:meth:`fhobs.core.kernel.Stepper.handle`; ValueError if the plant is not
        :attr:`compiled`). The plant keeps its state and its step count (its state detached
        from the buffers the loop writes): the loop's steps do not advance it."""
        if self._stepper is None:
            raise ValueError("the plant does not step in the compiled kernel")
        self._x = self._x.copy()
        return self._stepper.handle(dt, self._x)

    def _kernel_plan(self, dt: float) -> None:
        """Register the kernel's plan for dt (the ZOH matrices)."""
        try:
            blocks = [np.ascontiguousarray(block) for block in self._blocks(dt)]
        except ArithmeticError as err:
            raise floating_point_failure("plant", err) from err
        n, m, r = (block.shape[1] for block in blocks)
        plan = compiled.PlantPlan(n, m, r, *(compiled.pointer(block) for block in blocks))
        self._stepper.add_plan(dt, plan, *blocks)

    def _blocks(self, dt: float) -> list[np.ndarray]:
        """ZOH matrices ``[expm(dt A), Gamma_B, Gamma_E]`` for the step dt (cached per dt)."""
        blocks = self._zoh.get(dt)
        if blocks is None:
            if len(self._zoh) >= ZOH_CACHE_SIZE:  # variable steps: keep the cache bounded
                self._zoh.clear()
            blocks = self._zoh[dt] = zoh_blocks(self.A, [self.B, self.E], dt)
        return blocks

    def get_state(self) -> np.ndarray:
        """Full state ``[x, k]`` (a copy; k is exact as a float below 2**53)."""
        return np.append(self._x, float(self._k))

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state returned by :meth:`get_state`."""
        arr = as_finite_vector(arr, self._x.size + 1, "plant state")
        self._x = arr[:-1].copy()
        self._k = int(arr[-1])
