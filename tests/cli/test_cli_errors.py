"""Fault injection on the two command lines: every bad input or failure is one paragraph, exit 2.

The design command (``build_fmu.py``, :func:`fhobs.cli.main`) and the harness
(``python -m harness``, :func:`harness.cli.main`) are run in-process through their ``main()``
(an uncaught exception fails the test) and, for a few cases, as subprocesses (no traceback on
stderr). Each case names the field or the FMU in its message.
"""

from __future__ import annotations

import json
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import fhobs.cli
import fhobs.design.observer
import numpy as np
import pytest
from fhobs.cli import main as design_main
from fhobs.design.homogenisation import observability_index
from fhobs.design.limits import MAX_CHAIN, check_design_limits
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec, spec_from_dict
from fhobs.errors import SpecError

from harness.cli import main as harness_main

REPO = Path(__file__).resolve().parents[2]
"""The clone (for build_fmu.py, the command the README gives)."""
DOUBLE_INTEGRATOR = "A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\n"


def _design(tmp_path: Path, capsys, text: str | bytes, *extra: str) -> tuple[int, str]:
    spec = tmp_path / "spec.toml"
    spec.write_bytes(text if isinstance(text, bytes) else text.encode())
    out = [] if "--out" in extra else ["--out", str(tmp_path / "out")]
    code = design_main([str(spec), "--design-only", *out, *extra])
    return code, capsys.readouterr().err


def _one_paragraph(err: str) -> None:
    assert err.startswith("error: ") and "Traceback" not in err
    assert "\n\n" not in err.strip()


# ------------------------------------------------------------------------- design command


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("A = [[0, 1e308], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\n", "A[1,2] = 1e+308"),
        (DOUBLE_INTEGRATOR + "[observer]\nfilter_scale = 1e308\n", "observer.filter_scale"),
        (DOUBLE_INTEGRATOR + "[observer]\nrho = 1e308\n", "observer.rho"),
        (DOUBLE_INTEGRATOR + "[observer]\nnu = -1e-300\n", "observer.nu = -1e-300"),
        (DOUBLE_INTEGRATOR.encode() + b"# caf\xe9\n", "not UTF-8"),
    ],
)
def test_design_refuses_extreme_specs_with_a_message(tmp_path, capsys, text, named):
    code, err = _design(tmp_path, capsys, text)
    assert code == 2
    _one_paragraph(err)
    assert named in err
    assert not (tmp_path / "out").exists()


def _chain(n: int, k: int = 1) -> str:
    """k integrator chains of length n // k, each measured at its head."""
    s = n // k
    A, C = np.zeros((n, n)), np.zeros((k, n))
    for i in range(k):
        A[i * s:(i + 1) * s, i * s:(i + 1) * s] = np.diag(np.ones(s - 1), 1)
        C[i, i * s] = 1.0
    B = np.zeros((n, 1))
    B[-1] = 1.0
    return f"A = {A.tolist()}\nB = {B.tolist()}\nC = {C.tolist()}\n"


def test_design_refuses_a_chain_longer_than_the_limit_before_designing(tmp_path, capsys):
    code, err = _design(tmp_path, capsys, _chain(MAX_CHAIN + 2))
    assert code == 2
    _one_paragraph(err)
    assert f"n_tilde = {MAX_CHAIN + 2}" in err and f"n_tilde <= {MAX_CHAIN}" in err


@pytest.mark.slow
def test_the_limit_is_on_the_chain_not_on_n(tmp_path, capsys):
    """60 states in 6 measured chains of 10 (n_tilde = 10) design and pass the certificate."""
    code, err = _design(tmp_path, capsys, _chain(60, 6))
    assert code == 0, err
    design = json.loads((tmp_path / "out" / "design.json").read_text())
    assert design["model"]["n_tilde"] == 10 and np.shape(design["model"]["L0"]) == (60, 6)
    assert design["filtering"]["certificate"]["checks"]["lmi_filtering"] < 0


def test_a_300_chain_is_refused_by_the_limit_function():
    spec = spec_from_dict({"A": np.diag(np.ones(299), 1).tolist(), "B": [[0]] * 299 + [[1]],
                           "C": [[1] + [0] * 299]})
    with pytest.raises(SpecError, match="n_tilde = 300 .*exceeds"):
        check_design_limits(spec)


def test_scaled_observable_pair_is_observable():
    """A = [[a, 1], [0, a]], C = [1, 0]: [C; CA] = [[1, 0], [a, 1]] has determinant 1 exactly."""
    a = 10**150
    assert Fraction(1) * 1 - Fraction(0) * a == 1  # det [[1, 0], [a, 1]], exact
    assert observability_index(np.array([[1e150, 1.0], [0.0, 1e150]]), np.array([[1.0, 0.0]])) \
        == (2, 2)


def test_scaled_pair_is_refused_for_its_range_not_reported_unobservable(tmp_path, capsys):
    code, err = _design(tmp_path, capsys, "A = [[1e150, 1], [0, 1e150]]\nB = [[0], [1]]\n"
                                          "C = [[1, 0]]\n")
    assert code == 2
    _one_paragraph(err)
    assert "not observable" not in err and "A[1,1] = 1e+150" in err


@pytest.mark.parametrize("kind", ["file", "under_file"])
def test_design_out_that_cannot_be_a_folder(tmp_path, capsys, kind):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    out = blocker if kind == "file" else blocker / "sub"
    code, err = _design(tmp_path, capsys, DOUBLE_INTEGRATOR, "--out", str(out))
    assert code == 2
    _one_paragraph(err)
    assert f"--out {out}" in err and blocker.read_text() == "x"


@pytest.mark.parametrize(
    "failure",
    [FloatingPointError("overflow encountered"), np.linalg.LinAlgError("SVD did not converge"),
     MemoryError("Unable to allocate 33.0 GiB"), ValueError("G_d is not diagonalisable")],
)
def test_any_failure_inside_the_design_is_a_message(tmp_path, capsys, monkeypatch, failure):
    def failing(*args, **kwargs):
        raise failure

    monkeypatch.setattr(fhobs.design.observer, "design_for_spec", failing)
    code, err = _design(tmp_path, capsys, DOUBLE_INTEGRATOR)
    assert code == 2
    _one_paragraph(err)
    assert type(failure).__name__ in err and str(failure) in err


@pytest.mark.slow
def test_design_subprocess_prints_no_traceback(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(DOUBLE_INTEGRATOR + "[observer]\nnu = -1e-300\n")
    proc = subprocess.run(
        [sys.executable, str(REPO / "build_fmu.py"), str(spec), "--design-only",
         "--out", str(tmp_path / "o")],
        capture_output=True, text=True, check=False,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "observer.nu" in proc.stderr


# ------------------------------------------------------------------------------- harness

SYSTEM = """
name = "chain_observer"
[run]
step = 0.01
stop_time = 1.0
record = ["observer.x_hat"]
[fmus.wave]
block = "sine"
outputs = 1
start = {{ amplitude = [1.0], omega = [1.0] }}
[fmus.observer]
path = "{observer}"
start = {{ "u[1]" = 0.0{observer_start} }}
[[connections]]
from = "wave.y"
to = "observer.y"
{extra}
[evaluation]
at = [0.2, 0.9]
windows = [[0.0, 0.3]]
[evaluation.errors]
tracking = ["wave.y", "observer.x_hat[1]"]
"""


@pytest.fixture
def observer_fmu(chain_observer: Path) -> Path:
    """The triple integrator's observer FMU (n = 3, k = 1): tests/fmu_fixtures.py's
    ``chain_observer``, built once for the session."""
    return chain_observer


@pytest.fixture(scope="module")
def block_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


def _system(tmp_path: Path, observer: Path, extra: str = "", observer_start: str = "",
            replace: tuple[str, str] | None = None) -> Path:
    text = SYSTEM.format(observer=observer, extra=extra, observer_start=observer_start)
    if replace is not None:
        assert replace[0] in text
        text = text.replace(*replace)
    path = tmp_path / "system.toml"
    path.write_text(text)
    return path


def _harness(capsys, *argv: str) -> tuple[int, str]:
    code = harness_main(list(argv))
    return code, capsys.readouterr().err


def _run(tmp_path, capsys, block_cache, system: Path, *options: str) -> tuple[int, str]:
    return _harness(capsys, "run", str(system), "--out", str(tmp_path / "out"), "--no-plots",
                    "--block-cache", str(block_cache), *options)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (("--step", "0"), "step = 0.0 must be > 0"),
        (("--step", "-0.01"), "step = -0.01 must be > 0"),
        (("--stop-time", "-1"), "stop_time = -1.0 must be after start_time"),
        (("--stop-time", "0"), "stop_time = 0.0 must be after start_time"),
        (("--step", "0.003"), "step = 0.003 does not divide"),
        (("--seeds", "0"), "--seeds = 0"),
    ],
)
def test_harness_bad_timing_options(tmp_path, capsys, block_cache, observer_fmu, options, named):
    code, err = _run(tmp_path, capsys, block_cache, _system(tmp_path, observer_fmu), *options)
    assert code == 2
    _one_paragraph(err)
    assert named in err


@pytest.mark.parametrize(
    ("replace", "named"),
    [
        (("step = 0.01", "stpe = 0.01"), "unknown key 'stpe'"),
        (("[run]", "[runn]"), "unknown key 'runn'"),
        (("[evaluation]\n", "[evaluation]\nwindow = 1\n"), "unknown key 'window'"),
        (('to = "observer.y"', 'to = "observer.y"\ngian = [[1]]'), "unknown key 'gian'"),
        (('path = "', 'pth = "x"\npath = "'), "unknown key 'pth'"),
        (("step = 0.01", 'step = "fast"'), "run.step = 'fast' is not a finite number"),
        (("step = 0.01", "step = 0.0"), "step = 0.0 must be > 0"),
        (("stop_time = 1.0", "stop_time = 0.015"), "does not divide"),
        (('to = "observer.y"', 'to = "observer.y"\ngain = [["a"]]'), "gain[1,1] = 'a'"),
        (('to = "observer.y"', 'to = "observer.y"\ngain = [[1], [1, 2]]'), "unequal length"),
        (("windows = [[0.0, 0.3]]", "windows = [[0.3]]"), "window [0.3] is not a pair"),
        (("windows = [[0.0, 0.3]]", "windows = [[0.3, 0.1]]"), "must have start < end"),
        (("windows = [[0.0, 0.3]]", 'windows = [["a", 0.3]]'), "is not a finite number"),
        (("at = [0.2, 0.9]", "at = 0.2"), "at must be a list"),
        (('from = "wave.y"', "from = 3"), "from = 3 must be a string"),
        (("outputs = 1", "outputs = 0"), "outputs = 0 must be a positive integer"),
        (("omega = [1.0]", 'omega = ["x"]'), "start value omega[1] = 'x'"),
    ],
)
def test_strict_system_descriptions(tmp_path, capsys, block_cache, observer_fmu, replace, named):
    system = _system(tmp_path, observer_fmu, replace=replace)
    code, err = _run(tmp_path, capsys, block_cache, system)
    assert code == 2
    _one_paragraph(err)
    assert named in err


def test_short_vector_start_value_is_rejected(tmp_path, capsys, block_cache, observer_fmu):
    """A 2-vector for the 3-state observer's z0 leaves nothing silently at 0."""
    code, err = _run(tmp_path, capsys, block_cache, _system(tmp_path, observer_fmu),
                     "--set", "observer.z0=[1, 0.5]")
    assert code == 2
    _one_paragraph(err)
    assert "observer.z0: start value of shape 2, but the FMU has 3" in err


@pytest.mark.parametrize("kind", ["file", "under_file"])
def test_harness_out_that_cannot_be_a_folder(tmp_path, capsys, block_cache, observer_fmu, kind):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    out = blocker if kind == "file" else blocker / "sub"
    code, err = _harness(capsys, "run", str(_system(tmp_path, observer_fmu)), "--out", str(out),
                         "--block-cache", str(block_cache))
    assert code == 2
    _one_paragraph(err)
    assert f"--out {out}" in err and blocker.read_text() == "x"


def test_fmu_refusing_its_parameters_is_quoted(tmp_path, capsys, block_cache, observer_fmu):
    code, err = _run(tmp_path, capsys, block_cache, _system(tmp_path, observer_fmu),
                     "--set", "observer.nu=0.5")
    assert code == 2
    _one_paragraph(err)
    assert "observer: fmi2ExitInitializationMode" in err and "the FMU says:" in err
    assert "nu = 0.5 is outside" in err  # the observer's own check of its parameters


def test_mid_run_failure_keeps_the_recorded_rows(tmp_path, capsys, block_cache, observer_fmu):
    """y = sin(t) passes input_bound = 0.5 after t = asin(0.5) = 0.5236: the step from 0.52
    (whose input y(0.52) = 0.4969 is within the bound) succeeds, the one from 0.53 fails."""
    system = _system(tmp_path, observer_fmu, observer_start=", input_bound = 0.5")
    code, err = _run(tmp_path, capsys, block_cache, system)
    assert code == 2
    _one_paragraph(err)
    assert "observer: " in err and "at t = 0.53" in err and "input_bound" in err
    out = tmp_path / "out"
    table = np.genfromtxt(out / "results.csv", delimiter=",", names=True)
    np.testing.assert_allclose(table["time"], 0.01 * np.arange(54), rtol=0, atol=1e-12)
    np.testing.assert_allclose(table["wavey1"], np.sin(table["time"]), rtol=0, atol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["incomplete"] is True and "input_bound" in summary["error"]
    assert summary["steps"] == 53 and summary["stop_time"] == pytest.approx(0.53)
    assert "error_at_0_2" in summary["tracking"] and "error_at_0_9" not in summary["tracking"]


@pytest.mark.slow
def test_harness_subprocess_prints_no_traceback(tmp_path, block_cache, observer_fmu):
    proc = subprocess.run(
        [sys.executable, "-m", "harness", "run", str(_system(tmp_path, observer_fmu)),
         "--out", str(tmp_path / "o"), "--step", "0", "--block-cache", str(block_cache)],
        capture_output=True, text=True, check=False, cwd=REPO,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "step = 0.0 must be > 0" in proc.stderr


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (("--rho", "-1"), "observer.rho = -1.0 must be > 0"),
        (("--rho", "1", "--gamma", "4"), "observer.rho = 1.0 must be > gamma/2 = 2.0"),
        (("--settling-time", "0"), "observer.settling_time = 0.0 must be > 0"),
        (("--nu", "0.5"), "observer.nu = 0.5 is outside"),
        (("--h", "0"), "--h = 0.0: the internal step must be positive and finite"),
        (("--h", "nan"), "--h = nan: the internal step must be positive and finite"),
    ],
)
def test_design_overrides_are_checked_like_the_spec(tmp_path, capsys, options, words):
    """The command line's --rho, --gamma, --settling-time, --nu and --h: one paragraph naming
    the item, exit 2, before any design work (no output folder)."""
    code, err = _design(tmp_path, capsys, DOUBLE_INTEGRATOR, *options)
    assert code == 2 and words in err, err
    _one_paragraph(err)
    assert not (tmp_path / "out").exists()


def test_the_api_and_the_command_line_give_one_design(tmp_path):
    """``design_for_spec`` of a spec with a [noise] table is the design.json that
    ``build_fmu.py --design-only`` writes for it: the Kalman filter included."""
    from fhobs.core.gains import ObserverDesign
    from fhobs.paper import PENDULUM_SPEC

    assert design_main([str(PENDULUM_SPEC), "--out", str(tmp_path), "--design-only"]) == 0
    written = ObserverDesign.load_json(tmp_path / "design.json").to_dict()
    api = design_for_spec(load_spec(PENDULUM_SPEC)).to_dict()
    assert api["kalman"] is not None
    assert json.dumps(api, sort_keys=True) == json.dumps(written, sort_keys=True)


def test_design_for_spec_checks_the_design_limits():
    """A spec beyond the design's limits is refused by the API too, before any design work."""
    chain = MAX_CHAIN + 1
    A = np.eye(chain, k=1)
    spec = spec_from_dict({"A": A.tolist(), "B": np.eye(chain)[:, -1:].tolist(),
                           "C": np.eye(chain)[:1].tolist(), "observer": {"rho": 2.0}})
    with pytest.raises(SpecError, match="n_tilde"):
        design_for_spec(spec)


TUNED_SPEC = """A = [[0, 1], [0, 0]]
B = [[0], [1]]
C = [[1, 0]]
E = [[0], [1]]
[observer]
disturbance_order = 1
[noise]
measurement_std = [1e-3]
sample_time = 1e-2
process_intensity = 1.0
"""


@pytest.mark.slow
@pytest.mark.xdist_group("noise_tuning")  # one search of their spec, then the cache
def test_tune_noise_picks_a_design_for_the_specs_noise_and_disturbance(tmp_path, capsys):
    """``--tune-noise``: the design with the least predicted noisy RMS among those that reject
    the [disturbance] step 1e4 times better than the tuned Kalman filter; both predictions
    printed and kept in design.json, and the chosen design re-certifies."""
    from fhobs.core.certificate import certify
    from fhobs.core.gains import ObserverDesign

    spec = tmp_path / "di.toml"
    spec.write_text(TUNED_SPEC + '[disturbance]\nshape = "step"\nsize = 0.2\nstart = 0.5\n')
    assert design_main([str(spec), "--out", str(tmp_path / "out"), "--design-only",
                        "--tune-noise"]) == 0
    out = capsys.readouterr().out
    assert "noise tuning:" in out and "Kalman filter (intensity" in out
    gains = ObserverDesign.load_json(tmp_path / "out" / "design.json")
    certify(gains)
    tuning = gains.noise_tuning
    assert gains.kalman is not None and tuning["met"]
    assert tuning["predicted_noise_free_max"] * 1e4 <= tuning["kalman_predicted_noise_free_max"]
    assert f"{tuning['predicted_noisy_rms']:.3e}" in out
    # the same spec elsewhere: the search answered from the user's cache, the same design
    moved = tmp_path / "elsewhere.toml"
    moved.write_text(spec.read_text())
    assert design_main([str(moved), "--out", str(tmp_path / "again"), "--design-only",
                        "--tune-noise"]) == 0
    assert "(from the cache)" in capsys.readouterr().out
    assert ((tmp_path / "again" / "design.json").read_text()
            == (tmp_path / "out" / "design.json").read_text())


def test_tune_noise_without_a_disturbance_table_is_refused_before_any_design(tmp_path, capsys):
    spec = tmp_path / "di.toml"
    spec.write_text(TUNED_SPEC)
    assert design_main([str(spec), "--out", str(tmp_path / "out"), "--tune-noise"]) == 2
    err = capsys.readouterr().err
    assert "--tune-noise needs" in err and "no [disturbance] table" in err
    assert not (tmp_path / "out").exists()
