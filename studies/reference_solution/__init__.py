"""High-accuracy reference solution of the actuator model of ``docs/model.md``.

This package is an *independent* implementation of the model (it shares nothing with the
fixed-step kernel in :mod:`pneumatic_env.physics` but the parameter names). It integrates
the model with an adaptive, high-order Runge-Kutta method (scipy's ``DOP853`` stepper by
default, driven step by step) at tight tolerances and treats every discontinuity of the
model as a hybrid-system switch located by event detection, so that its result can serve
as the "exact" solution the kernel is tested against. It is slow (pure Python, about
1-5 s per simulated second); use it for tests, not for training.

Equation numbers refer to Richer & Hurmuzlu, *A High Performance Pneumatic Force Actuator
System: Part I* (ASME JDSMC 122, 2000), with the corrections of ``docs/model.md``.

The parts: ``model`` (the constants and the sub-models of the paper, written
independently of the kernel), ``events`` and ``hybrid`` (the hybrid-system integrator,
described below), ``simulate`` (``simulate_reference``) and ``segmented_tube``
(``simulate_segmented_line``, the independent reference of the kernel's transmission
line). This package keeps their public names.

How the hybrid system is integrated
-----------------------------------
Continuous state ``y = [x_s, v_s, x_d, v_d, P1, P2, x, v]``:

- ``x_s, v_s``: the spool (Eq. 38), driven by the zero-order-hold coil current.
- ``x_d, v_d``: the *delayed* spool, ``x_d(t) = x_s(t - tau)``. The spool is a linear
  time-invariant system driven by a piecewise-constant current, so its delayed trajectory
  is the solution of the same ODE driven by the delayed current ``i_c(t - tau)`` and
  started from the initial spool state at ``t = tau``; before ``tau`` it is frozen at the
  initial position (the history before ``t = 0`` is the initial state). This gives the
  delayed spool position to integration accuracy without interpolating a history.
- ``P1, P2``: chamber pressures (Eq. 14/16, corrected Eq. 55).
- ``x, v``: piston (Eq. 1).

Discrete state, changed only at located events (the integration restarts there):

- the flow regime (laminar/turbulent) of each of the four valve-tube paths: the tube
  resistance jumps at ``Re = Re_t`` (Eqs. 33, 35), so the right-hand side is discontinuous
  there; the regime is locked during a sub-interval and switched at the located crossing;
- the piston mode: ``rest`` (stuck by static friction, or held at an end stop; ``x``, ``v``
  frozen) or ``slip`` in direction ``+1``/``-1`` (Karnopp friction, Eq. 47 corrected);
- whether the delayed spool has started to move (``t >= tau``).

Sub-intervals are further split at every control-step boundary ``t_k`` (the current
changes) and at every ``t_k + tau`` (the delayed current changes). With the literal
coupling (``tube_coupling = 1``) the delayed chamber pressures ``P_i(t - tau)`` are
needed; they are read from the dense outputs of the already computed steps, and
sub-intervals are then no longer than ``tau`` so that ``t - tau`` always lies in the
computed past (method of steps).

Points where the right-hand side is continuous but not smooth are located too and the
integration restarts there ("kink" surfaces), because a high-order step straddling them
loses its accuracy without its error estimate noticing: the delayed spool at the hole
edges (the area grows like ``x_e^(3/2)``, Eq. 44), a path's pressure ratio at ``P_cr``
and at ``flow_linear_ratio``, and a flow reversal (``alpha_in``/``alpha_out`` switch).
Event functions are checked at several points inside every step, and the step that
found an event is recomputed up to the root, so that no right-hand-side value from
beyond a switching surface pollutes the state at the switch.

Limits: with the literal coupling, kinks of the past propagate through the delay and are
not located. Grazing switches (the Reynolds number just touching ``Re_t``, the piston
velocity touching zero with the applied force at the stick threshold) make the solution
depend non-smoothly on the data; there two tolerances can disagree by more than the
tolerance.
"""

from __future__ import annotations

from .model import (
    NEUTRAL_EFFECTS,
    ModelConstants,
    chamber_pressure_rate,
    chamber_volumes,
    flow_constants,
    load_force,
    orifice_area,
    orifice_mass_flow,
    output_force,
    piston_acceleration,
    pneumatic_force,
    reduced_flow,
    reynolds_number,
    spool_acceleration,
    tube_attenuation,
    tube_resistance,
)
from .segmented_tube import simulate_segmented_line
from .simulate import simulate_reference

__all__ = [
    "ModelConstants",
    "simulate_reference",
    "simulate_segmented_line",
    "NEUTRAL_EFFECTS",
    "flow_constants",
    "orifice_area",
    "reduced_flow",
    "orifice_mass_flow",
    "reynolds_number",
    "tube_resistance",
    "tube_attenuation",
    "chamber_volumes",
    "chamber_pressure_rate",
    "pneumatic_force",
    "load_force",
    "piston_acceleration",
    "spool_acceleration",
    "output_force",
]
