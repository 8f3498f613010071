"""Numba-jitted physics core: one module per sub-model, composed by ``kernel``.

Sub-models (paper equation numbers in their docstrings): ``valve`` (spool, orifice areas),
``flow`` (orifice flow), ``tube`` (delay, attenuation, transmission line), ``chamber``
(pressures, volumes), ``piston`` (forces, friction, stops), ``effects`` (beyond the paper's
model) and ``derived`` (areas, force scale, valve currents, gas constants, tube delay).
``layout`` names the rows of the parameter, state, history and output arrays; ``vecmath``
holds the SIMD-friendly exp, log and acos.

The integrator ``kernel`` is a facade over its five parts: ``constants`` (the per-environment
``Constants`` and their cache), ``nodes`` (algebraic flow balances), ``right_hand_side``
(derivatives, RK4), ``general_path`` (one environment through a control period) and
``batch_path`` (SIMD chunks, the step functions).
"""
