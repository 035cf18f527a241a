"""Every exception of fhobs and of the harness derives from one base, FhobsError, and keeps
the builtin base callers knew (ValueError, RuntimeError)."""

from __future__ import annotations

import fhobs
import fhobs.errors
import pytest

from harness.master import MasterError
from harness.sweep import SweepError
from harness.system import DescriptionError


@pytest.mark.parametrize(("cls", "builtin"), [
    (fhobs.errors.SpecError, ValueError), (fhobs.errors.LMIError, RuntimeError),
    (fhobs.errors.KalmanDesignError, ValueError), (fhobs.errors.BuildError, RuntimeError),
    (fhobs.errors.CertificateError, ValueError), (DescriptionError, ValueError),
    (SweepError, ValueError), (MasterError, RuntimeError),
])
def test_one_base(cls, builtin):
    assert issubclass(cls, fhobs.FhobsError) and issubclass(cls, builtin)


def test_a_spec_error_is_caught_as_the_base():
    with pytest.raises(fhobs.FhobsError, match="C"):
        fhobs.design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0, 0]])
