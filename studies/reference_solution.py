"""High-accuracy reference solution of the actuator model of ``docs/model.md``.

This module is an *independent* implementation of the model (it shares nothing with the
fixed-step kernel in :mod:`pneumatic_env.physics` but the parameter names). It integrates
the model with an adaptive, high-order Runge-Kutta method (scipy's ``DOP853`` stepper by
default, driven step by step) at tight tolerances and treats every discontinuity of the
model as a hybrid-system switch located by event detection, so that its result can serve
as the "exact" solution the kernel is tested against. It is slow (pure Python, about
1-5 s per simulated second); use it for tests, not for training.

Equation numbers refer to Richer & Hurmuzlu, *A High Performance Pneumatic Force Actuator
System: Part I* (ASME JDSMC 122, 2000), with the corrections of ``docs/model.md``.

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

import bisect
import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK45, Radau
from scipy.optimize import brentq

from pneumatic_env.physics.layout import EFFECT_NEUTRAL_VALUES

__all__ = [
    "ModelConstants",
    "simulate_reference",
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
]

# Continuous state layout of the reference integrator (independent of physics/layout.py).
IX_XS, IX_VS, IX_XD, IX_VD, IX_P1, IX_P2, IX_X, IX_V = range(8)
N_Y = 8

PISTON_FIXED, PISTON_FREE, PISTON_SPRING = 0, 1, 2
COUPLING_COMMAND, COUPLING_LITERAL = 0, 1

# The four valve-tube paths, in this order (and the chamber each one feeds):
#   0: chamber 1 <-> supply  through A_in(x_s)
#   1: chamber 1 <-> exhaust through A_ex(x_s) = A_in(-x_s)
#   2: chamber 2 <-> supply  through A_ex(x_s)
#   3: chamber 2 <-> exhaust through A_in(x_s)
PATH_CHAMBER = (0, 0, 1, 1)

FIRST_STEP_AFTER_EDGE = 1e-9  # s, first step after the delayed spool crosses a hole edge
EVENT_SAMPLES = 8  # points per integration step at which the event functions are checked
_METHODS = {"DOP853": DOP853, "Radau": Radau, "LSODA": LSODA, "RK45": RK45, "BDF": BDF}

_REQUIRED = (
    "gas_constant_j_per_kg_k", "heat_capacity_ratio", "temperature_k",
    "ambient_pressure_pa", "supply_pressure_pa", "air_viscosity_pa_s",
    "alpha_in", "alpha_out", "alpha_motion",
    "spool_mass_kg", "spool_damping_n_s_per_m", "spool_spring_n_per_m",
    "coil_force_n_per_a", "discharge_coefficient", "hole_radius_m",
    "spool_half_width_m", "holes_per_path",
    "tube_length_m", "tube_inner_diameter_m", "reynolds_turbulent", "tube_coupling",
    "bore_diameter_m", "rod_diameter_m", "stroke_m", "dead_volume_cap_m3",
    "dead_volume_rod_m3", "piston_mass_kg", "static_friction_n", "dynamic_friction_n",
    "viscous_friction_n_s_per_m", "leakage_area_m2",
    "piston_mode", "fixed_position_m", "load_mass_kg", "load_force_n",
    "spring_stiffness_n_per_m", "spring_rest_position_m",
    "flow_linear_ratio",
)


# Effects beyond the paper's model (docs/effects.md) and their neutral values. The
# reference implements docs/model.md only, so it refuses a parameter set that switches
# one of them on rather than silently computing a different model.
NEUTRAL_EFFECTS = EFFECT_NEUTRAL_VALUES


# --------------------------------------------------------------------------------------
# Constants
# --------------------------------------------------------------------------------------

def flow_constants(k: float, gas_constant: float) -> tuple[float, float, float]:
    """``(C1, C2, P_cr)`` of the orifice flow (Eq. 40, exponents corrected).

    ``C1 = sqrt(k/R (2/(k+1))^((k+1)/(k-1)))``, ``C2 = sqrt(2k/(R(k-1)))``,
    ``P_cr = (2/(k+1))^(k/(k-1))``; 0.040418, 0.156174, 0.528 for air.
    """
    c1 = math.sqrt(k / gas_constant * (2.0 / (k + 1.0)) ** ((k + 1.0) / (k - 1.0)))
    c2 = math.sqrt(2.0 * k / (gas_constant * (k - 1.0)))
    p_cr = (2.0 / (k + 1.0)) ** (k / (k - 1.0))
    return c1, c2, p_cr


@dataclass(frozen=True)
class ModelConstants:
    """Parameters and derived constants of one parameter set, in SI units."""

    R: float
    k: float
    T: float
    sqrt_T: float
    p_a: float
    p_s: float
    mu: float
    alpha_in: float
    alpha_out: float
    alpha: float
    # spool and orifice
    m_s: float
    c_s: float
    k_s: float
    k_fc: float
    c_f: float
    r_h: float
    p_w: float
    n_h: float
    c1: float
    c2: float
    p_cr: float
    r_lin: float
    m_r_lin: float  # unlinearised reduced flow at r_lin (0 when r_lin >= 1)
    # tube
    tube_length: float
    tube_d: float
    re_t: float
    c_sound: float
    tau: float
    coupling: int
    # cylinder and load
    a1: float
    a2: float
    a_r: float
    stroke: float
    v01: float
    v02: float
    mass: float  # M_p + M_L
    f_sf: float
    f_df: float
    f_stick: float  # max(F_sf, F_df)
    beta: float
    a_leak: float
    piston_mode: int
    x_fixed: float
    f_load: float
    k_env: float
    x_rest: float

    @classmethod
    def from_params(cls, params: dict) -> "ModelConstants":
        missing = [n for n in _REQUIRED if n not in params]
        if missing:
            raise KeyError(f"parameter set lacks {missing}")
        switched_on = [n for n, neutral in NEUTRAL_EFFECTS.items()
                       if n in params and float(params[n]) != neutral]
        if switched_on:
            raise NotImplementedError(
                f"the reference solution implements docs/model.md only; effects switched "
                f"on: {switched_on} (set them to their neutral values {NEUTRAL_EFFECTS})")
        p = {n: float(params[n]) for n in _REQUIRED}
        R, k, T = p["gas_constant_j_per_kg_k"], p["heat_capacity_ratio"], p["temperature_k"]
        c1, c2, p_cr = flow_constants(k, R)
        r_lin = p["flow_linear_ratio"]
        c_sound = math.sqrt(k * R * T)
        a1 = math.pi * p["bore_diameter_m"] ** 2 / 4.0
        a_r = math.pi * p["rod_diameter_m"] ** 2 / 4.0
        mode = int(round(p["piston_mode"]))
        coupling = int(round(p["tube_coupling"]))
        if mode not in (PISTON_FIXED, PISTON_FREE, PISTON_SPRING):
            raise ValueError(f"piston_mode must be 0, 1 or 2, got {p['piston_mode']}")
        if coupling not in (COUPLING_COMMAND, COUPLING_LITERAL):
            raise ValueError(f"tube_coupling must be 0 or 1, got {p['tube_coupling']}")
        const = cls(
            R=R, k=k, T=T, sqrt_T=math.sqrt(T),
            p_a=p["ambient_pressure_pa"], p_s=p["supply_pressure_pa"],
            mu=p["air_viscosity_pa_s"],
            alpha_in=p["alpha_in"], alpha_out=p["alpha_out"], alpha=p["alpha_motion"],
            m_s=p["spool_mass_kg"], c_s=p["spool_damping_n_s_per_m"],
            k_s=p["spool_spring_n_per_m"], k_fc=p["coil_force_n_per_a"],
            c_f=p["discharge_coefficient"], r_h=p["hole_radius_m"],
            p_w=p["spool_half_width_m"], n_h=p["holes_per_path"],
            c1=c1, c2=c2, p_cr=p_cr, r_lin=r_lin, m_r_lin=0.0,
            tube_length=p["tube_length_m"], tube_d=p["tube_inner_diameter_m"],
            re_t=p["reynolds_turbulent"], c_sound=c_sound,
            tau=p["tube_length_m"] / c_sound, coupling=coupling,
            a1=a1, a2=a1 - a_r, a_r=a_r, stroke=p["stroke_m"],
            v01=p["dead_volume_cap_m3"], v02=p["dead_volume_rod_m3"],
            mass=p["piston_mass_kg"] + p["load_mass_kg"],
            f_sf=p["static_friction_n"], f_df=p["dynamic_friction_n"],
            f_stick=max(p["static_friction_n"], p["dynamic_friction_n"]),
            beta=p["viscous_friction_n_s_per_m"], a_leak=p["leakage_area_m2"],
            piston_mode=mode, x_fixed=p["fixed_position_m"],
            f_load=p["load_force_n"], k_env=p["spring_stiffness_n_per_m"],
            x_rest=p["spring_rest_position_m"],
        )
        if r_lin < 1.0:
            object.__setattr__(const, "m_r_lin", _reduced_flow_exact(const, r_lin))
        return const


# --------------------------------------------------------------------------------------
# Sub-models
# --------------------------------------------------------------------------------------

def spool_acceleration(m: ModelConstants, x_s: float, v_s: float, i_c: float) -> float:
    """Spool acceleration from ``M_s x_s'' + c_s x_s' + 2 k_s x_s = K_fc i_c`` (Eq. 38)."""
    return (m.k_fc * i_c - m.c_s * v_s - 2.0 * m.k_s * x_s) / m.m_s


def orifice_area(m: ModelConstants, x_s: float) -> float:
    """Area of the path that opens for positive spool displacement, ``A_in(x_s)``.

    Eqs. 41-44 with the corrected effective opening ``x_e = x_s - (p_w - R_h)`` (Eq. 43):
    ``n_h`` circle segments of height ``x_e`` of holes of radius ``R_h``. The other path
    is ``A_ex(x_s) = A_in(-x_s)`` (Eq. 45).
    """
    r = m.r_h
    x_e = x_s - (m.p_w - r)
    if x_e <= 0.0:
        return 0.0
    if x_e >= 2.0 * r:
        return math.pi * m.n_h * r * r
    h = r - x_e
    return m.n_h * (r * r * math.acos(h / r) - h * math.sqrt(x_e * (2.0 * r - x_e)))


def _reduced_flow_exact(m: ModelConstants, r: float) -> float:
    """Reduced flow of Eq. 52 without the linearisation near ``r = 1``."""
    if r <= m.p_cr:
        return m.c1
    return m.c2 * r ** (1.0 / m.k) * math.sqrt(max(0.0, 1.0 - r ** ((m.k - 1.0) / m.k)))


def reduced_flow(m: ModelConstants, r: float) -> float:
    """Reduced flow ``m_r(r)`` of the pressure ratio ``r = P_d / P_u`` in ``[0, 1]``.

    Choked (``C1``) for ``r <= P_cr``, subsonic (Eq. 52) up to ``r_lin =
    flow_linear_ratio``, and linearised to zero above it:
    ``m_r(r) = m_r(r_lin) (1 - r) / (1 - r_lin)`` for ``r_lin < r <= 1`` (docs/model.md,
    *Numerics*), which keeps the slope finite at ``r -> 1``.
    """
    if r > m.r_lin and m.r_lin < 1.0:
        return m.m_r_lin * (1.0 - r) / (1.0 - m.r_lin) if r < 1.0 else 0.0
    return _reduced_flow_exact(m, r)


def orifice_mass_flow(m: ModelConstants, area: float, p_from: float, p_to: float) -> float:
    """Signed mass flow (kg/s) through an orifice, positive from ``p_from`` to ``p_to``.

    Eq. 39 (with Eq. 52's reduced flow): ``C_f A P_u / sqrt(T) m_r(P_d / P_u)``, the flow
    passing from the higher pressure ``P_u`` to the lower ``P_d``.
    """
    if area <= 0.0 or p_from == p_to:
        return 0.0
    if p_from > p_to:
        return m.c_f * area * p_from / m.sqrt_T * reduced_flow(m, p_to / p_from)
    return -m.c_f * area * p_to / m.sqrt_T * reduced_flow(m, p_from / p_to)


def reynolds_number(m: ModelConstants, mdot: float) -> float:
    """Tube Reynolds number of a mass flow, ``Re = 4 |mdot| / (pi D mu)``."""
    return 4.0 * abs(mdot) / (math.pi * m.tube_d * m.mu)


def tube_resistance(m: ModelConstants, reynolds: float, turbulent: bool) -> float:
    """Tube resistance ``R_t``: laminar ``32 mu / D^2`` (Eq. 33) or wholly turbulent
    ``0.158 mu Re^(3/4) / D^2`` (Blasius, Eqs. 34-35).

    The regime is passed in (``turbulent = Re >= Re_t``) because the integrator locks it
    between located switching times.
    """
    if turbulent:
        return 0.158 * m.mu * reynolds ** 0.75 / m.tube_d ** 2
    return 32.0 * m.mu / m.tube_d ** 2


def tube_attenuation(m: ModelConstants, r_t: float, p_end: float) -> float:
    """Tube flow attenuation ``phi = exp(-R_t R T tau / (2 P))`` (Eqs. 25, 30), with
    ``P`` the tube-end (chamber) pressure and ``tau = L_t / c``."""
    return math.exp(-r_t * m.R * m.T * m.tau / (2.0 * p_end))


def chamber_volumes(m: ModelConstants, x: float) -> tuple[float, float]:
    """Chamber volumes ``V1 = V01 + A1 (L/2 + x)``, ``V2 = V02 + A2 (L/2 - x)`` (Eq. 15)."""
    half = 0.5 * m.stroke
    return m.v01 + m.a1 * (half + x), m.v02 + m.a2 * (half - x)


def chamber_pressure_rate(m: ModelConstants, p: float, volume: float, volume_rate: float,
                          mdot_in: float, mdot_out: float) -> float:
    """``dP/dt = R T / V (alpha_in mdot_in - alpha_out mdot_out) - alpha P V' / V``
    (Eq. 14 with Eq. 15, i.e. Eq. 16 / corrected Eq. 55); ``mdot_in``, ``mdot_out >= 0``."""
    return (m.R * m.T * (m.alpha_in * mdot_in - m.alpha_out * mdot_out)
            - m.alpha * p * volume_rate) / volume


def pneumatic_force(m: ModelConstants, p1: float, p2: float) -> float:
    """Actuator force ``F_p = P1 A1 - P2 A2 - P_a A_r`` (right-hand side of Eq. 1)."""
    return p1 * m.a1 - p2 * m.a2 - m.p_a * m.a_r


def load_force(m: ModelConstants, x: float) -> float:
    """External force ``F_L`` resisting extension: ``load_force_n`` in free mode,
    ``k_env (x - x_rest)`` in spring mode, 0 in fixed mode (docs/model.md)."""
    if m.piston_mode == PISTON_FREE:
        return m.f_load
    if m.piston_mode == PISTON_SPRING:
        return m.k_env * (x - m.x_rest)
    return 0.0


def piston_acceleration(m: ModelConstants, applied_force: float, v: float,
                        slip_direction: float) -> float:
    """Piston acceleration while slipping (Eq. 1 with Karnopp friction, Eq. 47 corrected):
    ``(M_p + M_L) x'' = (F_p - F_L) - beta v - F_df s``, ``s = sign(v)`` the slip direction
    (locked during a slip phase, so it is defined at ``v = 0`` too)."""
    return (applied_force - m.beta * v - m.f_df * slip_direction) / m.mass


def output_force(m: ModelConstants, p1: float, p2: float, x: float) -> float:
    """Force output: ``F_p`` in fixed and free mode, ``k_env (x - x_rest)`` in spring mode."""
    if m.piston_mode == PISTON_SPRING:
        return m.k_env * (x - m.x_rest)
    return pneumatic_force(m, p1, p2)


# --------------------------------------------------------------------------------------
# Hybrid integrator
# --------------------------------------------------------------------------------------

class _EventSet:
    """The event functions watched during one integration, evaluated all at once:
    selected switching surfaces, then the piston-mode events."""

    def __init__(self, sim: "_HybridSimulation", surface_index: np.ndarray,
                 directions: np.ndarray, actions: list):
        self.sim = sim
        self.surface_index = surface_index
        self.directions = directions
        self.actions = actions
        self.piston_actions = actions[len(surface_index):]

    def __len__(self) -> int:
        return len(self.actions)

    def values(self, t: float, y: np.ndarray) -> np.ndarray:
        g = self.sim.surfaces(t, y)[self.surface_index]
        if self.piston_actions:
            g = np.concatenate([g, self.sim.piston_event_values(y, self.piston_actions)])
        return g


@dataclass
class _Piece:
    """Result of one event-stopped integration."""

    t_end: float
    y_end: np.ndarray
    event: int | None  # index of the event that stopped it
    t_step: float  # start of the last step
    y_step: np.ndarray
    dense_steps: list  # (t0, t1, dense output) of the completed steps (literal only)


def _active_events(g_old: np.ndarray, g_new: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Events whose function changed sign in their direction (solve_ivp's convention)."""
    up = (g_old <= 0) & (g_new >= 0)
    down = (g_old >= 0) & (g_new <= 0)
    return np.nonzero((up & (direction > 0)) | (down & (direction < 0))
                      | ((up | down) & (direction == 0)))[0]


def _event_root(events: _EventSet, e: int, dense, t_a: float, t_b: float) -> float:
    """Root of event ``e`` along the dense output in ``[t_a, t_b]``."""
    def f(t):
        return events.values(t, dense(t))[e]
    fa, fb = f(t_a), f(t_b)
    if fa == 0.0:
        # The function starts on the surface (a slip phase starts at v = 0). It first
        # moves to the side the event watches crossings from, possibly only briefly
        # (the force can turn back within microseconds): find a point on that side.
        side = -events.directions[e]
        for t in t_a + (t_b - t_a) * np.geomspace(1e-9, 1.0, 40)[:-1]:
            ft = f(t)
            if ft * side > 0.0:
                t_a, fa = t, ft
                break
        else:
            return t_a
    if fb == 0.0:
        return t_b
    if fa * fb > 0.0:  # a sign change of round-off size between samples
        return t_a if abs(fa) < abs(fb) else t_b
    return brentq(f, t_a, t_b, xtol=4 * np.finfo(float).eps, rtol=4 * np.finfo(float).eps)


class _HybridSimulation:
    def __init__(self, m: ModelConstants, currents: np.ndarray, dt: float, y0: np.ndarray,
                 rtol: float, atol, method: str):
        if method not in _METHODS:
            raise ValueError(f"method must be one of {sorted(_METHODS)}, got {method!r}")
        self.m = m
        self.currents = currents
        self.dt = dt
        self.y = y0.copy()
        self.y0 = y0.copy()
        self.rtol = rtol
        self.atol = atol
        self.method = method
        self.t_end = len(currents) * dt
        self.use_tube = m.tau > 0.0
        self.literal = m.coupling == COUPLING_LITERAL and self.use_tube
        # literal coupling: dense outputs of the computed past
        self.hist_t0: list[float] = []
        self.hist_sol: list = []
        # segment-wise constants
        self.i_now = 0.0
        self.i_delayed = 0.0
        self.delayed_active = False
        # discrete state
        self.turbulent = [False] * 4
        self.piston = "fixed" if m.piston_mode == PISTON_FIXED else "rest"
        self.slip_dir = 0.0
        self.stop_side = 0.0  # -1/+1 while resting at an end stop
        self._cache_key = None
        self._cache_val = None
        self._surf_key = None
        self._surf_val = None
        self.kinds = self.surface_kinds()
        self.fired: dict[int, tuple[float, float]] = {}  # kink surface -> (time, side)
        self.fire_count: dict[int, int] = {}  # kink surface -> firings in this sub-interval
        # below this distance a kink surface counts as "on the surface" at a restart
        tiny = 10.0 * max(rtol, 1e-13)
        self.surface_noise = np.array(
            [0.0 if kind == "regime" else tiny * (m.r_h if j < 4 else m.p_a)
             for kind, j in self.kinds])
        self.n_events = 0
        self.small_first_step = 0.0

    # ---- delayed quantities -----------------------------------------------------------
    def delayed_pressures(self, t: float) -> tuple[float, float]:
        """``P1(t - tau), P2(t - tau)``; the initial state before ``t = 0``."""
        s = t - self.m.tau
        if s <= 0.0 or not self.hist_sol:
            return self.y0[IX_P1], self.y0[IX_P2]
        j = bisect.bisect_right(self.hist_t0, s) - 1
        j = min(max(j, 0), len(self.hist_sol) - 1)
        yy = self.hist_sol[j](s)
        return float(yy[IX_P1]), float(yy[IX_P2])

    # ---- right-hand side --------------------------------------------------------------
    def valve_pressures(self, t: float, y: np.ndarray) -> tuple[float, float]:
        """Chamber pressures the valve flows are evaluated with: current (command
        coupling) or delayed (literal coupling, Eq. 55 as printed)."""
        if self.literal:
            return self.delayed_pressures(t)
        return y[IX_P1], y[IX_P2]

    def valve_flows(self, t: float, y: np.ndarray) -> tuple[float, float, float, float]:
        """Signed valve flows into the chambers of the four paths (before the tube),
        evaluated with the delayed spool position ``x_s(t - tau)``."""
        m = self.m
        x_d = y[IX_XD]
        p1b, p2b = self.valve_pressures(t, y)
        a_in = orifice_area(m, x_d)
        a_ex = orifice_area(m, -x_d)
        return (orifice_mass_flow(m, a_in, m.p_s, p1b),
                orifice_mass_flow(m, a_ex, m.p_a, p1b),
                orifice_mass_flow(m, a_ex, m.p_s, p2b),
                orifice_mass_flow(m, a_in, m.p_a, p2b))

    def evaluate(self, t: float, y: np.ndarray):
        """``(dy/dt, valve flows, applied force F_p - F_L)``, cached for the last point."""
        key = (t, y.tobytes())
        if key == self._cache_key:
            return self._cache_val
        m = self.m
        p1, p2, x, v = y[IX_P1], y[IX_P2], y[IX_X], y[IX_V]
        q = self.valve_flows(t, y)
        # tube: attenuate each path's flow by phi at the chamber pressure
        p_ch = (p1, p1, p2, p2)
        mdot_in = [0.0, 0.0]
        mdot_out = [0.0, 0.0]
        for j in range(4):
            qj = q[j]
            if qj == 0.0:
                continue
            if self.use_tube:
                re = reynolds_number(m, qj)
                qj *= tube_attenuation(m, tube_resistance(m, re, self.turbulent[j]), p_ch[j])
            c = PATH_CHAMBER[j]
            if qj > 0.0:
                mdot_in[c] += qj
            else:
                mdot_out[c] -= qj
        if m.a_leak > 0.0:  # leakage between the chambers, no tube (Sec. 2.2)
            ql = orifice_mass_flow(m, m.a_leak, p2, p1)
            if ql > 0.0:
                mdot_in[0] += ql
                mdot_out[1] += ql
            else:
                mdot_out[0] -= ql
                mdot_in[1] -= ql
        # piston
        f_applied = pneumatic_force(m, p1, p2) - load_force(m, x)
        if self.piston == "slip":
            xdot, vdot = v, piston_acceleration(m, f_applied, v, self.slip_dir)
        else:
            xdot, vdot = 0.0, 0.0
        v1, v2 = chamber_volumes(m, x)
        dy = np.empty(N_Y)
        dy[IX_XS] = y[IX_VS]
        dy[IX_VS] = spool_acceleration(m, y[IX_XS], y[IX_VS], self.i_now)
        if self.delayed_active:
            dy[IX_XD] = y[IX_VD]
            dy[IX_VD] = spool_acceleration(m, y[IX_XD], y[IX_VD], self.i_delayed)
        else:
            dy[IX_XD] = 0.0
            dy[IX_VD] = 0.0
        dy[IX_P1] = chamber_pressure_rate(m, p1, v1, m.a1 * xdot, mdot_in[0], mdot_out[0])
        dy[IX_P2] = chamber_pressure_rate(m, p2, v2, -m.a2 * xdot, mdot_in[1], mdot_out[1])
        dy[IX_X] = xdot
        dy[IX_V] = vdot
        self._cache_key = key
        self._cache_val = (dy, q, f_applied)
        return self._cache_val

    def rhs(self, t, y):
        return self.evaluate(t, y)[0]

    def applied_force(self, y) -> float:
        m = self.m
        return pneumatic_force(m, y[IX_P1], y[IX_P2]) - load_force(m, y[IX_X])

    # ---- events -----------------------------------------------------------------------
    # Switching surfaces g(t, y) = 0 of the right-hand side. "regime" surfaces switch the
    # tube flow regime of a path (a jump of the right-hand side); "kink" surfaces only
    # restart the integration where the right-hand side loses smoothness, so that no
    # step of the high-order method straddles them.
    def surface_kinds(self) -> list[tuple[str, int]]:
        m = self.m
        kinds: list[tuple[str, int]] = []
        if self.use_tube:
            kinds += [("regime", j) for j in range(4)]
        kinds += [("kink", j) for j in range(4)]  # delayed spool at the hole edges
        n_pairs = 5 if m.a_leak > 0.0 else 4
        kinds += [("kink", 4 + j) for j in range(n_pairs)]  # flow reversal (alpha switch)
        kinds += [("kink", 9 + j) for j in range(n_pairs)]  # choking ratio P_cr
        if m.r_lin < 1.0:
            kinds += [("kink", 14 + j) for j in range(n_pairs)]  # linearisation ratio
        return kinds

    def surfaces(self, t: float, y: np.ndarray) -> np.ndarray:
        key = (t, y.tobytes())
        if key == self._surf_key:
            return self._surf_val
        m = self.m
        x_d = y[IX_XD]
        p1b, p2b = self.valve_pressures(t, y)
        pairs = [(m.p_s, p1b), (m.p_a, p1b), (m.p_s, p2b), (m.p_a, p2b)]
        if m.a_leak > 0.0:
            pairs.append((y[IX_P2], y[IX_P1]))
        vals = []
        if self.use_tube:
            q = self.valve_flows(t, y)
            vals += [reynolds_number(m, qj) - m.re_t for qj in q]
        e0, e1 = m.p_w - m.r_h, m.p_w + m.r_h
        vals += [x_d - e0, -x_d - e0, x_d - e1, -x_d - e1]
        vals += [b - a for a, b in pairs]
        vals += [max(a, b) * m.p_cr - min(a, b) for a, b in pairs]
        if m.r_lin < 1.0:
            vals += [max(a, b) * m.r_lin - min(a, b) for a, b in pairs]
        self._surf_key = key
        self._surf_val = np.asarray(vals)
        return self._surf_val

    def make_events(self, t0: float) -> _EventSet:
        """The events to watch from ``t0`` on, in the present discrete state."""
        m = self.m
        idx, directions, actions = [], [], []
        g0 = self.surfaces(t0, self.y)
        for e, (kind, j) in enumerate(self.kinds):
            if kind == "regime":
                direction = -1.0 if self.turbulent[j] else 1.0
            elif self.fire_count.get(e, 0) >= 3:
                # the solution hovers on a kink (e.g. a chamber pressure converging to
                # the supply pressure): stop restarting there until the next sub-interval
                continue
            elif e in self.fired and t0 - self.fired[e][0] <= 1e-12 * max(1.0, t0):
                direction = -self.fired[e][1]  # just crossed: watch the way back
            elif abs(g0[e]) <= self.surface_noise[e]:
                continue  # on the surface (e.g. a chamber at exactly ambient)
            elif g0[e] > 0.0:
                direction = -1.0
            else:
                direction = 1.0
            idx.append(e)
            directions.append(direction)
            actions.append((kind, j, e, direction))
        if self.piston == "slip":
            s = self.slip_dir
            directions += [-s, s]  # velocity back through zero; end stop reached
            actions += [("velocity_zero",), ("end_stop", s)]
        elif self.piston == "rest":
            for d in (1.0, -1.0):
                if d != self.stop_side:  # pushing into a stop does not move the piston
                    directions.append(1.0)
                    actions.append(("break_away", d))
        return _EventSet(self, np.array(idx, dtype=int), np.array(directions), actions)

    def piston_event_values(self, y: np.ndarray, actions) -> list[float]:
        """Event functions of the piston mode (see :meth:`make_events`)."""
        if self.piston == "slip":
            return [y[IX_V], y[IX_X] - self.slip_dir * 0.5 * self.m.stroke]
        if self.piston == "rest":
            f = self.applied_force(y)
            return [a[1] * f - self.m.f_stick for a in actions]
        return []

    def settle_at_rest(self) -> None:
        """The piston is at rest: stick, or break away at once if the applied force
        already exceeds the stick threshold in an allowed direction."""
        m = self.m
        self.y[IX_V] = 0.0
        self.piston = "rest"
        self.slip_dir = 0.0
        f = self.applied_force(self.y)
        for d in (1.0, -1.0):
            if d != self.stop_side and d * f > m.f_stick:
                self.piston = "slip"
                self.slip_dir = d
                self.stop_side = 0.0
                return

    def apply(self, action, t: float) -> None:
        kind = action[0]
        if kind == "regime":
            j = action[1]
            self.turbulent[j] = not self.turbulent[j]
        elif kind == "kink":
            e = action[2]
            self.fired[e] = (t, action[3])
            self.fire_count[e] = self.fire_count.get(e, 0) + 1
            if action[1] < 4:
                # a hole edge: the area grows like x_e^(3/2) from here, a singularity
                # that embedded error estimates miss; start with a tiny step
                self.small_first_step = FIRST_STEP_AFTER_EDGE
        elif kind == "velocity_zero":
            self.stop_side = 0.0
            self.settle_at_rest()
        elif kind == "end_stop":
            s = action[1]
            self.y[IX_X] = s * 0.5 * self.m.stroke
            self.stop_side = s
            self.settle_at_rest()
        elif kind == "break_away":
            self.piston = "slip"
            self.slip_dir = action[1]
            self.stop_side = 0.0
            self.y[IX_V] = 0.0
        else:  # pragma: no cover
            raise AssertionError(kind)
        self._cache_key = None
        self._surf_key = None

    def init_discrete_state(self) -> None:
        m = self.m
        y = self.y
        half = 0.5 * m.stroke
        if self.use_tube:
            q = self.valve_flows(0.0, y)
            self.turbulent = [reynolds_number(m, qj) >= m.re_t for qj in q]
        if m.piston_mode == PISTON_FIXED:
            self.piston = "fixed"
            return
        v = y[IX_V]
        if abs(y[IX_X]) >= half:
            self.stop_side = math.copysign(1.0, y[IX_X])
            y[IX_X] = self.stop_side * half
            if v * self.stop_side >= 0.0:
                self.settle_at_rest()
                return
        if v != 0.0:
            self.piston = "slip"
            self.slip_dir = math.copysign(1.0, v)
            self.stop_side = 0.0
        else:
            self.settle_at_rest()

    # ---- driver -----------------------------------------------------------------------
    def breakpoints(self) -> np.ndarray:
        n = len(self.currents)
        grid = np.arange(n + 1) * self.dt
        pts = list(grid)
        tau = self.m.tau
        if self.use_tube:
            pts += [t + tau for t in grid[:-1] if t + tau < self.t_end]
        pts = np.unique(np.asarray(pts))
        # merge points closer than a tiny tolerance, keeping control-grid points
        tol = 1e-12 * max(1.0, self.t_end)
        keep = [pts[0]]
        for p in pts[1:]:
            if p - keep[-1] > tol:
                keep.append(p)
            elif np.min(np.abs(grid - p)) < np.min(np.abs(grid - keep[-1])):
                keep[-1] = p
        pts = np.asarray(keep)
        if self.literal:  # method of steps: sub-intervals no longer than tau
            sub = [pts[0]]
            for a, b in zip(pts[:-1], pts[1:]):
                k = int(math.ceil((b - a) / tau - 1e-9))
                sub += list(np.linspace(a, b, k + 1)[1:])
            pts = np.asarray(sub)
        return pts

    def integrate(self, t0: float, t1: float, y0: np.ndarray, events: _EventSet | None,
                  first_step: float | None = None) -> _Piece:
        """Integrate ``[t0, t1]`` in the present discrete state, stopping at the first
        event.

        The event functions are checked at ``EVENT_SAMPLES`` points of every step's
        dense output, not only at the step ends as ``solve_ivp`` does, so that a surface
        crossed twice within one step (a brief excursion of the Reynolds number above
        ``Re_t``, a velocity reversal) is not missed. The root is then found with
        ``brentq`` on the dense output.
        """
        solver = _METHODS[self.method](self.rhs, t0, y0, t1, rtol=self.rtol, atol=self.atol,
                                       first_step=first_step)
        if events is not None and len(events) == 0:
            events = None
        if events is not None:
            directions = events.directions
            g_old = events.values(t0, y0)
        dense_steps: list[tuple[float, float, object]] = []
        while True:
            t_old, y_old = solver.t, solver.y.copy()
            solver.step()
            if solver.status == "failed":
                raise RuntimeError(f"integration failed at t = {t_old}: "
                                   f"step size {solver.step_size}")
            t_new = solver.t
            dense = solver.dense_output() if (events is not None or self.literal) else None
            if events is not None:
                s = t_old + (t_new - t_old) * np.arange(1, EVENT_SAMPLES + 1) / EVENT_SAMPLES
                s[-1] = t_new
                ys = dense(s)
                s_prev, g_prev = t_old, g_old
                for i in range(EVENT_SAMPLES):
                    y_i = ys[:, i] if i < EVENT_SAMPLES - 1 else solver.y
                    g = events.values(s[i], y_i)
                    active = _active_events(g_prev, g, directions)
                    if active.size:
                        roots = [_event_root(events, e, dense, s_prev, s[i]) for e in active]
                        j = int(np.argmin(roots))
                        t_ev = roots[j]
                        y_ev = y_old if t_ev <= t_old else dense(t_ev)
                        return _Piece(t_ev, y_ev, int(active[j]), t_old, y_old, dense_steps)
                    s_prev, g_prev = s[i], g
                g_old = g_prev
            if self.literal:
                dense_steps.append((t_old, t_new, dense))
            if solver.status == "finished":
                return _Piece(t_new, solver.y.copy(), None, t_old, y_old, dense_steps)

    def add_history(self, dense_steps) -> None:
        """Keep the dense outputs of the computed past (literal coupling)."""
        for t0, t1, dense in dense_steps:
            if t1 > t0:
                self.hist_t0.append(t0)
                self.hist_sol.append(dense)

    def current_at(self, t: float) -> float:
        k = int(math.floor(t / self.dt))
        return float(self.currents[min(max(k, 0), len(self.currents) - 1)])

    def run(self) -> dict:
        m = self.m
        n = len(self.currents)
        out = {key: np.empty(n + 1) for key in ("p1", "p2", "x", "v", "f", "x_s")}
        out["t"] = np.arange(n + 1) * self.dt
        self.init_discrete_state()

        def record(k):
            y = self.y
            out["p1"][k] = y[IX_P1]
            out["p2"][k] = y[IX_P2]
            out["x"][k] = y[IX_X]
            out["v"][k] = y[IX_V]
            out["f"][k] = output_force(m, y[IX_P1], y[IX_P2], y[IX_X])
            out["x_s"][k] = y[IX_XS]

        record(0)
        pts = self.breakpoints()
        k_out = 1
        for a, b in zip(pts[:-1], pts[1:]):
            mid = 0.5 * (a + b)
            self.i_now = self.current_at(mid)
            if self.use_tube:
                active = mid > m.tau
                if active and not self.delayed_active:
                    # the delayed spool's history ends at t = tau: from there on it
                    # repeats the spool's trajectory from the initial spool state
                    self.y[IX_XD] = self.y0[IX_XS]
                    self.y[IX_VD] = self.y0[IX_VS]
                self.delayed_active = active
                self.i_delayed = self.current_at(mid - m.tau) if active else 0.0
            else:
                self.delayed_active = True
                self.i_delayed = self.i_now
            self._cache_key = None
            self._surf_key = None
            self.fire_count.clear()
            t = a
            stalls = 0
            while b - t > 1e-14 * max(1.0, b):
                events = self.make_events(t)
                first_step = None
                if self.small_first_step:
                    first_step = min(self.small_first_step, 0.5 * (b - t))
                    self.small_first_step = 0.0
                res = self.integrate(t, b, self.y, events, first_step)
                t_new = res.t_end
                if res.event is not None and t_new > res.t_step:
                    # The step that found the event straddled the switching surface, so
                    # its interpolant at the root is polluted by right-hand-side values
                    # from beyond the surface: redo that step up to the root.
                    self.add_history(res.dense_steps)
                    redo = self.integrate(res.t_step, t_new, res.y_step, None)
                    self.add_history(redo.dense_steps)
                    self.y = redo.y_end.copy()
                else:
                    self.add_history(res.dense_steps)
                    self.y = res.y_end.copy()
                self._cache_key = None
                self._surf_key = None
                if res.event is not None:
                    self.apply(events.actions[res.event], t_new)
                    self.n_events += 1
                    stalls = stalls + 1 if t_new - t <= 1e-13 * max(1.0, t_new) else 0
                    if stalls > 50:
                        raise RuntimeError(f"event chattering at t = {t_new}")
                t = t_new
            while k_out <= n and abs(out["t"][k_out] - b) <= 1e-9 * self.dt:
                record(k_out)
                k_out += 1
        if k_out != n + 1:  # pragma: no cover
            raise AssertionError("missed an output time")
        return out


def _default_atol(m: ModelConstants, rtol: float) -> np.ndarray:
    """Absolute tolerances scaled to each state's natural size."""
    omega_s = math.sqrt(2.0 * m.k_s / m.m_s)
    scale = np.empty(N_Y)
    scale[[IX_XS, IX_XD]] = m.r_h
    scale[[IX_VS, IX_VD]] = m.r_h * omega_s
    scale[[IX_P1, IX_P2]] = m.p_a
    scale[IX_X] = m.stroke
    scale[IX_V] = 0.1
    return rtol * scale


def simulate_reference(params: dict, coil_current_a: np.ndarray, control_dt_s: float,
                       initial: dict | None = None, rtol: float = 1e-9, atol=None,
                       method: str = "DOP853") -> dict:
    """Integrate the model of ``docs/model.md`` to high accuracy.

    Parameters
    ----------
    params
        Parameter set, a dict ``name -> float`` with the names of
        ``pneumatic_env.physics.layout.PARAMETER_NAMES`` (extra names are ignored).
    coil_current_a
        Coil current (A) of each control period, held constant (zero-order hold) over
        ``[k dt, (k+1) dt)``.
    control_dt_s
        Control period ``dt`` (s).
    initial
        Initial state, keys among ``p1``, ``p2`` (Pa abs), ``x`` (m), ``v`` (m/s),
        ``x_s`` (m), ``v_s`` (m/s). Defaults: both chambers at ambient pressure, piston at
        rest at ``fixed_position_m`` (fixed mode) or ``x = 0``, spool centred at rest. The
        delay history before ``t = 0`` equals the initial state.
    rtol, atol
        Tolerances of ``solve_ivp``; ``atol`` defaults to ``rtol`` times a natural scale
        of each state (hole radius, ambient pressure, stroke, ...).
    method
        ``solve_ivp`` method (explicit "DOP853" by default; "Radau" and "LSODA" work too).

    Returns
    -------
    dict of arrays of length ``n + 1`` sampled at ``t_k = k dt``: ``t``, ``p1``, ``p2``,
    ``x``, ``v``, ``f`` (force output: ``F_p`` for fixed and free rods,
    ``k_env (x - x_rest)`` for the spring mode), ``x_s``.
    """
    m = ModelConstants.from_params(params)
    currents = np.asarray(coil_current_a, dtype=float).ravel()
    if currents.size == 0:
        raise ValueError("coil_current_a is empty")
    if not np.all(np.isfinite(currents)):
        raise ValueError("coil_current_a contains non-finite values")
    if not control_dt_s > 0.0:
        raise ValueError("control_dt_s must be positive")
    init = {"p1": m.p_a, "p2": m.p_a, "x": m.x_fixed if m.piston_mode == PISTON_FIXED else 0.0,
            "v": 0.0, "x_s": 0.0, "v_s": 0.0}
    if initial:
        unknown = set(initial) - set(init)
        if unknown:
            raise KeyError(f"unknown initial-state keys {sorted(unknown)}")
        init.update({key: float(val) for key, val in initial.items()})
    if m.piston_mode == PISTON_FIXED and (init["x"] != m.x_fixed or init["v"] != 0.0):
        raise ValueError("fixed rod: initial x must be fixed_position_m and v must be 0")
    if abs(init["x"]) > 0.5 * m.stroke:
        raise ValueError("initial piston position beyond the end stops")
    if init["p1"] <= 0.0 or init["p2"] <= 0.0:
        raise ValueError("initial pressures must be positive (absolute)")
    y0 = np.zeros(N_Y)
    y0[IX_XS] = y0[IX_XD] = init["x_s"]
    y0[IX_VS] = init["v_s"]
    y0[IX_VD] = 0.0  # delayed spool frozen at the initial position until t = tau
    y0[IX_P1], y0[IX_P2] = init["p1"], init["p2"]
    y0[IX_X], y0[IX_V] = init["x"], init["v"]
    if m.tau == 0.0:
        y0[IX_VD] = init["v_s"]
    if atol is None:
        atol = _default_atol(m, rtol)
    sim = _HybridSimulation(m, currents, float(control_dt_s), y0, rtol, atol, method)
    return sim.run()


# --------------------------------------------------------------------------------------
# A segmented tube line: the independent reference of the transmission line (tube_waves)
# --------------------------------------------------------------------------------------

def simulate_segmented_line(params: dict, coil_current_a: float, duration_s: float,
                            n_segments: int = 40, sample_dt_s: float = 1e-3,
                            rtol: float = 1e-8) -> dict:
    """A clamped rod driven by a constant current through two tubes of ``n_segments``
    finite volumes each: the reference for the kernel's transmission line
    (``tube_waves = 1``, docs/effects.md), written without it.

    Each segment of length dx = L_t / n is a node of volume A_t dx, its pressure changing
    isentropically with the mass it gains, dP_k/dt = k R T (m_{k-1} - m_k) / (A_t dx), and
    a link to the next node (the last one to the chamber) whose mass flow obeys the
    momentum balance of its air, dm_k/dt = A_t (P_k - P_{k+1}) / dx - R_t m_k / rho, with
    the tube friction R_t of Eqs. 33, 35 and rho the mean density of its two nodes. The
    valve feeds the first node (Eq. 39, four paths, spool of Eq. 38, no delay); the
    chambers follow Eq. 14 at the clamp. As n grows the line tends to the wave equation
    with friction, whose waves travel at c = sqrt(k R T) (Eq. 31).

    The segments replace the tube, so ``tube_coupling`` and ``tube_waves`` do not apply;
    any other effect beyond the paper is refused. Returns ``t``, ``p1``, ``p2`` and ``valve_p1``, ``valve_p2`` (the first nodes) at
    ``sample_dt_s``, and the line's air mass at the end (``line_mass_kg``) with the mass
    the valve let in (``valve_mass_kg``) and the chambers received (``chamber_mass_kg``),
    for a conservation check.
    """
    from scipy.integrate import solve_ivp

    switched_on = [n for n, neutral in NEUTRAL_EFFECTS.items()
                   if n != "tube_waves" and n in params and float(params[n]) != neutral]
    if switched_on:
        raise NotImplementedError(
            f"simulate_segmented_line models the paper's valve and chambers with a segmented "
            f"tube only; effects switched on: {switched_on}")
    # the segments are the tube: the paper's tube coupling and the line switch do not apply
    m = ModelConstants.from_params({**params, "tube_waves": 0.0, "tube_coupling": 0.0})
    if m.piston_mode != PISTON_FIXED:
        raise ValueError("simulate_segmented_line models a clamped rod (piston_mode = 0) only")
    n = int(n_segments)
    if n < 2:
        raise ValueError(f"n_segments = {n_segments} is not allowed: must be an integer >= 2")
    area_t = math.pi * m.tube_d ** 2 / 4.0
    dx = m.tube_length / n
    rt = m.R * m.T
    v1, v2 = chamber_volumes(m, m.x_fixed)
    # state: x_s, v_s, mass let in by the valve, mass into the chambers, then per tube: n
    # node pressures, n link flows, the chamber pressure
    tube = 2 * n + 1

    def resistance(mdot):
        re = reynolds_number(m, mdot)
        return tube_resistance(m, re, re >= m.re_t)

    def rhs(_t, y):
        x_s, v_s = y[0], y[1]
        out = np.zeros_like(y)
        out[0] = v_s
        out[1] = spool_acceleration(m, x_s, v_s, coil_current_a)
        a_in, a_ex = orifice_area(m, x_s), orifice_area(m, -x_s)
        for side, (supply_area, exhaust_area, volume) in enumerate(
                ((a_in, a_ex, v1), (a_ex, a_in, v2))):
            first = 4 + side * tube
            nodes = y[first:first + n]
            links = y[first + n:first + 2 * n]
            chamber = y[first + 2 * n]
            valve = (orifice_mass_flow(m, supply_area, m.p_s, nodes[0])
                     - orifice_mass_flow(m, exhaust_area, nodes[0], m.p_a))
            out[2] += valve
            inflow = np.concatenate([[valve], links[:-1]])
            out[first:first + n] = m.k * rt * (inflow - links) / (area_t * dx)
            downstream = np.append(nodes[1:], chamber)
            rho = 0.5 * (nodes + downstream) / rt
            friction = np.array([resistance(q) for q in links])
            out[first + n:first + 2 * n] = (area_t * (nodes - downstream) / dx
                                            - friction * links / rho)
            out[3] += links[-1]
            out[first + 2 * n] = chamber_pressure_rate(m, chamber, volume, 0.0,
                                                       max(links[-1], 0.0), max(-links[-1], 0.0))
        return out

    y0 = np.zeros(4 + 2 * tube)
    for side in range(2):
        first = 4 + side * tube
        y0[first:first + n] = m.p_a
        y0[first + 2 * n] = m.p_a
    t = np.arange(int(round(duration_s / sample_dt_s)) + 1) * sample_dt_s
    scale = np.concatenate([[m.r_h, m.r_h * 1e3, 1e-6, 1e-6],
                            np.tile(np.concatenate([np.full(n, m.p_a), np.full(n, 1e-3),
                                                    [m.p_a]]), 2)])
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, method="LSODA", t_eval=t, rtol=rtol,
                    atol=rtol * scale)
    if not sol.success:
        raise RuntimeError(f"segmented line: solve_ivp failed: {sol.message}")
    end = sol.y[:, -1]
    # the line's air gained since t = 0 (isentropic: dm = V dP / (k R T))
    line_mass = sum((end[4 + s * tube:4 + s * tube + n] - m.p_a).sum() * area_t * dx
                    / (m.k * rt) for s in range(2))
    return {"t": t, "p1": sol.y[4 + 2 * n], "p2": sol.y[4 + tube + 2 * n],
            "valve_p1": sol.y[4], "valve_p2": sol.y[4 + tube],
            "line_mass_kg": line_mass, "chamber_mass_kg": end[3], "valve_mass_kg": end[2]}
