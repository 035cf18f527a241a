"""The package's folders are its layers and data flows one way (docs/architecture.md): each
module imports only from its own layer and the layers below it, resolved from the source."""

import ast
import importlib.util
from pathlib import Path

import fhobs
import pytest

import harness

PACKAGE = Path(fhobs.__file__).parent
COMMON = {"fhobs.errors", "fhobs.extras", "fhobs.paper", "fhobs.core"}
ALLOWED = {
    "core": {"fhobs.core"},
    "design": COMMON | {"fhobs.design"},
    "fmu": {"fhobs.core", "fhobs.fmu"},
    "model_description": COMMON | {"fhobs.design", "fhobs.fmu"},
    "build": COMMON | {"fhobs.design", "fhobs.fmu", "fhobs.model_description", "fhobs.build"},
    "native": COMMON | {"fhobs.design", "fhobs.fmu", "fhobs.model_description", "fhobs.build",
               "fhobs.native"},
    "cli": COMMON | {"fhobs.design", "fhobs.build", "fhobs.native", "fhobs.cli"},
    "base": COMMON,
    "top": {"fhobs"},
}
"""Layer -> the fhobs packages and modules its modules may import (with their submodules)."""


def module_name(path: Path, root: Path, top: str) -> str:
    """Dotted name of the module at ``path`` under the package ``top`` rooted at ``root``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([top, *parts])


def imported_modules(path: Path, name: str, names: bool = True) -> set[str]:
    """Absolute names of the modules imported by the source at ``path`` (module ``name``),
    relative imports resolved; with ``names``, ``from module import name`` also counts
    ``module.name`` (which is a module for ``from package import module``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found |= {base} | ({f"{base}.{alias.name}" for alias in node.names} if names
                               else set())
    return found


def layer_of(name: str) -> str:
    """The layer of an fhobs module: its folder, or its own name for the top-level modules."""
    parts = name.split(".")
    if len(parts) == 1:
        return "top"  # fhobs/__init__.py: the public API, imported from every layer on use
    return "base" if parts[1] in ("errors", "extras", "paper") else parts[1]


def allowed(imported: str, layer: str) -> bool:
    """Whether an fhobs module of ``layer`` may import ``imported``."""
    return any(imported == a or imported.startswith(a + ".") for a in ALLOWED[layer])


FHOBS_MODULES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", FHOBS_MODULES, ids=lambda p: p.relative_to(PACKAGE).as_posix())
def test_fhobs_modules_import_their_layer_and_below(path):
    name = module_name(path, PACKAGE, "fhobs")
    layer = layer_of(name)
    for imported in imported_modules(path, name):
        assert not imported.startswith("harness"), (name, imported)
        if imported.startswith("fhobs."):
            assert allowed(imported, layer), f"{name} ({layer} layer) imports {imported}"


def test_the_lower_layers_do_not_import_the_upper_ones():
    """The checks above can fail: a design module importing an FMU module is refused."""
    assert not allowed("fhobs.fmu.kinds", "design")
    assert not allowed("fhobs.native.build", "fmu")
    assert not allowed("fhobs.design.spec", "core")
    assert not allowed("fhobs.design.observer", "base")
    assert allowed("fhobs.core.gains", "design")


HARNESS = Path(harness.__file__).parent
ALL_MODULES = [(p, module_name(p, PACKAGE, "fhobs")) for p in FHOBS_MODULES] + [
    (p, module_name(p, HARNESS, "harness")) for p in sorted(HARNESS.rglob("*.py"))]


@pytest.mark.parametrize("path, name", ALL_MODULES, ids=[name for _, name in ALL_MODULES])
def test_every_import_of_ours_names_a_module_that_exists(path, name):
    """Every fhobs and harness import names an existing module (a moved module leaves no
    stale import behind, even one made only on use inside a function)."""
    for imported in imported_modules(path, name, names=False):
        if imported.split(".")[0] in ("fhobs", "harness"):
            assert importlib.util.find_spec(imported) is not None, f"{name} imports {imported}"


def test_the_module_map_names_what_each_module_imports():
    """docs/architecture.md's module map: each row of one module names, in its "depends on"
    column, every module of ours that the module imports (by its dotted name, its name within
    fhobs or harness, its own name, or a package that holds it)."""
    import re

    text = (PACKAGE.parents[1] / "docs" / "architecture.md").read_text()
    rows = re.findall(r"^\| `((?:fmu_src/)?(?:fhobs|harness)/[\w/]+\.py)` \|.*\| ([^|]*) \|$",
                      text, flags=re.MULTILINE)
    assert len(rows) > 30
    missing = []
    for relative, cell in rows:
        top = relative.removeprefix("fmu_src/").split("/")[0]
        root = PACKAGE if top == "fhobs" else Path(harness.__file__).parent
        path = root.parent / relative.removeprefix("fmu_src/")
        name = module_name(path, root, top)
        words = set(re.findall(r"[\w.]+", cell))
        for imported in imported_modules(path, name, names=False):
            parts = imported.split(".")
            if parts[0] not in ("fhobs", "harness") or imported in (name, parts[0]):
                continue
            if name.startswith(imported + "."):
                continue  # the module's own package
            spellings = {imported, ".".join(parts[1:]), parts[-1]}
            spellings |= {".".join(parts[:i]) for i in range(2, len(parts))}
            if not spellings & words and "all of" not in cell:
                missing.append(f"{relative}: {imported}")
    assert not missing, missing
