"""Rebuilding an unchanged design copies the FMU from the user's cache; any change of the design
or of an option builds afresh (fhobs.build's FMU cache, fhobs.native.build's object cache)."""

import zipfile

import fhobs.build
import numpy as np
from fhobs.build import build_fmus
from fhobs.design.observer import design_observer
from fmpy import read_model_description


def _files(fmu):
    with zipfile.ZipFile(fmu) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


def _start(fmu, name):
    variables = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    return float(variables[name].start)


def test_a_rebuild_is_the_same_fmu_and_a_change_is_not(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cache.mkdir()
    monkeypatch.setattr(fhobs.build, "cache_dir", lambda: cache)  # the compiled helpers stay
    gains = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    first = build_fmus(gains, tmp_path / "a", kinds=("observer",), z0=[0.5, 0.0])["observer"]
    again = build_fmus(gains, tmp_path / "b", kinds=("observer",), z0=[0.5, 0.0])["observer"]
    assert _files(again) == _files(first)
    assert len(list((cache / "fmus").glob("*.fmu"))) == 1

    option = build_fmus(gains, tmp_path / "c", kinds=("observer",), z0=[0.25, 0.0])["observer"]
    assert _start(option, "z0[1]") == 0.25 and _start(first, "z0[1]") == 0.5

    other = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=3.0)
    redesigned = build_fmus(other, tmp_path / "d", kinds=("observer",), z0=[0.5, 0.0])["observer"]
    assert _start(redesigned, "rho") == 3.0 and _start(first, "rho") == 2.0
    assert not np.isclose(_start(redesigned, "L[1,1]"), _start(first, "L[1,1]"))
    assert len(list((cache / "fmus").glob("*.fmu"))) == 3
