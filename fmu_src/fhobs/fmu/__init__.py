"""pythonfmu slave classes of the FMUs that :mod:`fhobs.build` writes.

``kinds`` declares every FMU kind, ``options`` the build options; ``slave_base`` holds the
FMI plumbing the slaves share and the generic observer slave; ``prescribed_time``,
``kalman``, ``supervised`` and ``plant`` hold the slave classes of the kinds with checks of
their own. This package and :mod:`fhobs.core` are copied whole into each FMU's
``resources/`` under a build-unique package name, so they import one another relatively and,
besides, only numpy, pythonfmu and the standard library.
"""
