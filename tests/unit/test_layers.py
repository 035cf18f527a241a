"""The package's folders are its layers and data flows one way (docs/architecture.md): each
module imports only from its own layer and the layers below it, resolved from the source."""

import ast
from pathlib import Path

import fhobs
import pytest

import harness

PACKAGE = Path(fhobs.__file__).parent
COMMON = {"fhobs", "fhobs.errors", "fhobs.extras", "fhobs.paper", "fhobs.core"}
ALLOWED = {
    "core": {"fhobs.core"},
    "design": COMMON | {"fhobs.design"},
    "fmu": {"fhobs.core", "fhobs.fmu"},
    "build": COMMON | {"fhobs.design", "fhobs.fmu", "fhobs.build"},
    "native": COMMON | {"fhobs.design", "fhobs.fmu", "fhobs.build", "fhobs.native"},
    "cli": COMMON | {"fhobs.design", "fhobs.build", "fhobs.native", "fhobs.cli"},
    "top": COMMON | {"fhobs.design", "fhobs.build", "fhobs.native", "fhobs.fmu"},
}
"""Layer -> the fhobs packages and modules its modules may import (with their submodules)."""


def module_name(path: Path, root: Path, top: str) -> str:
    """Dotted name of the module at ``path`` under the package ``top`` rooted at ``root``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([top, *parts])


def imported_modules(path: Path, name: str) -> set[str]:
    """Absolute names of the modules imported by the source at ``path`` (module ``name``),
    relative imports resolved, ``from package import module`` counted as the module."""
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
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return found


def layer_of(name: str) -> str:
    """The layer of an fhobs module: its folder, or its own name for the top-level modules."""
    parts = name.split(".")
    if len(parts) == 1:
        return "top"
    if parts[1] in ALLOWED:
        return parts[1]
    return "top" if parts[1] in ("errors", "extras", "paper") else parts[1]


def allowed(imported: str, layer: str) -> bool:
    """Whether an fhobs module of ``layer`` may import ``imported``."""
    return any(imported == a or (a != "fhobs" and imported.startswith(a + "."))
               for a in ALLOWED[layer])


FHOBS_MODULES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", FHOBS_MODULES, ids=lambda p: p.relative_to(PACKAGE).as_posix())
def test_fhobs_modules_import_their_layer_and_below(path):
    name = module_name(path, PACKAGE, "fhobs")
    layer = layer_of(name)
    for imported in imported_modules(path, name):
        assert not imported.startswith("harness"), (name, imported)
        if imported.startswith("fhobs.") and layer != "top":
            assert allowed(imported, layer), f"{name} ({layer} layer) imports {imported}"


def test_the_lower_layers_do_not_import_the_upper_ones():
    """The checks above can fail: a design module importing an FMU module is refused."""
    assert not allowed("fhobs.fmu.kinds", "design")
    assert not allowed("fhobs.native.build", "fmu")
    assert not allowed("fhobs.design.spec", "core")
    assert allowed("fhobs.core.gains", "design")


def test_harness_is_above_fhobs():
    """harness imports fhobs, never the other way (checked above); the harness's own modules
    resolve, so the walk covers them."""
    root = Path(harness.__file__).parent
    names = {module_name(p, root, "harness") for p in root.rglob("*.py")}
    assert {"harness.reference", "harness.zoo", "harness.figures"} <= names
