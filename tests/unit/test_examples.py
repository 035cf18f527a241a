"""The Examples sections of the public modules' docstrings run and give what they print."""

import doctest
import importlib

import pytest

PUBLIC_MODULES = (
    "fhobs", "fhobs.design", "fhobs.spec", "fhobs.errors", "fhobs.limits", "fhobs.build",
    "fhobs.kalman", "fhobs.core.certificate", "fhobs.core.runtime", "fhobs.core.plant",
    "fhobs.core.kalman_filter", "fhobs.core.linalg",
)


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"


def test_public_functions_have_examples():
    from fhobs.build import build_fmus
    from fhobs.core.certificate import certify
    from fhobs.core.kalman_filter import KalmanObserver
    from fhobs.core.plant import LTIPlant
    from fhobs.core.runtime import (
        FilteringObserver,
        LuenbergerObserver,
        PrescribedTimeObserver,
    )
    from fhobs.design import design_for_spec, design_observer
    from fhobs.spec import load_spec, plant_spec

    for item in (build_fmus, certify, LTIPlant, FilteringObserver, LuenbergerObserver,
                 PrescribedTimeObserver, KalmanObserver,
                 design_for_spec, design_observer, load_spec, plant_spec):
        assert "Examples\n    --------\n    >>>" in item.__doc__ or (
            "Examples\n    --------\n    A " in item.__doc__), item.__qualname__
