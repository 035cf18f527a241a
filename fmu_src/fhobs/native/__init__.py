"""Native FMUs: FMI 2.0 co-simulation FMUs of compiled C (the step kernel and an FMI layer),
with no Python at run time (:mod:`fhobs.native.build`)."""
