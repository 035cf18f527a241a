"""The noise tuning never chooses a design whose error does not converge, and says when no
candidate meets the rejection asked for; the chosen design's convergence is checked again on
a loop computed apart from the tuning (tests/noise_replay.py)."""

import numpy as np
import pytest
from fhobs.design import tuning
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from fhobs.errors import LMIError
from noise_replay import replay_error, window_rms

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("noise_tuning")]

DOUBLE_INTEGRATOR = ([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], [[0], [1]])
STEP = {"shape": "step", "size": 0.2, "start": 0.5}
# three masses, wall - m1 - m2 - m3 (springs 3 - 1 - 1 less the couplings, light dampers),
# force on mass 1, position of mass 3 measured, no disturbance model
THREE_MASSES = (
    [[0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1],
     [-3, 1, 0, -0.3, 0.1, 0], [1, -2, 1, 0.1, -0.2, 0.1], [0, 1, -1, 0, 0.1, -0.1]],
    [[0], [0], [0], [1], [0], [0]], [[0, 0, 1, 0, 0, 0]], [[0], [0], [0], [1], [0], [0]])
STD, SAMPLE_TIME, SETTLING_TIME = 1e-3, 1e-2, 2.0


def final_ratios(record, draws):
    """The final quarter's RMS error over the initial error: noise-free, then each draw."""
    out = []
    for std, draw in [(None, 0)] + [(STD, d) for d in range(draws)]:
        t, e = replay_error(record, std, SAMPLE_TIME, SETTLING_TIME, STEP["size"],
                            STEP["start"], draw=draw)
        out.append(window_rms(t, e, 2.5 * SETTLING_TIME, 3 * SETTLING_TIME) / e[0])
    return out


def test_a_plant_whose_every_candidate_diverges_under_noise_is_refused():
    """The three-mass chain: every certified candidate's error grows under noise; the tuning
    refuses with one line instead of choosing one (it used to choose a noisy RMS of 1e2-1e3
    against the Kalman filter's 0.8); the automatic design, one of the candidates, does diverge
    on the loop computed apart."""
    with pytest.raises(LMIError) as caught:
        tuning.design_for_noise(*THREE_MASSES, measurement_std=[STD], sample_time=SAMPLE_TIME,
                                disturbance=STEP, disturbance_order=0, noise_draws=1, refine=0)
    message = str(caught.value)
    assert "none of the" in message and "converges" in message and "kalman.fmu" in message
    assert "\n" not in message
    A, B, C, E = THREE_MASSES
    auto = design_for_spec(spec_from_dict({"A": A, "B": B, "C": C, "E": E}))
    assert max(final_ratios(auto.filtering, 1)) > 1.0 / tuning.DECAY


def test_the_normal_choice_meets_the_rejection_and_converges():
    """The double integrator: the choice meets the rejection, is labelled so, and converges
    (final-quarter error 10x below the initial one, without noise and on every draw) on the
    loop computed apart, whose figures agree with the prediction."""
    result = tuning.design_for_noise(*DOUBLE_INTEGRATOR, measurement_std=[STD],
                                     sample_time=SAMPLE_TIME, disturbance=STEP,
                                     noise_draws=2, refine=0)
    assert result.met and result.design.noise_tuning["selection"] == tuning.SELECTIONS[True]
    assert not any(line.startswith("warning:") for line in result.summary())
    ratios = final_ratios(result.design.filtering, 2)
    assert max(ratios) < 1.0 / tuning.DECAY
    assert max(ratios) == pytest.approx(result.predicted.final_ratio, rel=1e-6)
    t, e = replay_error(result.design.filtering, STD, SAMPLE_TIME, SETTLING_TIME, STEP["size"],
                        STEP["start"], draw=0)
    assert window_rms(t, e, SETTLING_TIME, 3 * SETTLING_TIME) == pytest.approx(
        result.predicted.noisy_rms_draws[0], rel=1e-6)


def test_without_a_candidate_meeting_the_rejection_the_choice_converges_and_says_so():
    """An unreachable rejection: the converging candidate of the strongest rejection is chosen,
    labelled in the summary and in noise_tuning; every candidate of a stronger rejection was
    found not to converge; the choice converges on the loop computed apart."""
    result = tuning.design_for_noise(*DOUBLE_INTEGRATOR, measurement_std=[STD],
                                     sample_time=SAMPLE_TIME, disturbance=STEP,
                                     rejection=1e300, noise_draws=2, refine=0)
    record = result.design.noise_tuning
    assert not result.met and not record["met"]
    assert record["selection"] == tuning.SELECTIONS[False]
    warning = [line for line in result.summary() if line.startswith("warning:")]
    assert len(warning) == 1 and "strongest rejection" in warning[0]
    chosen = next(row for row in result.candidates
                  if all(row[key] == value for key, value in result.parameters.items()))
    stronger = [row for row in result.candidates
                if row.get("noise_free_max", np.inf) < chosen["noise_free_max"]]
    assert all("failed" in row for row in stronger)
    ratios = final_ratios(result.design.filtering, 2)
    assert max(ratios) < 1.0 / tuning.DECAY
