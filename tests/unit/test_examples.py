"""The Examples sections of the public modules' docstrings run and give what they print."""

import doctest
import importlib

import pytest

PUBLIC_MODULES = (
    "fhobs", "fhobs.cli", "fhobs.design.observer", "fhobs.design.spec", "fhobs.errors",
    "fhobs.design.limits", "fhobs.design.feedback", "fhobs.design.cache", "fhobs.build",
    "fhobs.core.cache_files",
    "fhobs.design.kalman", "fhobs.core.certificate", "fhobs.core.runtime", "fhobs.core.plant",
    "fhobs.core.kalman_filter", "fhobs.core.linalg", "fhobs.paper", "harness.reference",
    "fhobs.design.settling", "fhobs.core.disturbance", "fhobs.native.build",
    "harness.system", "harness.master", "harness.ssp", "harness.results", "harness.fmu_files",
    "fhobs.fmu.kinds", "fhobs.core.gains",
    "harness.figures", "harness.zoo", "harness.cli",
    "fhobs.design.partial", "fhobs.design.supervised", "fhobs.core.supervisor",
    "harness.writing", "harness.engine_log",
    # a tuning search (~15 s) of the spec of the command-line tests of --tune-noise: with them
    # on one worker, one search and then the user's cache
    pytest.param("fhobs.design.tuning",
                 marks=[pytest.mark.slow, pytest.mark.xdist_group("noise_tuning")]),
)


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"


def test_public_functions_have_examples():
    from fhobs.build import build_fmus
    from fhobs.core.certificate import (
        certify,
        certify_filtering,
        certify_kalman,
        certify_luenberger,
        certify_parts,
        certify_prescribed_time,
    )
    from fhobs.core.disturbance import extended_model
    from fhobs.core.gains import ObserverDesign
    from fhobs.core.kalman_filter import KalmanObserver
    from fhobs.core.plant import LTIPlant
    from fhobs.core.runtime import (
        FilteringObserver,
        LuenbergerObserver,
        PrescribedTimeObserver,
    )
    from fhobs.design.observer import design_for_spec, design_observer, paper_gains
    from fhobs.design.settling import error_response
    from fhobs.design.spec import load_spec, plant_spec
    from fhobs.native.build import build_native_fmus
    from fhobs.paper import published

    from harness.master import run_system
    from harness.reference import simulate
    from harness.results import error_figures, settling_figures
    from harness.ssp import export_ssp
    from harness.sweep import fmu_bundle, run_in_process, sweep_from_table
    from harness.system import (
        build_blocks,
        load_system,
        override_evaluation,
        parse_evaluation,
        resolve_system,
    )

    for item in (build_fmus, certify, certify_parts, certify_filtering, certify_prescribed_time,
                 certify_luenberger, certify_kalman, ObserverDesign, LTIPlant, FilteringObserver,
                 LuenbergerObserver, PrescribedTimeObserver, KalmanObserver,
                 design_for_spec, design_observer, load_spec, plant_spec, paper_gains,
                 published, simulate, error_response, extended_model, load_system,
                 resolve_system, build_blocks, run_system, export_ssp, build_native_fmus,
                 error_figures, settling_figures, parse_evaluation, override_evaluation,
                 sweep_from_table, run_in_process, fmu_bundle):
        _, heading, examples = item.__doc__.partition("\n    Examples\n    --------\n")
        assert heading and ">>> " in examples, item.__qualname__
