"""The numpy-only core of fhobs: everything that runs inside the FMUs.

The design and its records (``gains``), the extended model (``disturbance``), the certificate
(``certificate``), the discrete-time observers (``runtime``, ``injection``, ``dilation``,
``linalg``), the plant (``plant``), the Kalman filter (``kalman_filter``), the compiled step kernel
(``kernel`` with ``kernel.c``), the argument checks (``validation``) and the exception
(``errors``). The modules import one another relatively and nothing but numpy and the standard
library, so :mod:`fhobs.build` copies this folder whole into each FMU's resources.
"""
