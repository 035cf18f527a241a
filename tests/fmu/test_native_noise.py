"""The native plant's measurement noise (``fhobs/native/noise.c``) against numpy's generator.

The pythonfmu plant draws its noise from ``numpy.random.default_rng([seed, block])``; the
native plant must draw the very same numbers so that a scenario gives the same results with
either FMU. numpy is the independent reference here.
"""

from __future__ import annotations

import ctypes
import shutil
from pathlib import Path

import fhobs.native
import numpy as np
import pytest
from fhobs.core.kernel import compile_source
from fhobs.core.plant import NOISE_BLOCK, uniform_noise

NOISE_SOURCE = Path(fhobs.native.__file__).with_name("noise.c")

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")


@pytest.fixture(scope="module")
def noise_block(tmp_path_factory):
    target = tmp_path_factory.mktemp("noise") / "noise.so"
    compile_source(NOISE_SOURCE, target, "cc", ("-O2", "-shared", "-fPIC", "-DFHOBS_EXPORT"))
    function = ctypes.CDLL(str(target)).fhobs_noise_block
    function.argtypes = [ctypes.c_uint32, ctypes.c_uint32, ctypes.c_size_t, ctypes.c_void_p]
    function.restype = None

    def draw(seed: int, block: int, count: int) -> np.ndarray:
        out = np.full(count, np.nan)
        function(seed, block, count, out.ctypes.data)
        return out

    return draw


def test_bit_equal_to_numpy_default_rng_over_seeds_and_blocks(noise_block):
    pairs = np.random.default_rng(20261123).integers(0, 2**32, size=(40, 2))
    pairs = [(0, 0), (1, 0), (0, 1), (2**32 - 1, 2**32 - 1), *map(tuple, pairs.tolist())]
    for seed, block in pairs:
        expected = np.random.default_rng([seed, block]).uniform(-1.0, 1.0, size=3 * NOISE_BLOCK)
        assert np.array_equal(noise_block(seed, block, 3 * NOISE_BLOCK), expected), (seed, block)


def test_the_plants_noise_sequence_is_reproduced(noise_block):
    """eta_k of the numpy plant (2 outputs, amplitude 1e-3) for steps across block bounds."""
    amplitude, size, seed = 1e-3, 2, 7
    for k in (0, 1, NOISE_BLOCK - 1, NOISE_BLOCK, 5 * NOISE_BLOCK + 17):
        block, index = divmod(k, NOISE_BLOCK)
        draws = noise_block(seed, block, NOISE_BLOCK * size).reshape(NOISE_BLOCK, size)
        assert np.array_equal(amplitude * draws[index], uniform_noise(seed, k, amplitude, size))


def test_a_different_seed_or_block_gives_different_draws(noise_block):
    first = noise_block(5, 0, 64)
    assert not np.array_equal(first, noise_block(6, 0, 64))
    assert not np.array_equal(first, noise_block(5, 1, 64))
    assert np.all(np.abs(first) <= 1.0)
