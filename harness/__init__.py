"""fmpy co-simulation harness: system descriptions, a Jacobi master, SSP export, CLI."""
