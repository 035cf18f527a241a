"""The automatic choice of rho: uncertified values are passed over, the climb goes on, and
when nothing certifies the message says what was tried and what to change."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs import cli
from fhobs.design import observer
from fhobs.design.settling import error_response
from fhobs.design.spec import plant_spec
from fhobs.errors import LMIError

pytestmark = pytest.mark.unit

TRIPLE = ([[0, 1, 0], [0, 0, 1], [0, 0, 0]], [[0], [0], [1]], [[1, 0, 0]])


@pytest.fixture(autouse=True)
def no_cache(monkeypatch):
    monkeypatch.setenv("FHOBS_NO_DESIGN_CACHE", "1")


def test_uncertified_rungs_are_passed_over(monkeypatch):
    """rho below 4 refused (as a stiff plant's LMI is): the climb goes past them and keeps the
    first rung that certifies and meets the settling time."""
    original = observer._design_at_margin

    def refusing(spec, *args):
        if spec.rho < 4.0:
            raise LMIError(f"LMI solver status infeasible (rho = {spec.rho})")
        return original(spec, *args)

    monkeypatch.setattr(observer, "_design_at_margin", refusing)
    spec = plant_spec(*TRIPLE, settling_time=2.0)
    design = observer.design_for_spec(spec)
    assert design.filtering.rho >= 4.0
    assert design.settling_tuning["met"]
    # the rung below it, had it certified, would also have had to miss the request or be
    # refused: the choice is the smallest certified rho that meets it
    climb = observer._rho_climb(spec)
    chosen = climb.index(design.filtering.rho)
    assert all(rho < 4.0 for rho in climb[:chosen])


def test_climb_reaches_far_beyond_the_former_ladder():
    """A request 100 times faster than the default is met by a rho far above 32."""
    spec = plant_spec(*TRIPLE, settling_time=0.02)
    design = observer.design_for_spec(spec)
    assert design.filtering.rho > 32.0
    response = error_response(design.filtering, np.ones(3), 0.02)
    assert response.settling_time <= 0.02


def test_nothing_certifies_says_what_was_tried(monkeypatch):
    def refusing(spec, *args):
        raise LMIError(f"LMI solver status infeasible (rho = {spec.rho})")

    monkeypatch.setattr(observer, "_design_at_margin", refusing)
    with pytest.raises(LMIError) as info:
        observer.design_for_spec(plant_spec(*TRIPLE, settling_time=0.5))
    message = str(info.value)
    assert "settling time of 0.5 s" in message
    assert "tried rho from 6 to " in message  # 1.5 * 2 s / 0.5 s
    for advice in ("settling_time", "state_scale", "fast_mode_rate", "by hand"):
        assert advice in message


def test_build_command_exits_2_with_that_message(monkeypatch, tmp_path, capsys):
    def refusing(spec, *args):
        raise LMIError(f"LMI solver status infeasible (rho = {spec.rho})")

    monkeypatch.setattr(observer, "_design_at_margin", refusing)
    spec = tmp_path / "plant.toml"
    spec.write_text('A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\n')
    assert cli.main([str(spec), "--out", str(tmp_path / "out"), "--design-only"]) == 2
    err = capsys.readouterr().err
    assert "no certified design for a settling time of 2 s" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "design.json").exists()
