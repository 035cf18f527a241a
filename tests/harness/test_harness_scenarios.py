"""The bundled scenario files: the paper's set-up as :mod:`fhobs.paper` states it, and the
``extends`` mechanism that keeps the three of them one description plus two changes."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.paper import H_PAPER, K_PAPER, PAPER_SCENARIOS, X0_PAPER

from harness.cli import PAPER_SCENARIO_FILES as FILES
from harness.cli import SCENARIO_DIR
from harness.system import DescriptionError, load_system


@pytest.mark.parametrize("scenario", sorted(FILES))
def test_bundled_scenario_is_the_papers_set_up(scenario):
    spec = load_system(SCENARIO_DIR / f"{FILES[scenario]}.toml")
    paper = PAPER_SCENARIOS[scenario]
    plant = spec.fmus["plant"].start
    assert [plant[f"x0[{i}]"] for i in range(1, 5)] == X0_PAPER.tolist()
    assert plant["noise_amplitude"] == paper.noise_amplitude
    if paper.q_amplitude == 0.0:  # no perturbation: q a constant input of value 0
        assert "perturbation" not in spec.fmus and plant["q[1]"] == 0.0
    else:
        sine = spec.fmus["perturbation"].start
        assert (sine["amplitude[1]"], sine["omega[1]"]) == (paper.q_amplitude,
                                                              paper.q_frequency)
        assert (sine["phase[1]"], sine["offset[1]"]) == (0.0, 0.0)
        assert "q[1]" not in plant
    gains = [c.gain for c in spec.connections if c.gain is not None]
    assert len(gains) == 4 and all(np.array_equal(g, K_PAPER) for g in gains)
    assert spec.step == H_PAPER and spec.name == FILES[scenario]


def _write(path, text):
    path.write_text(text)
    return path


BASE = """
name = "base"
[run]
step = 0.5
stop_time = 2.0
record = ["a.y"]
[fmus.a]
path = "a.fmu"
start = { x0 = [1.0, 2.0], gain = 3.0 }
[[connections]]
from = "a.y"
to = "b.u"
"""


def test_extends_merges_tables_appends_connections_and_replaces_values(tmp_path):
    _write(tmp_path / "base.toml", BASE)
    child = _write(tmp_path / "child.toml", """
extends = "base.toml"
name = "child"
[run]
stop_time = 4.0
[fmus.a]
start = { gain = 5.0 }
[fmus.b]
path = "b.fmu"
[[connections]]
from = "b.y"
to = "a.u"
""")
    spec = load_system(child)
    assert spec.name == "child" and (spec.step, spec.stop_time) == (0.5, 4.0)
    assert spec.fmus["a"].start == {"x0[1]": 1.0, "x0[2]": 2.0, "gain": 5.0}
    assert spec.fmus["a"].path == (tmp_path / "a.fmu").resolve()
    assert set(spec.fmus) == {"a", "b"}
    assert [(c.source, c.target) for c in spec.connections] == [("a.y", "b.u"), ("b.y", "a.u")]


def test_a_connection_of_the_extending_file_replaces_the_bases_constant_input(tmp_path):
    """The base gives a.u[1] (and, as a vector, a.w) start values; the extending file connects
    them: the start values go, the base's other start values stay. Within one file both are
    still an error (resolve_system)."""
    _write(tmp_path / "base.toml", BASE.replace("gain = 3.0 }", 'gain = 3.0, "u[1]" = 0.5, '
                                                               "w = [1.0, 2.0] }"))
    child = _write(tmp_path / "child.toml", """
extends = "base.toml"
[[connections]]
from = "b.y"
to = "a.u[1]"
[[connections]]
from = "b.v"
to = "a.w"
""")
    start = load_system(child).fmus["a"].start
    assert start == {"x0[1]": 1.0, "x0[2]": 2.0, "gain": 3.0}
    assert load_system(tmp_path / "base.toml").fmus["a"].start["u[1]"] == 0.5


def test_extends_errors_name_the_files(tmp_path):
    missing = _write(tmp_path / "missing.toml", 'extends = "nowhere.toml"\n')
    with pytest.raises(DescriptionError, match=r"nowhere.toml does not exist \(extended by"):
        load_system(missing)
    _write(tmp_path / "one.toml", 'extends = "two.toml"\n')
    two = _write(tmp_path / "two.toml", 'extends = "one.toml"\n')
    with pytest.raises(DescriptionError, match="a cycle"):
        load_system(two)
    number = _write(tmp_path / "number.toml", "extends = 3\n")
    with pytest.raises(DescriptionError, match="extends = 3 must name a description file"):
        load_system(number)


def test_paper_values_are_substituted_and_unknown_names_refused(tmp_path):
    path = _write(tmp_path / "paper.toml", BASE.replace("gain = 3.0", 'gain = "${paper.step}", '
                                                        'k = "${paper.K}"'))
    start = load_system(path).fmus["a"].start
    assert start["gain"] == H_PAPER
    assert [start[f"k[1,{j}]"] for j in range(1, 5)] == K_PAPER[0].tolist()
    _write(path, BASE.replace("gain = 3.0", 'gain = "${paper.gain}"'))
    with pytest.raises(DescriptionError, match=r"\$\{paper.gain\} is not one of the paper's "
                                               r"values \(paper.K, "):
        load_system(path)


def test_list_names_every_bundled_scenario_with_its_first_sentence(capsys):
    from harness.cli import main

    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == sorted(
        path.stem for path in SCENARIO_DIR.glob("*.toml"))
    by_name = {line.split()[0]: line.split(maxsplit=1)[1] for line in lines}
    assert by_name["pendulum_nominal"] == "The paper's nominal scenario"
    assert by_name["pendulum_noisy"] == "The paper's perturbed and noisy scenario"
