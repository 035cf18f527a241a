"""Optional dependencies: the design (cvxpy, clarabel), the plots (matplotlib) and the sweeps
(distributed, pyarrow, pandas; and the design and the plots, which a sweep's points and
pictures need) are extras of the package (``pip install 'fhobs[design]'``, ``[plots]``,
``[sweep]``; ``[all]`` has them all); a runtime-only user (FMUs from a design.json, the harness
without plots) needs none of them. A module that needs one imports it through :func:`require`,
which names the extra to install when it is missing.

Examples
--------
>>> require("numpy", "design").__name__
'numpy'
"""

from __future__ import annotations

import importlib
from types import ModuleType

EXTRAS = {"design": ("cvxpy", "clarabel"), "plots": ("matplotlib",),
          "sweep": ("distributed", "pyarrow", "pandas")}
"""The extras of pyproject.toml and the modules each one installs (besides the extras it
includes: ``sweep`` includes ``design`` and ``plots``)."""


def require(module: str, extra: str) -> ModuleType:
    """Import ``module``, or raise ModuleNotFoundError saying which extra installs it.

    Raises
    ------
    ModuleNotFoundError
        ``"... needs <module>, an optional dependency: pip install 'fhobs[<extra>]'"``.

    Examples
    --------
    >>> try:
    ...     require("fhobs_no_such_module", "plots")
    ... except ModuleNotFoundError as err:
    ...     print(str(err)[-37:])
    dependency: pip install 'fhobs[plots]'
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name != module.split(".")[0]:
            raise
        raise ModuleNotFoundError(
            f"this part of fhobs needs {module}, an optional dependency: "
            f"pip install 'fhobs[{extra}]'", name=module) from err
