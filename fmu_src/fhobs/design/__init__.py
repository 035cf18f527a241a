"""The design layer: a plant spec -> a certified design record.

``spec`` (the plant spec: TOML loading and the validation of every design), ``limits`` (sizes
and magnitudes the design handles), ``homogenisation`` (observability index, L0, G_d), ``lmi``
(the LMIs of Theorems 1 and 2 and the Luenberger baseline, cvxpy + Clarabel), ``settling``
(predicted settling time and peaking), ``kalman`` (the steady-state Kalman filter baseline),
``feedback`` (the LQR state feedback of the predicted closed loops), ``tuning`` (the noise-aware
search of ``--tune-noise``) and ``observer`` (``design_observer``, ``design_for_spec``: the
steps above put together). The modules are imported on use: loading a spec needs no cvxpy.
"""
