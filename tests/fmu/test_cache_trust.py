"""What the user's cache hands back is used only when it is this user's alone and is what it
claims to be (fhobs.core.cache_files): a foreign or world-writable library is compiled again, a
text file in place of a cached FMU or object file is built again, each with one warning line;
a cache folder that cannot be used (a file in its place, not writable, a full disk) costs the
build its cache, not its result, with one warning line naming the folder."""

import errno
import logging
import os
import shutil
import zipfile
from pathlib import Path

import fhobs.build
import pytest
from fhobs.build import build_fmus
from fhobs.core import kernel
from fhobs.core.cache_files import ELF_MAGIC, fmu_guid
from fhobs.design.cache import cached
from fhobs.design.observer import design_observer
from fhobs.native import build as native_build
from fhobs.native.build import build_native_fmus

PLANT = ([[0, 1], [0, 0]], [[0], [1]], [[1, 0]])
FOREIGN_UID = 65534
needs_cc = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                              reason="needs a C compiler")


@pytest.fixture
def cache_home(tmp_path, monkeypatch, caplog):
    """The user's cache in tmp_path; the warnings of the cache logged for the test."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home"))
    monkeypatch.setattr("fhobs.core.cache_files._WARNED", set())
    caplog.set_level(logging.WARNING, logger="fhobs.cache")
    return tmp_path / "home" / "fhobs"


def cache_warnings(caplog) -> list[str]:
    return [record.getMessage() for record in caplog.records if record.name == "fhobs.cache"]


def foreign(path: Path, mode: int) -> None:
    """Make ``path`` another user's (when this process may) or else writable by others."""
    if os.geteuid() == 0:
        os.chown(path, FOREIGN_UID, FOREIGN_UID)
    path.chmod(mode)


@pytest.fixture
def unusable_cache(tmp_path, monkeypatch, caplog):
    """XDG_CACHE_HOME under a file (as root, modes do not stop writes) or a read-only folder."""
    home = tmp_path / "home"
    if os.geteuid() == 0:
        home.write_text("a file, not a folder")
        home = home / "below"
    else:
        home.mkdir(mode=0o500)
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.setattr("fhobs.core.cache_files._WARNED", set())
    caplog.set_level(logging.WARNING, logger="fhobs.cache")
    yield home / "fhobs"
    if os.geteuid() != 0:
        home.chmod(0o700)


@needs_cc
@pytest.mark.parametrize("mode", [0o755, 0o777])
def test_a_foreign_or_world_writable_library_is_compiled_again(cache_home, caplog, mode):
    path = kernel.cached_build(kernel.SOURCE, "fhobs_kernel", kernel.LIBRARY_FLAGS, ("-lm",),
                               (kernel.HEADER,))
    assert path.parent == cache_home
    genuine = path.read_bytes()
    path.write_bytes(ELF_MAGIC + b"not the kernel")
    foreign(path, mode)
    if mode == 0o755 and os.geteuid() != 0:
        path.chmod(0o757)  # cannot give it away: others may write it instead
    again = kernel.cached_build(kernel.SOURCE, "fhobs_kernel", kernel.LIBRARY_FLAGS, ("-lm",),
                                (kernel.HEADER,))
    assert again == path and again.read_bytes() == genuine
    assert again.stat().st_uid == os.getuid() and again.stat().st_mode & 0o022 == 0
    (line,) = cache_warnings(caplog)
    assert str(path) in line and "built again" in line


@needs_cc
def test_a_text_file_in_place_of_a_library_is_compiled_again(cache_home, caplog):
    path = kernel.cached_build(kernel.SOURCE, "fhobs_kernel", kernel.LIBRARY_FLAGS, ("-lm",),
                               (kernel.HEADER,))
    path.write_text("not a library")
    again = kernel.cached_build(kernel.SOURCE, "fhobs_kernel", kernel.LIBRARY_FLAGS, ("-lm",),
                                (kernel.HEADER,))
    assert again.read_bytes()[:4] == ELF_MAGIC
    (line,) = cache_warnings(caplog)
    assert "ELF file expected" in line


def test_a_cache_folder_others_may_write_is_not_used(cache_home, caplog):
    cache_home.mkdir(parents=True)
    cache_home.chmod(0o777)
    with pytest.raises(PermissionError, match="may be written by others"):
        kernel.cache_dir()
    (line,) = cache_warnings(caplog)
    assert f"cache folder {cache_home} is not used" in line


@needs_cc
def test_a_text_file_in_place_of_a_cached_fmu_is_built_again(cache_home, tmp_path, caplog):
    design = design_observer(*PLANT, rho=2.0)
    first = build_fmus(design, tmp_path / "a", kinds=("observer",))["observer"]
    (entry,) = (cache_home / "fmus").glob("observer_*.fmu")
    entry.write_text("37 bytes of text, not an FMU at all.\n")
    again = build_fmus(design, tmp_path / "b", kinds=("observer",))["observer"]
    assert fmu_guid(first) is not None and fmu_guid(again) not in (None, fmu_guid(first))
    with zipfile.ZipFile(again) as archive:
        assert archive.testzip() is None
    assert fmu_guid(entry) == fmu_guid(again)  # the entry built again (a new GUID)
    (line,) = cache_warnings(caplog)
    assert str(entry) in line and "FMU expected" in line


@needs_cc
def test_a_foreign_cached_fmu_is_not_copied(cache_home, tmp_path, caplog):
    design = design_observer(*PLANT, rho=2.0)
    build_fmus(design, tmp_path / "a", kinds=("observer",))
    (entry,) = (cache_home / "fmus").glob("observer_*.fmu")
    foreign(entry, 0o666)
    build_fmus(design, tmp_path / "b", kinds=("observer",))
    assert entry.stat().st_uid == os.getuid() and entry.stat().st_mode & 0o022 == 0
    assert len(cache_warnings(caplog)) == 1


@needs_cc
def test_a_text_file_in_place_of_a_cached_object_is_compiled_again(cache_home, tmp_path,
                                                                    caplog):
    compiler = shutil.which("cc") or shutil.which("gcc")
    sources = Path(native_build.__file__).parent
    first = native_build.cached_object(sources, "noise.c", tmp_path / "out", compiler)
    assert first.parent == cache_home / "objects"
    genuine = first.read_bytes()
    first.write_text("int main;")
    again = native_build.cached_object(sources, "noise.c", tmp_path / "out2", compiler)
    assert again.read_bytes() == genuine
    (line,) = cache_warnings(caplog)
    assert "ELF file expected" in line


def test_a_foreign_design_pickle_is_not_read(cache_home, caplog):
    calls = []
    compute = lambda: calls.append(1) or design_observer(*PLANT, rho=2.0)  # noqa: E731
    cached("test", 1, compute, check=lambda design: None)
    (path,) = (cache_home / "designs").glob("test_*.pickle")
    foreign(path, 0o644 if os.geteuid() == 0 else 0o646)
    _, hit = cached("test", 1, compute, check=lambda design: None)
    assert not hit and len(calls) == 2
    (line,) = cache_warnings(caplog)
    assert str(path) in line


@pytest.mark.slow
@needs_cc
def test_an_unusable_cache_folder_builds_without_it(unusable_cache, tmp_path, caplog):
    design = design_observer(*PLANT, rho=2.0)
    result, hit = cached("test", 1, lambda: design, check=lambda design: None)
    assert result is design and not hit
    path = kernel.cached_build(kernel.SOURCE, "fhobs_kernel", kernel.LIBRARY_FLAGS, ("-lm",),
                               (kernel.HEADER,))
    assert path.read_bytes()[:4] == ELF_MAGIC and unusable_cache not in path.parents
    built = build_fmus(design, tmp_path / "out", kinds=("observer",))
    assert fmu_guid(built["observer"]) is not None
    native = build_native_fmus(design, tmp_path / "native", kinds=("observer",))
    assert fmu_guid(native["observer"]) is not None
    (line,) = {line for line in cache_warnings(caplog)}  # one line, however many caches
    assert f"the cache folder {unusable_cache} is not used" in line


@pytest.mark.slow
@needs_cc
def test_a_full_cache_is_skipped_with_one_warning(cache_home, tmp_path, caplog, monkeypatch):
    def full(source, target):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    monkeypatch.setattr(fhobs.build, "cache_copy", full)
    monkeypatch.setattr(native_build, "cache_copy", full)
    design = design_observer(*PLANT, rho=2.0)
    built = build_fmus(design, tmp_path / "out", kinds=("observer",))
    assert fmu_guid(built["observer"]) is not None
    native = build_native_fmus(design, tmp_path / "native", kinds=("observer",))
    assert fmu_guid(native["observer"]) is not None
    lines = cache_warnings(caplog)
    assert lines and all("No space left on device" in line for line in lines)
    assert {line.split(" is not used")[0] for line in lines} == {
        f"fhobs: the cache folder {cache_home / 'fmus'}",
        f"fhobs: the cache folder {cache_home / 'objects'}"}
