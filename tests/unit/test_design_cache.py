"""The user's cache of long design computations (fhobs.design.cache), with real designs: a
repeated call is answered from the cache with the same record, other inputs compute again, and
a file that is unreadable or whose design fails its certificate is computed again, replaced."""

import pickle
from collections.abc import Callable

import numpy as np
import pytest
from designs import edited_design
from fhobs.core.certificate import certify
from fhobs.core.gains import ObserverDesign
from fhobs.design.cache import cached
from fhobs.design.observer import design_observer

PLANT = ([[0, 1], [0, 0]], [[0], [1]], [[1, 0]])


@pytest.fixture
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    return tmp_path / "fhobs" / "designs"


def counted(rho: float, calls: list) -> Callable[[], ObserverDesign]:
    def compute():
        calls.append(rho)
        return design_observer(*PLANT, rho=rho)
    return compute


def test_a_repeated_call_is_answered_from_the_cache(cache_home):
    calls = []
    first, hit = cached("test", ("plant", 2.0), counted(2.0, calls), certify)
    assert not hit and calls == [2.0]
    again, hit = cached("test", ("plant", 2.0), counted(2.0, calls), certify)
    assert hit and calls == [2.0]
    assert np.array_equal(again.filtering.L, first.filtering.L)
    assert np.array_equal(again.filtering.P_bar, first.filtering.P_bar)
    other, hit = cached("test", ("plant", 3.0), counted(3.0, calls), certify)
    assert not hit and calls == [2.0, 3.0] and other.filtering.rho != first.filtering.rho
    assert len(list(cache_home.glob("test_*.pickle"))) == 2


def test_an_unreadable_file_is_computed_again_and_replaced(cache_home):
    calls = []
    cached("test", 1, counted(2.0, calls), certify)
    (path,) = cache_home.glob("test_*.pickle")
    path.write_bytes(b"partial")
    result, hit = cached("test", 1, counted(2.0, calls), certify)
    assert not hit and calls == [2.0, 2.0]
    assert np.array_equal(pickle.loads(path.read_bytes()).filtering.L, result.filtering.L)


def test_a_design_that_fails_its_certificate_is_not_used(cache_home):
    calls = []
    good, _ = cached("test", 1, counted(2.0, calls), certify)
    (path,) = cache_home.glob("test_*.pickle")
    path.write_bytes(pickle.dumps(edited_design(good, "filtering.L", -good.filtering.L)))
    result, hit = cached("test", 1, counted(2.0, calls), certify)
    assert not hit and calls == [2.0, 2.0] and np.array_equal(result.filtering.L, good.filtering.L)


def test_an_unwritable_cache_only_costs_time(cache_home):
    cache_home.parent.mkdir(parents=True)
    cache_home.write_text("a file where the folder would be")
    calls = []
    for _ in range(2):
        result, hit = cached("test", 1, counted(2.0, calls), certify)
        assert not hit and result.filtering.rho == 2.0
    assert calls == [2.0, 2.0]


def test_every_input_of_the_noise_tuning_is_part_of_its_key(cache_home, monkeypatch):
    """design_for_noise through the cache with a counting search: the same call is answered
    from the cache, a change of any one input searches again."""
    from fhobs.design import tuning

    searches = []

    def search(spec, *arguments):
        searches.append(arguments)
        design = design_observer(spec.A, spec.B, spec.C, E=spec.E, disturbance_order=1, rho=2.0)
        prediction = tuning.ErrorPrediction(1.0, (1.0,), 1.0, 1.0)
        return tuning.NoiseDesign(design, {}, prediction, prediction, 1.0, (0.0, 1.0), True, (),
                                  0.0)

    monkeypatch.setattr(tuning, "_search", search)
    base = dict(measurement_std=[1e-3], sample_time=1e-2,
                disturbance={"shape": "step", "size": 0.2, "start": 0.5})
    changes = [{}, {"measurement_std": [2e-3]}, {"sample_time": 2e-2}, {"kalman_order": 2},
               {"fixed": {"rho": 3.0}}, {"rejection": 50.0}, {"noise_draws": 2}, {"seed": 1},
               {"refine": 2}, {"settling_time": 3.0}, {"state_scale": 2.0},
               {"disturbance": {"shape": "step", "size": 0.3, "start": 0.5}}]
    for change in changes:
        result = tuning.design_for_noise(*PLANT, [[0], [1]], **(base | change))
        assert not result.cached, change
    assert len(searches) == len(changes)
    again = tuning.design_for_noise(*PLANT, [[0], [1]], **base)
    assert again.cached and len(searches) == len(changes)


def test_a_file_others_may_write_is_not_read(cache_home):
    calls = []
    cached("test", 1, counted(2.0, calls), certify)
    (path,) = cache_home.glob("test_*.pickle")
    path.chmod(0o666)
    result, hit = cached("test", 1, counted(2.0, calls), certify)
    assert not hit and calls == [2.0, 2.0] and result.filtering.rho == 2.0
    assert path.stat().st_mode & 0o022 == 0  # replaced by a private file


def counting_designs(monkeypatch) -> list:
    """The spec of every design :func:`design_for_spec` computes (not read from the cache)."""
    from fhobs.design import observer

    computed, real = [], observer._designed

    def designed(spec, *arguments):
        computed.append(spec)
        return real(spec, *arguments)

    monkeypatch.setattr(observer, "_designed", designed)
    return computed


def test_every_input_of_a_design_is_part_of_its_key(cache_home, monkeypatch):
    """design_for_spec: the same spec (from another source) is read from the cache, equal to a
    design made afresh; a change of any one input designs again."""
    import dataclasses

    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import plant_spec, spec_from_dict

    computed = counting_designs(monkeypatch)
    spec = plant_spec(*PLANT, rho=2.0)
    first = design_for_spec(spec)
    again = design_for_spec(dataclasses.replace(spec, source="another file"))
    assert len(computed) == 1 and again is not first
    monkeypatch.setenv("FHOBS_NO_DESIGN_CACHE", "1")
    fresh = design_for_spec(spec)
    monkeypatch.delenv("FHOBS_NO_DESIGN_CACHE")
    assert len(computed) == 2
    for record, gain in (("filtering", "L"), ("prescribed_time", "L_pt"),
                         ("luenberger", "L_lin")):
        read, made = getattr(again, record), getattr(fresh, record)
        assert np.array_equal(getattr(read, gain), getattr(made, gain)), record
        assert read.certificate == made.certificate, record
    base = {"A": PLANT[0], "B": PLANT[1], "C": PLANT[2], "observer": {"rho": 2.0}}
    variants = [({"observer": {"rho": 3.0}}, {}), ({"observer": {"rho": 2.0, "gamma": 3.0}}, {}),
                ({"A": [[0, 1], [-1, 0]]}, {}),
                ({"observer": {"rho": 2.0, "filter_scale": 1.5}}, {}),
                ({"observer": {"rho": 2.0, "state_scale": 2.0}}, {}),
                ({"E": [[0], [1]]}, {}),
                ({"E": [[0], [1]],
                  "noise": {"measurement_amplitude": [1e-3], "sample_time": 1e-2,
                            "process_intensity": 1e-2}}, {}),
                ({}, {"objective": "min_gain"}), ({}, {"margin": 2e-2}),
                ({}, {"filter_scale": 1.5})]
    for change, arguments in variants:
        design_for_spec(spec_from_dict(base | change, source="variant"), **arguments)
    assert len(computed) == 2 + len(variants)


def test_without_the_cache_nothing_is_read_or_written(cache_home, monkeypatch):
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import plant_spec

    monkeypatch.setenv("FHOBS_NO_DESIGN_CACHE", "1")
    computed = counting_designs(monkeypatch)
    for _ in range(2):
        design_for_spec(plant_spec(*PLANT, rho=2.0))
    assert len(computed) == 2 and not cache_home.exists()


def test_the_folder_keeps_the_most_recently_used_files(cache_home, monkeypatch):
    import os

    from fhobs.design import cache

    monkeypatch.setattr(cache, "KEPT", 3)
    for key in range(3):
        cached("test", key, lambda key=key: key, check=int)
        for path in cache_home.glob("*.pickle"):  # every earlier file older by a second
            os.utime(path, (path.stat().st_mtime - 1, path.stat().st_mtime - 1))
    assert cached("test", 0, lambda: -1, check=int) == (0, True)  # the oldest, used again
    cached("test", 3, lambda: 3, check=int)
    assert len(list(cache_home.iterdir())) == 3
    assert [cached("test", key, lambda: -1, check=int)[1] for key in (0, 2, 3)] == [True] * 3
    assert cached("test", 1, lambda: -1, check=int) == (-1, False)


def test_a_cache_folder_that_cannot_be_made_only_costs_time(tmp_path, monkeypatch):
    """XDG_CACHE_HOME a file: no cache folder at all; every design is computed."""
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import plant_spec

    blocker = tmp_path / "a file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    computed = counting_designs(monkeypatch)
    for _ in range(2):
        assert design_for_spec(plant_spec(*PLANT, rho=2.0)).filtering.rho == 2.0
    assert len(computed) == 2
