#!/usr/bin/env python3
"""Design the filtering homogeneous observer for a plant spec and build its FMUs.

Usage: ``python build_fmu.py SPEC [--out DIR] [--design-only] [--objective NAME]``.
See ``fhobs.cli`` and the README.
"""

import sys

from fhobs.cli import main

if __name__ == "__main__":
    sys.exit(main())
