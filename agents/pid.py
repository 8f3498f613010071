"""PID force controller with anti-windup, reference-rate feed-forward and dead-band compensation.

    e     = r(k + d) - f(k)                         d = reference lead (steps of the preview)
    u     = kp e + I + kd D + k_ff rdot(k + d)      D: filtered derivative of -f (no kick)
    u_db  = u + i_db clip(u / i_ramp, -1, 1)        dead-band compensation (Eqs. 43, 46)
    i     = clip(u_db, -i_sat, i_sat)               i_sat = current opening the valve fully
    I    += ki e dt + (i - u_db) dt / T_t           back-calculation anti-windup

Why a *rate* feed-forward: with the rod clamped and no leakage, a closed valve holds any
force, so the static map from desired force to current is zero; the valve current sets the
flow, i.e. the force *rate* (Eq. 14 with dV = 0). ``k_ff`` maps the reference slope to a
current. i_db and i_sat follow from the valve geometry (``base.valve_currents``).
With ``reference_smoothing_steps`` W > 0, r is the reference's centred mean over 2 W + 1
periods (``base.Controller.smoothed_reference``; 0 in the benchmark's gains).
Gains come from ``configs/agents/pid-<variant>.yaml`` (written by ``agents/tune_pid.py``).
"""

from __future__ import annotations

import numpy as np

from .base import OBS_F, Controller, ControllerContext, check_gain, valve_currents

__all__ = ["PIDController", "PID_GAINS"]

PID_GAINS = (
    "kp_a_per_n",
    "ki_a_per_n_s",
    "kd_a_s_per_n",
    "derivative_filter_s",
    "rate_feedforward_a_s_per_n",
    "reference_lead_s",
    "antiwindup_tracking_s",
    "deadband_ramp_a",
)


class PIDController(Controller):
    """Batched PID; every gain may be a scalar or an array with one value per env (tuning)."""

    name = "pid"

    def __init__(
        self,
        context: ControllerContext,
        *,
        kp_a_per_n,
        ki_a_per_n_s,
        kd_a_s_per_n,
        derivative_filter_s,
        rate_feedforward_a_s_per_n,
        reference_lead_s,
        antiwindup_tracking_s,
        deadband_ramp_a,
        deadband_compensation,
        reference_smoothing_steps=0,
    ):
        super().__init__(context)
        own = "PIDController"
        self.set_reference_smoothing(own, reference_smoothing_steps)
        self.kp = check_gain(own, "kp_a_per_n", kp_a_per_n)
        self.ki = check_gain(own, "ki_a_per_n_s", ki_a_per_n_s)
        self.kd = check_gain(own, "kd_a_s_per_n", kd_a_s_per_n)
        self.tf = check_gain(own, "derivative_filter_s", derivative_filter_s)
        self.kff = check_gain(own, "rate_feedforward_a_s_per_n", rate_feedforward_a_s_per_n)
        self.tt = check_gain(own, "antiwindup_tracking_s", antiwindup_tracking_s, ge=None, gt=0.0)
        self.i_ramp = check_gain(own, "deadband_ramp_a", deadband_ramp_a, ge=None, gt=0.0)
        lead = check_gain(own, "reference_lead_s", reference_lead_s)
        self.lead_steps = np.rint(np.asarray(lead) / context.dt_s).astype(np.int64)
        if np.any(self.lead_steps + 1 > context.preview_steps):
            raise ValueError(
                f"{own}: reference_lead_s = {reference_lead_s!r} needs "
                f"{int(np.max(self.lead_steps)) + 1} preview steps, the env gives "
                f"{context.preview_steps}: raise preview_steps"
            )
        i_db, i_full = valve_currents(context.base_params)
        self.i_db = i_db if deadband_compensation else 0.0
        self.i_sat = min(i_full, context.i_max_a)

    def _allocate(self, n):
        self.integral = np.zeros(n)
        self.deriv = np.zeros(n)
        self.prev_f = np.full(n, np.nan)

    def _reset_rows(self, rows):
        self.integral[rows] = 0.0
        self.deriv[rows] = 0.0
        self.prev_f[rows] = np.nan

    def _act(self, obs):
        dt = self.context.dt_s
        f = obs[:, OBS_F]
        r = self.reference_ahead(obs, self.lead_steps)
        rdot = (self.reference_ahead(obs, self.lead_steps + 1) - r) / dt
        e = r - f
        df = np.where(np.isnan(self.prev_f), 0.0, f - self.prev_f)
        self.deriv = (self.tf * self.deriv - df) / (self.tf + dt)  # backward Euler of s/(tf s+1)
        self.prev_f = f.copy()
        u = self.kp * e + self.integral + self.kd * self.deriv + self.kff * rdot
        u_db = u + self.i_db * np.clip(u / self.i_ramp, -1.0, 1.0)
        i = np.clip(u_db, -self.i_sat, self.i_sat)
        self.integral = self.integral + self.ki * e * dt + (i - u_db) * dt / self.tt
        return i
