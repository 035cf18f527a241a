"""Designs shared by the unit tests, each made once per session (the designs are deterministic:
the same spec gives the same gains): the bundled examples' default designs and seeded random
plants. The gains are shared, so a test must not modify their arrays in place (copy first)."""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from fhobs.core.gains import ESTIMATORS, SHARED, ObserverDesign
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from fhobs.fmu.kinds import edited_record

from harness.zoo import load_zoo_spec, zoo_spec_paths

ZOO = zoo_spec_paths()


@functools.cache
def zoo_design(name: str) -> ObserverDesign:
    """The bundled example's design with every tuning parameter at its default."""
    return design_for_spec(load_zoo_spec(ZOO[name]))


@functools.cache
def whole_model_design(name: str) -> ObserverDesign:
    """The bundled example's default design with every mode homogenised (no fast stable mode
    kept by the model: ``fast_mode_rate = inf``), as in the paper."""
    spec = load_zoo_spec(ZOO[name])
    return design_for_spec(dataclasses.replace(spec, fast_mode_rate=math.inf))


@functools.cache
def random_design(seed: int, n: int, k: int, order: int) -> ObserverDesign:
    """A random observable plant (m = 2) designed with explicit rho = 3 and gamma = 2.75; with
    ``order`` >= 1 a random E and a disturbance model of that order."""
    rng = np.random.default_rng(seed)
    data = {"A": (rng.standard_normal((n, n)) / np.sqrt(n)).tolist(),
            "B": rng.standard_normal((n, 2)).tolist(),
            "C": rng.standard_normal((k, n)).tolist(),
            "observer": {"rho": 3.0, "gamma": 2.75}}
    if order:
        data["E"] = rng.standard_normal((n, 1)).tolist()
        data["observer"]["disturbance_order"] = order
    return design_for_spec(spec_from_dict(data, source=f"random seed {seed}"))


def edited_design(design: ObserverDesign, path: str, value: Any) -> ObserverDesign:
    """``design`` with the field ``path`` of one of its records (``"filtering.L"``,
    ``"plant.A"``, ``"model.G_d"``) replaced by ``value``; an edited plant or model replaces the
    design's in every estimator record that holds it (they share it)."""
    head, _, field = path.partition(".")
    new = edited_record(getattr(design, head), {field: value})
    if head not in SHARED:
        return dataclasses.replace(design, **{head: new})
    records = {name: edited_record(getattr(design, name), {head: new})
               for name in ESTIMATORS if hasattr(getattr(design, name), head)}
    return dataclasses.replace(design, **{head: new}, **records)
