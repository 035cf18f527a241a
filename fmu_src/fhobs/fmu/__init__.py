"""pythonfmu slave classes of the FMUs that :mod:`fhobs.build` writes.

``slave_base`` holds the FMI plumbing the slaves share; ``observer``, ``luenberger``,
``prescribed_time``, ``plant`` and ``kalman`` hold the slave classes. This package and
:mod:`fhobs.core` are copied whole into each FMU's ``resources/`` under a build-unique package
name, so they import one another relatively and, besides, only numpy, pythonfmu and the
standard library.
"""
