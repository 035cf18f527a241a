"""The design's records (fhobs.core.gains): design.json holds the plant and the homogeneous model
once and each estimator's own fields under its name, the round trip is exact and shares the
plant and model objects, and each estimator's certificate report is its own record's figures."""

import dataclasses
import json

import numpy as np
import pytest
from fhobs.core.certificate import (
    certify_filtering,
    certify_kalman,
    certify_luenberger,
    certify_prescribed_time,
    certify_supervised,
)
from fhobs.core.gains import (
    ESTIMATORS,
    FilteringGains,
    KalmanGains,
    ObserverDesign,
    PlantModel,
)
from fhobs.design.observer import design_observer

ESTIMATOR_FIELDS = {
    "filtering": {"rho", "gamma", "L_tilde", "L", "P_bar", "certificate",
                  "max_communication_step"},
    "prescribed_time": {"rho", "L_pt", "P_pt", "certificate"},
    "luenberger": {"L_lin", "certificate"},
    "kalman": {"disturbance_order", "sample_time", "measurement_std", "process_intensity",
               "gain", "covariance", "tuning", "certificate", "process_covariance"},
    "supervised": {"filtering", "kalman", "window", "lower", "upper", "lower_return",
                   "upper_return", "ceiling", "dwell_time", "false_alarm",
                   "handover_covariance", "certificate"},
}


@pytest.fixture(scope="module")
def noise_design(kalman_design, pendulum_spec) -> ObserverDesign:
    """The pendulum design with both records of its [noise] table: the Kalman filter and the
    supervised observer (as design_for_spec attaches them)."""
    from fhobs.design.supervised import with_supervised

    return with_supervised(kalman_design, pendulum_spec.noise)


@pytest.fixture(scope="module")
def settled_design() -> ObserverDesign:
    """A design whose rho the settling-time search chose (it carries settling_tuning)."""
    return design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], settling_time=2.0)


def assert_same_record(back, original, path: str) -> None:
    """Every field of two records equal: arrays bit for bit (shape and dtype too), nested
    records field by field."""
    for field in dataclasses.fields(original):
        a, b = getattr(back, field.name), getattr(original, field.name)
        where = f"{path}.{field.name}"
        if dataclasses.is_dataclass(b):
            assert_same_record(a, b, where)
        elif isinstance(b, np.ndarray):
            assert isinstance(a, np.ndarray) and a.dtype == b.dtype, where
            assert a.shape == b.shape and np.array_equal(a, b), where
        else:
            assert a == b, where


@pytest.mark.parametrize("name", ["noise_design", "paper_design", "settled_design"])
def test_the_json_round_trip_is_exact(request, tmp_path, name):
    design = request.getfixturevalue(name)
    back = ObserverDesign.load_json(design.save_json(tmp_path / "design.json"))
    assert_same_record(back, design, "design")
    assert json.dumps(back.to_dict()) == json.dumps(design.to_dict())


def test_the_records_share_the_designs_plant_and_model_after_loading(noise_design, tmp_path):
    back = ObserverDesign.load_json(noise_design.save_json(tmp_path / "design.json"))
    for name in ESTIMATORS:
        record = getattr(back, name)
        assert record.plant is back.plant
        if name in ("filtering", "prescribed_time", "supervised"):
            assert record.model is back.model
    parts = back.supervised.filtering, back.supervised.kalman
    assert all(part.plant is back.plant for part in parts) and parts[0].model is back.model


def test_a_design_json_without_the_supervised_record_loads(noise_design):
    """A design.json written before the supervised record existed loads, without it."""
    data = noise_design.to_dict()
    del data["supervised"]
    back = ObserverDesign.from_dict(json.loads(json.dumps(data)))
    assert back.supervised is None and back.kalman is not None


def test_design_json_holds_the_plant_and_the_model_once(noise_design, settled_design):
    data = noise_design.to_dict()
    assert set(data) == {"plant", "model", *ESTIMATORS, "settling_tuning", "noise_tuning"}
    assert set(data["plant"]) == {"A", "B", "C", "E"}
    assert set(data["model"]) == {"disturbance_order", "n_tilde", "nu", "G0", "L0", "G_d",
                                  "slow_projector"}
    for name, fields in ESTIMATOR_FIELDS.items():
        assert set(data[name]) == fields, name
    assert data["plant"]["A"] == noise_design.plant.A.tolist()
    assert data["model"]["L0"] == noise_design.model.L0.tolist()
    assert data["filtering"]["L"] == noise_design.filtering.L.tolist()
    assert data["settling_tuning"] is None
    assert settled_design.to_dict()["settling_tuning"] == settled_design.settling_tuning
    assert settled_design.settling_tuning["settling_time_requested"] == 2.0


def test_a_record_alone_round_trips_with_the_plant_given(kalman_design):
    kalman = kalman_design.kalman
    back = KalmanGains.from_dict(json.loads(json.dumps(kalman.to_dict())), plant=kalman.plant)
    assert_same_record(back, kalman, "kalman")
    assert back.measurement_std.ndim == 1
    plant = PlantModel(np.eye(2), np.ones((2, 1)), np.ones((1, 2)))
    assert PlantModel.from_dict(plant.to_dict()).E is None


def test_a_missing_field_is_named(kalman_design):
    data = kalman_design.to_dict()
    del data["filtering"]["L_tilde"]
    with pytest.raises(KeyError, match="L_tilde"):
        ObserverDesign.from_dict(data)


def test_a_record_of_another_plant_is_refused(kalman_design):
    plant = dataclasses.replace(kalman_design.plant, A=kalman_design.plant.A.copy())
    luenberger = dataclasses.replace(kalman_design.luenberger, plant=plant)
    with pytest.raises(ValueError, match="luenberger.plant"):
        dataclasses.replace(kalman_design, luenberger=luenberger)
    model = dataclasses.replace(kalman_design.model)
    filtering: FilteringGains = dataclasses.replace(kalman_design.filtering, model=model)
    with pytest.raises(ValueError, match="filtering.model"):
        dataclasses.replace(kalman_design, filtering=filtering)


def test_each_certificate_report_holds_its_own_records_figures(noise_design):
    """Every estimator record has its certificate report, whose checks are the figures the
    record's own certificate gives, and only those: the filtering observer's have no Theorem 1
    figure and the other way round."""
    for name, certify in (("filtering", certify_filtering),
                          ("prescribed_time", certify_prescribed_time),
                          ("luenberger", certify_luenberger), ("kalman", certify_kalman),
                          ("supervised", certify_supervised)):
        record = getattr(noise_design, name)
        # to round-off: a cached design's report may come from another BLAS kernel
        checks = certify(record)
        assert set(record.certificate["checks"]) == set(checks), name
        assert record.certificate["checks"] == pytest.approx(checks, rel=1e-9, abs=1e-12), name
    assert "lmi_pt" not in noise_design.filtering.certificate["checks"]
    assert "lmi_filtering" not in noise_design.prescribed_time.certificate["checks"]
    assert set(noise_design.luenberger.certificate["checks"]) == {"hurwitz_luenberger"}
    assert set(noise_design.kalman.certificate["checks"]) == {"schur_kalman"}
