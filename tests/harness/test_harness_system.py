"""System description: loading, expansion, and every class of error it must report."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

from harness.master import CoSimResult, run_system
from harness.results import error_figures, time_key
from harness.system import (
    DescriptionError,
    Evaluation,
    build_blocks,
    expand_start,
    load_system,
    resolve_system,
    vector_names,
)

BASE = """
name = "blocks"
[run]
step = 0.01
stop_time = 0.05
[fmus.wave]
block = "sine"
outputs = 2
start = {{ amplitude = [1.0, 2.0], omega = [1.0, 3.0] }}
[fmus.g]
{gain}
{extra}
"""
GAIN = 'block = "gain"\noutputs = 1\ninputs = 2\nstart = { K = [[1.0, -1.0]] }'
WIRED = '[[connections]]\nfrom = "wave.y"\nto = "g.u"\n'


@pytest.fixture(scope="module")
def block_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


def _load(tmp_path, block_cache, extra=WIRED, gain=GAIN, variables=None):
    path = tmp_path / "system.toml"
    path.write_text(BASE.format(gain=gain, extra=extra))
    return build_blocks(load_system(path, variables), block_cache)


def _resolve(*args, **kwargs):
    return resolve_system(_load(*args, **kwargs))


def test_valid_system_runs_and_blocks_compute(tmp_path, block_cache):
    system = _resolve(tmp_path, block_cache)
    spec = system.spec
    assert spec.fmus["g"].start == {"K[1,1]": 1.0, "K[1,2]": -1.0}
    result = run_system(
        resolve_system(type(spec)(**{**spec.__dict__, "record": ("g.y[1]",)})), progress=False
    )
    t = result.time
    wave = np.column_stack([np.sin(t), 2 * np.sin(3 * t)])
    np.testing.assert_allclose(result.vector("wave.y"), wave, atol=1e-15)
    # the gain block reads its input at exchange time: y(t_k) = K wave(t_{k-1})
    np.testing.assert_allclose(result.signal("g.y[1]")[1:], wave[:-1] @ [1.0, -1.0], atol=1e-15)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('[[connections]]\nfrom = "wave.y"\nto = "g.v"\n', "FMU 'g' has no variable 'v'"),
        ('[[connections]]\nfrom = "wave.y"\nto = "h.u"\n', "unknown FMU 'h'"),
        ('[[connections]]\nfrom = "g.u"\nto = "wave.y"\n', "causality is input"),
        ('[[connections]]\nfrom = "wave.y[1]"\nto = "g.u"\n', "sizes differ"),
        ('[[connections]]\nfrom = "wave.y"\nto = "g.u"\ngain = [[1.0]]\n', "gain shape (1, 1)"),
        ("", "input g.u[1] is unconnected"),
        (
            WIRED + '[[connections]]\nfrom = "wave.y[1]"\nto = "g.u[1]"\n',
            "connected more than once",
        ),
        ('[[connections]]\nfrom = "wave.y"\nto = "g.y"\n', "causality is output"),
    ],
)
def test_connection_errors(tmp_path, block_cache, extra, message):
    with pytest.raises(DescriptionError, match=re.escape(message)):
        _resolve(tmp_path, block_cache, extra=extra)


@pytest.mark.parametrize(
    ("gain", "message"),
    [
        (GAIN.replace("]] }", ']], "K[1,3]" = 1.0 }'), "no variable 'K\\[1,3\\]'"),
        (GAIN + "\n[fmus.g.start]\nK = 1.0", "invalid TOML"),
        ('block = "gain"\noutputs = 1\ninputs = 2\nstart = { amplitude = true }', "no variable"),
        ('block = "gain"\noutputs = 1\ninputs = 2\nstart = { "K[1,1]" = true }', "given boolean"),
        ('block = "gain"\noutputs = 1\ninputs = 2\nstart = { "y[1]" = 1.0 }', "cannot be given"),
        ('block = "integrator"', "unknown block 'integrator'"),
        ('path = "${nowhere}/g.fmu"', "uses undefined 'nowhere'"),
        ('path = "missing.fmu"', "missing.fmu does not exist"),
    ],
)
def test_fmu_and_start_value_errors(tmp_path, block_cache, gain, message):
    with pytest.raises(DescriptionError, match=message):
        _resolve(tmp_path, block_cache, gain=gain)


def test_connected_input_cannot_also_have_a_start_value(tmp_path, block_cache):
    gain = GAIN.replace("start = { K", 'start = { "u[1]" = 0.0, K')
    with pytest.raises(DescriptionError, match="connected and also given a start value"):
        _resolve(tmp_path, block_cache, gain=gain)


def test_constant_inputs_satisfy_the_unconnected_check(tmp_path, block_cache):
    gain = GAIN.replace("start = { K", "start = { u = [1.0, 2.0], K")
    system = _resolve(tmp_path, block_cache, extra="", gain=gain)
    assert system.connections == ()


def _without_dependencies(fmu: Path, out: Path) -> Path:
    """Copy of an FMU whose model description declares no dependencies (as pythonfmu writes)."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb' dependencies="[^"]*"', b"", data)
            dst.writestr(item, data)
    return out


LOOP = """
[fmus.a]
path = "{a}"
start = {{ K = [[0.5]] }}
[fmus.b]
path = "{b}"
start = {{ K = [[0.5]] }}
[[connections]]
from = "a.y[1]"
to = "b.u[1]"
[[connections]]
from = "b.y[1]"
to = "a.u[1]"
gain = [[{k}]]
"""


@pytest.mark.parametrize("declared", [True, False])
def test_algebraic_loop_through_declared_feedthrough(tmp_path, block_cache, declared):
    """The gain block declares its direct feedthrough, so a loop through two of them is
    rejected (a zero gain cuts it); the same blocks without declarations are not assumed to
    feed through."""
    from harness.blocks import block_fmu

    block = block_fmu("gain", (1, 1), block_cache)
    fmu = block if declared else _without_dependencies(block, tmp_path / "plain.fmu")
    path = tmp_path / "loop.toml"
    path.write_text(LOOP.format(a=fmu, b=fmu, k=1.0))
    if declared:
        with pytest.raises(DescriptionError, match="algebraic loop.*a.y\\[1\\] -> b.u\\[1\\]"):
            resolve_system(load_system(path))
        path.write_text(LOOP.format(a=fmu, b=fmu, k=0.0))  # a zero gain cuts the loop
    assert resolve_system(load_system(path)).fmus.keys() == {"a", "b"}


def test_vector_names_sort_by_index():
    names = {f"x[{i}]": None for i in (10, 2, 1)} | {"x[1,2]": None, "y": None}
    assert vector_names(names, "x") == ["x[1]", "x[1,2]", "x[2]", "x[10]"]
    assert vector_names(names, "y") == ["y"]
    assert expand_start("K", [[1, 2], [3, 4]]) == {
        "K[1,1]": 1.0,
        "K[1,2]": 2.0,
        "K[2,1]": 3.0,
        "K[2,2]": 4.0,
    }


def test_error_figures_instants_and_windows():
    t = np.linspace(0.0, 3.0, 301)
    e = np.exp(-t)
    values = np.column_stack([e, np.zeros_like(t)])
    result = CoSimResult(t, ("p.x[1]", "o.x_hat[1]"), values, 300, 0.0)
    ev = Evaluation(at=(1.5, 4.0), windows=((1.0, 3.0),), errors={"obs": ("p.x", "o.x_hat")})
    figures = error_figures(result, ev)["obs"]
    assert set(figures) == {"error_at_1_5", "max_error_1_3", "rms_error_1_3"}
    assert figures["error_at_1_5"] == pytest.approx(np.exp(-1.5))
    assert figures["max_error_1_3"] == pytest.approx(np.exp(-1.0))
    mask = (t >= 1.0 - 1e-12) & (t <= 3.0 + 1e-12)
    assert mask.sum() == 201
    assert figures["rms_error_1_3"] == pytest.approx(np.sqrt(np.mean(e[mask] ** 2)))
    assert time_key(0.25) == "0_25" and time_key(3.0) == "3"


def test_results_csv_is_fmpys_format(tmp_path):
    """write_csv gives the file fmpy's own writer gives for the same rows (the format an fmpy
    user reads), on numbers of every kind: tiny, huge, integral, negative zero, inf, nan."""
    from fmpy.util import write_csv as fmpy_write_csv

    from harness.results import write_csv

    rng = np.random.default_rng(11)
    values = rng.standard_normal((50, 3)) * 10.0 ** rng.integers(-300, 300, (50, 3))
    values[:6, 0] = [0.0, -0.0, 3.0, np.inf, -np.inf, np.nan]
    values[6:9, 1] = [1e16, 2.0**-1074, 0.1]
    time = np.arange(50) * 0.1
    result = CoSimResult(time, ("plant.x[1]", "observer.x_hat[1]", "q"), values, 49, 0.0)
    table = np.empty(50, dtype=[("time", float)] + [(n, float) for n in result.names])
    table["time"] = time
    for j, name in enumerate(result.names):
        table[name] = values[:, j]
    fmpy_write_csv(str(tmp_path / "fmpy.csv"), table)
    ours = write_csv(result, tmp_path / "ours.csv")
    assert ours.read_text() == (tmp_path / "fmpy.csv").read_text()
    every = write_csv(result, tmp_path / "every.csv", every=20).read_text().splitlines()
    kept = [repr(float(time[k])) for k in (0, 20, 40, 49)]
    assert [line.split(",")[0] for line in every[1:]] == kept


def test_fmu_files_are_read_once_while_unchanged(tmp_path):
    """An FMU's extraction and model description are reused while the file is unchanged, and
    read afresh when it is rewritten or its extracted folder has gone."""
    import shutil

    from harness.blocks import block_fmu
    from harness.fmu_files import description, unzipped

    fmu = tmp_path / "block.fmu"
    shutil.copyfile(block_fmu("sine", (1,), tmp_path / "cache"), fmu)
    folder = unzipped(fmu)
    assert unzipped(fmu) == folder and description(fmu) is description(fmu)
    assert (Path(folder) / "modelDescription.xml").is_file()
    shutil.rmtree(folder)
    again = unzipped(fmu)
    assert (Path(again) / "modelDescription.xml").is_file()
    first = description(fmu)
    shutil.copyfile(block_fmu("sine", (2,), tmp_path / "cache"), fmu)  # rewritten in place
    assert unzipped(fmu) != again
    assert len([v for v in description(fmu).modelVariables if v.causality == "output"]) == 2
    assert len([v for v in first.modelVariables if v.causality == "output"]) == 1
