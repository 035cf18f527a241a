"""The value references of every FMU kind's variables, the stability contract of
docs/fmus.md ("Value references"): ``tests/value_references.json`` holds them for the bundled
pendulum spec's design (every record, a disturbance model, E), and
tests/unit/test_value_references.py checks that every variable there keeps its value
reference. Regenerate the file only when a kind or a variable is added (new variables are
appended, so the old ones keep theirs)::

    python tests/value_references.py --write

The value references are counted here from the declaration's order
(:meth:`fhobs.fmu.kinds.Kind.starts`), one per scalar element, as both builds number them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.fmu.kinds import KINDS
from fhobs.fmu.options import fmu_options
from fhobs.fmu.variables import element_names

SNAPSHOT = Path(__file__).with_name("value_references.json")
SPEC = Path(__file__).resolve().parents[1] / "examples" / "pendulum.toml"


def pendulum_design() -> ObserverDesign:
    """The design of examples/pendulum.toml (with its [noise] table's records)."""
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import load_spec

    return design_for_spec(load_spec(SPEC))


def value_references(design: ObserverDesign) -> dict[str, dict[str, int]]:
    """``{kind: {scalar variable: value reference}}`` of every kind the design builds."""
    kinds = [name for name, kind in KINDS.items() if kind.built_when(design)]
    options = fmu_options(design, kinds)
    table = {}
    for name in kinds:
        kind = KINDS[name]
        names = [element for variable, start in kind.starts(kind.runs(design), options)
                 for element in element_names(variable.name, np.shape(start))]
        table[name] = {element: vr for vr, element in enumerate(names)}
    return table


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/value_references.py --write  (rewrites the contract)")
    SNAPSHOT.write_text(json.dumps(value_references(pendulum_design()), indent=1) + "\n")
    print(f"wrote {SNAPSHOT}")
