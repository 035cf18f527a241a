"""pythonfmu slave classes of the FMUs that :mod:`fhobs.build` writes.

``slave_base`` holds the FMI plumbing the three slaves share; ``observer``, ``luenberger``
and ``plant`` are the slave scripts. They are copied into each FMU's ``resources/`` under a
build-unique package name, so they import numpy-only modules only.
"""
