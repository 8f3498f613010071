"""Model-based sliding-mode force controller for the clamped rod (derivation: docs/sliding-mode.md).

Per control period and env:

1. Prediction (optional, Smith-predictor-like): the commands of the last d periods have not
   reached the load cell yet (tube delay tau = L/c, Eq. 31, plus the spool lag c_s/(2 k_s),
   Eq. 38), so f^(k+d) = f(k) + dt * sum of their model force rates.
2. Sliding surface on the force error, compared with the reference l = d + extra lead steps
   ahead (preview): e = f^(k+d) - r(k+l),  s = e + lambda_I * integral(e).
3. Reaching law with a boundary layer: the force rate wanted is
   Fdot_d = rdot(k+l) - lambda_I e - k_r s - eta sat(s / Phi).
4. Equivalent control by inverting the model: Fdot = A1 P1dot - A2 P2dot with the chamber
   equations (Eq. 14/16, dV = 0) and the valve flows (Eqs. 39, 44, tube attenuation Eq. 30)
   evaluated at the measured pressures; the spool opening giving Fdot_d is found on a grid of
   openings (monotone search with interpolation), then x_s (Eq. 43) and the current (Eq. 46).

With ``reference_smoothing_steps`` W > 0 the reference r is first the centred mean over
2 W + 1 periods (``base.Controller.smoothed_reference``): a step becomes a ramp centred
on it (``agents/rig_training.py`` searches W on a fitted rig; the benchmark's gains use 0).

The controller's model is the paper's nominal model built from the simulator's sub-model
functions (orifice area, orifice flow, tube attenuation, chamber pressure rate); effects the
simulator may add beyond the paper (configs/effects.yaml) are model error to it. It reads only
the observation [p1, p2, x, f, ref, preview] and the parameters.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numba import njit, prange

from pneumatic_env.params import parameter_array
from pneumatic_env.physics.chamber import chamber_volumes, pressure_rate
from pneumatic_env.physics.constants import Constants, env_constants
from pneumatic_env.physics.derived import tube_delay_s
from pneumatic_env.physics.flow import orifice_mass_flow
from pneumatic_env.physics.layout import EFFECT_NEUTRAL_VALUES
from pneumatic_env.physics.tube import tube_attenuation
from pneumatic_env.physics.valve import orifice_area
from pneumatic_env.simulator import PARALLEL_MIN_ENVS

from .base import OBS_F, OBS_P1, OBS_P2, OBS_X, Controller, ControllerContext, check_gain

__all__ = [
    "SlidingModeController",
    "force_rate",
    "invert_force_rate",
    "model_constants",
    "model_delay_s",
    "PARALLEL_MIN_ROWS",
]

#: From this many rows the model inversion runs on Numba's threads (row by row the same
#: numbers; the benchmark's 9 rows stay serial), as the env's step from
#: ``simulator.PARALLEL_MIN_ENVS``: below it a thread team costs more than it saves, and
#: switching teams with torch's between small steps slowed a 64-env training 30-fold.
PARALLEL_MIN_ROWS = PARALLEL_MIN_ENVS


def model_constants(params: Mapping[str, float]) -> Constants:
    """The controller's nominal model: the kernel's ``Constants`` (``env_constants``) of
    ``params`` with every effect beyond the paper's model off (``EFFECT_NEUTRAL_VALUES``).
    The jitted functions below read its paper fields (Eqs. 14, 30, 39, 44) and take it as
    a plain tuple (``tuple(model)``), which Numba's dispatcher types faster."""
    paper = parameter_array({**params, **EFFECT_NEUTRAL_VALUES})
    return env_constants(paper, 0, 1.0)  # the substep sets no field the model reads


@njit(cache=True)
def _path_flow(m, area, p_from, p_to, p_chamber):
    """Valve path flow (Eq. 39, signed from -> to) attenuated by its tube (Eq. 30)."""
    q = orifice_mass_flow(
        area,
        m.discharge,
        p_from,
        p_to,
        m.inv_sqrt_t,
        m.k,
        m.c1,
        m.c2,
        m.critical_ratio,
        m.linear_ratio,
        m.linear_slope,
    )
    return q * tube_attenuation(
        q, p_chamber, m.gas_rt, m.delay_s, m.tube_diameter, m.viscosity, m.reynolds_turbulent
    )


@njit(cache=True)
def force_rate(m, p1, p2, x, spool_m):
    """dF/dt (N/s) of the clamped rod at pressures p1, p2 with the spool held at ``spool_m``.

    F = P1 A1 - P2 A2 - Pa Ar (Eq. 1) with V fixed: Fdot = A1 P1dot - A2 P2dot, the pressure
    rates from Eq. 14/16 and the valve flows of Eqs. 39, 44 through the tubes (Eq. 30).
    Chamber 1 is fed through A(x_s) and exhausted through A(-x_s); chamber 2 the other way.
    """
    area_a = orifice_area(spool_m, m.hole_radius, m.half_width, m.holes)
    area_b = orifice_area(-spool_m, m.hole_radius, m.half_width, m.holes)
    s1 = _path_flow(m, area_a, m.supply_pa, p1, p1)  # supply -> 1
    e1 = _path_flow(m, area_b, p1, m.ambient_pa, p1)  # 1 -> exhaust
    s2 = _path_flow(m, area_b, m.supply_pa, p2, p2)  # supply -> 2
    e2 = _path_flow(m, area_a, p2, m.ambient_pa, p2)  # 2 -> exhaust
    v1, v2 = chamber_volumes(x, m.half_stroke, m.area_cap, m.area_rod, m.dead_cap, m.dead_rod)
    dp1 = pressure_rate(
        p1,
        v1,
        0.0,
        max(s1, 0.0) + max(-e1, 0.0),
        max(-s1, 0.0) + max(e1, 0.0),
        m.gas_rt,
        m.alpha_in,
        m.alpha_out,
        0.0,
    )
    dp2 = pressure_rate(
        p2,
        v2,
        0.0,
        max(s2, 0.0) + max(-e2, 0.0),
        max(-s2, 0.0) + max(e2, 0.0),
        m.gas_rt,
        m.alpha_in,
        m.alpha_out,
        0.0,
    )
    return m.area_cap * dp1 - m.area_rod * dp2


@njit(cache=True)
def _invert_one(m, p1, p2, x, fdot_des, openings, blend, refine_iterations):
    overlap = m.half_width - m.hole_radius
    target = max(abs(fdot_des), blend)
    sign = 1.0 if fdot_des >= 0.0 else -1.0
    prev_open, prev_rate = 0.0, 0.0
    best_open, best_rate = 0.0, 0.0
    found = False
    opening = 0.0
    for j in range(1, openings.size):
        op = openings[j]
        rate = sign * force_rate(m, p1, p2, x, sign * (overlap + op))
        if rate >= target:  # bracketed: refine by regula falsi on the model itself
            lo, r_lo, hi, r_hi = prev_open, prev_rate, op, rate
            for _ in range(refine_iterations):
                w = (target - r_lo) / (r_hi - r_lo) if r_hi > r_lo else 1.0
                mid = lo + w * (hi - lo)
                r_mid = sign * force_rate(m, p1, p2, x, sign * (overlap + mid))
                if r_mid < target:
                    lo, r_lo = mid, r_mid
                else:
                    hi, r_hi = mid, r_mid
            w = (target - r_lo) / (r_hi - r_lo) if r_hi > r_lo else 1.0
            opening = lo + w * (hi - lo)
            found = True
            break
        if rate > best_rate:
            best_open, best_rate = op, rate
        prev_open, prev_rate = op, rate
    if not found:  # the valve cannot deliver the rate: open where the model gives the most
        opening = best_open
    spool = sign * (overlap + opening)
    if abs(fdot_des) < blend:  # through the dead band linearly: no current jump at Fdot_d = 0
        spool *= abs(fdot_des) / blend
    return spool, force_rate(m, p1, p2, x, spool)


@njit(cache=True)
def invert_force_rate(
    m, p1, p2, x, fdot_des, openings, blend, spool_out, rate_out, refine_iterations=4
):
    """Spool positions (m) giving the force rates ``fdot_des`` (N/s), and the model's rate there.

    ``openings``: grid of effective openings x_e in [0, 2 R_h] (Eq. 43) searched for the first
    one reaching the rate, then refined by ``refine_iterations`` regula-falsi steps; where no
    opening reaches it, the one with the largest rate. ``blend`` (N/s): below it the spool
    moves linearly through the overlap instead of jumping across it.
    """
    m = Constants(*m)
    for i in range(p1.size):
        spool_out[i], rate_out[i] = _invert_one(
            m, p1[i], p2[i], x[i], fdot_des[i], openings, blend, refine_iterations
        )


@njit(cache=True, parallel=True)
def invert_force_rate_parallel(
    m, p1, p2, x, fdot_des, openings, blend, spool_out, rate_out, refine_iterations=4
):
    """:func:`invert_force_rate` with the rows spread over Numba's threads."""
    m = Constants(*m)
    for i in prange(p1.size):
        spool_out[i], rate_out[i] = _invert_one(
            m, p1[i], p2[i], x[i], fdot_des[i], openings, blend, refine_iterations
        )


@njit(cache=True)
def _force_rates(m, p1, p2, x, spool, out):
    m = Constants(*m)
    for i in range(p1.size):
        out[i] = force_rate(m, p1[i], p2[i], x[i], spool[i])


@njit(cache=True, parallel=True)
def _force_rates_parallel(m, p1, p2, x, spool, out):
    m = Constants(*m)
    for i in prange(p1.size):
        out[i] = force_rate(m, p1[i], p2[i], x[i], spool[i])


def model_delay_s(params: dict) -> tuple[float, float]:
    """(tube delay L/c of Eq. 31, spool time constant c_s/(2 k_s) of Eq. 38) in s."""
    return (
        tube_delay_s(
            params["tube_length_m"],
            params["heat_capacity_ratio"],
            params["gas_constant_j_per_kg_k"],
            params["temperature_k"],
        ),
        params["spool_damping_n_s_per_m"] / (2.0 * params["spool_spring_n_per_m"]),
    )


class SlidingModeController(Controller):
    """Sliding-mode force control with model inversion, boundary layer and delay compensation."""

    name = "sliding_mode"

    def __init__(
        self,
        context: ControllerContext,
        *,
        lambda_integral_per_s,
        reaching_gain_per_s,
        switching_gain_n_per_s,
        boundary_layer_n,
        deadband_blend_n_per_s,
        extra_lead_s,
        predictor,
        opening_grid_points,
        reference_smoothing_steps=0,
    ):
        super().__init__(context)
        own = "SlidingModeController"
        self.set_reference_smoothing(own, reference_smoothing_steps)
        self.lam = check_gain(own, "lambda_integral_per_s", lambda_integral_per_s)
        self.k_r = check_gain(own, "reaching_gain_per_s", reaching_gain_per_s)
        self.eta = check_gain(own, "switching_gain_n_per_s", switching_gain_n_per_s)
        self.phi = check_gain(own, "boundary_layer_n", boundary_layer_n, ge=None, gt=0.0)
        self.blend = float(
            check_gain(own, "deadband_blend_n_per_s", deadband_blend_n_per_s, ge=None, gt=0.0)
        )
        extra = check_gain(own, "extra_lead_s", extra_lead_s)
        pred = np.asarray(predictor)
        if pred.dtype != bool:
            raise ValueError(
                f"{own}: predictor = {predictor!r} is not allowed: true or false "
                "(or an array of them, one per env)"
            )
        if int(opening_grid_points) != opening_grid_points or opening_grid_points < 3:
            raise ValueError(
                f"{own}: opening_grid_points = {opening_grid_points!r} is not "
                "allowed: an integer >= 3"
            )
        p = context.base_params
        if p["spool_half_width_m"] < p["hole_radius_m"]:
            raise ValueError(
                f"{own}: spool_half_width_m = {p['spool_half_width_m']} < "
                f"hole_radius_m = {p['hole_radius_m']}: the inversion assumes an "
                "overlapped (closed-centre) valve"
            )
        tube_s, spool_s = model_delay_s(p)
        self.delay_s = tube_s + spool_s
        self.d = int(np.rint(self.delay_s / context.dt_s))  # prediction horizon (steps)
        self.lead = self.d + np.rint(np.asarray(extra) / context.dt_s).astype(np.int64)
        if np.any(self.lead + 1 > context.preview_steps):
            raise ValueError(
                f"{own}: the delay {self.delay_s * 1e3:.1f} ms + extra_lead_s = "
                f"{extra_lead_s!r} needs {int(np.max(self.lead)) + 1} preview steps, "
                f"the env gives {context.preview_steps}: raise preview_steps"
            )
        self.predictor = pred
        self.openings = np.linspace(0.0, 2.0 * p["hole_radius_m"], int(opening_grid_points))
        self.model = model_constants(p)
        self._model_tuple = tuple(self.model)  # as the jitted functions take it
        self.i_per_m = 2.0 * p["spool_spring_n_per_m"] / p["coil_force_n_per_a"]  # Eq. 46

    def _allocate(self, n):
        self.integral = np.zeros(n)
        self.pending = np.zeros((n, max(self.d, 1)))  # model force rates of commands in flight
        self.head = 0

    def _reset_rows(self, rows):
        self.integral[rows] = 0.0
        self.pending[rows] = 0.0

    def _compute(self, obs, integral, pending_sum):
        """(current, model rate, new integral, predicted error) of SI rows ``obs`` from the
        given state; no state change."""
        dt, n = self.context.dt_s, obs.shape[0]
        f = obs[:, OBS_F]
        if self.d > 0:
            f = np.where(self.predictor, f + dt * pending_sum, f)
        r = self.reference_ahead(obs, self.lead)
        rdot = (self.reference_ahead(obs, self.lead + 1) - r) / dt
        e = f - r
        s = e + self.lam * integral
        inside = np.abs(s) < self.phi  # integrate only inside the boundary layer (anti-windup)
        integral = np.where(inside, integral + e * dt, integral)
        s = e + self.lam * integral
        fdot = rdot - self.lam * e - self.k_r * s - self.eta * np.clip(s / self.phi, -1.0, 1.0)
        spool, rate = np.empty(n), np.empty(n)
        invert = invert_force_rate_parallel if n >= PARALLEL_MIN_ROWS else invert_force_rate
        invert(
            self._model_tuple,
            np.ascontiguousarray(obs[:, OBS_P1]),
            np.ascontiguousarray(obs[:, OBS_P2]),
            np.ascontiguousarray(obs[:, OBS_X]),
            np.ascontiguousarray(fdot),
            self.openings,
            self.blend,
            spool,
            rate,
        )
        i_max = self.context.i_max_a
        current = np.clip(spool * self.i_per_m, -i_max, i_max)
        return current, rate, integral, e

    def _act(self, obs):
        current, rate, self.integral, self.last_error = self._compute(
            obs, self.integral, self.pending.sum(axis=1)
        )
        if self.d > 0:
            self.pending[:, self.head] = rate
            self.head = (self.head + 1) % self.d
        return current

    # -- hooks for a residual policy on top (agents/residual.py) -------------------------
    def _rows(self, obs) -> np.ndarray:
        return np.asarray(obs, dtype=np.float64).reshape(-1, self.context.obs_dim)

    def applied(self, obs, current, rows=None) -> None:
        """Tell the predictor the current actually applied after the last ``act(obs)``
        (e.g. the controller's plus a learned correction) in ``rows`` (default all): the
        model rate of the command in flight is recomputed for it. Without this the
        prediction believes the controller's own command is in flight, and a correction can
        hold a force offset the integral never sees. ``obs``: the observation ``act`` got
        (any normalisation); ``current``: one per row of ``obs``."""
        if self.d == 0:
            return
        rows = np.arange(self.pending.shape[0]) if rows is None else np.asarray(rows)
        if rows.size == 0:
            return
        o = self.observation_si(self._rows(obs))[rows]
        spool = (
            np.clip(
                np.asarray(current, dtype=np.float64).reshape(-1)[rows],
                -self.context.i_max_a,
                self.context.i_max_a,
            )
            / self.i_per_m
        )
        rate = np.empty(o.shape[0])
        rates = _force_rates_parallel if o.shape[0] >= PARALLEL_MIN_ROWS else _force_rates
        rates(
            self._model_tuple,
            np.ascontiguousarray(o[:, OBS_P1]),
            np.ascontiguousarray(o[:, OBS_P2]),
            np.ascontiguousarray(o[:, OBS_X]),
            np.ascontiguousarray(spool),
            rate,
        )
        self.pending[rows, (self.head - 1) % self.d] = rate

    def peek(self, obs, rows):
        """(current, predicted error in N) that ``act`` would give rows ``rows`` for their
        observations ``obs`` (len(rows) rows, any normalisation), without changing state."""
        o = self.smoothed_reference(self.observation_si(self._rows(obs)), rows)
        current, _, _, e = self._compute(o, self.integral[rows], self.pending[rows].sum(axis=1))
        return current, e
