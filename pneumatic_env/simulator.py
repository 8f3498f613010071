"""A batch of simulated actuators: owns the state arrays and calls the jitted kernel.

This is the one Python object between the kernel and every user of it (the Gymnasium
environments, recording replay, the paper's experiments, identification).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .physics import kernel
from .physics import layout as L
from .physics.piston import MODE_FIXED
from .physics.tube import sound_speed

INITIAL_STATE_KEYS = ("p1", "p2", "x", "v", "x_s")
PARALLEL_MIN_ENVS = 256  # below this, threads cost more than they save (see docs/speed.md)


class BatchSimulator:
    """``n_envs`` actuators advanced together, one parameter column per environment.

    Parameters
    ----------
    params : array (N_PARAMS, n_envs) from ``params.parameter_array``.
    control_dt_s : control period; the coil current is held over it.
    n_substeps : RK4 substeps per control period.
    """

    def __init__(self, params: np.ndarray, control_dt_s: float = 1e-3, n_substeps: int = 20,
                 parallel: bool | None = None):
        params = np.array(params, dtype=np.float64, order="C", ndmin=2)
        if params.shape[0] != L.N_PARAMS:
            raise ValueError(f"params has {params.shape[0]} rows, expected {L.N_PARAMS} "
                             "(one per name in pneumatic_env.physics.layout.PARAMETER_NAMES)")
        if not np.all(np.isfinite(params)):
            bad = np.argwhere(~np.isfinite(params))[0]
            raise ValueError(f"params[{L.PARAMETER_NAMES[bad[0]]}] of environment {bad[1]} "
                             f"is {params[tuple(bad)]}, must be finite")
        if not (control_dt_s > 0 and np.isfinite(control_dt_s)):
            raise ValueError(f"control_dt_s = {control_dt_s} is not allowed: must be > 0")
        if int(n_substeps) != n_substeps or n_substeps < 1:
            raise ValueError(f"n_substeps = {n_substeps} is not allowed: must be an integer >= 1")
        self.params = params
        self.n_envs = params.shape[1]
        self.control_dt_s = float(control_dt_s)
        self.n_substeps = int(n_substeps)
        self.parallel = self.n_envs >= PARALLEL_MIN_ENVS if parallel is None else bool(parallel)
        self.state = np.zeros((L.N_STATE, self.n_envs))
        self.outputs = np.zeros((L.N_OUTPUT, self.n_envs))
        self.head = 0
        self.history = np.zeros((self._slots_needed(), L.N_HISTORY, self.n_envs))
        # the kernel's per-environment constants, refreshed when a parameter column changes
        self.constants_key, self.constants = kernel.constants_cache(self.n_envs)
        self.time_s = np.zeros(self.n_envs)
        self._check_tube_waves(range(self.n_envs))
        self.reset()

    # -- parameters ----------------------------------------------------------------------
    def delays_s(self) -> np.ndarray:
        """Tube delay tau = L_t / c of each environment (Eq. 31)."""
        p = self.params
        c = np.array([sound_speed(p[L.P_HEAT_CAPACITY_RATIO, i], p[L.P_GAS_CONSTANT_J_PER_KG_K, i],
                                  p[L.P_TEMPERATURE_K, i]) for i in range(self.n_envs)])
        return p[L.P_TUBE_LENGTH_M] / c

    def _check_tube_waves(self, envs) -> None:
        """The transmission line (``tube_waves = 1``) reads waves sent at least one substep ago."""
        substep_s = self.control_dt_s / self.n_substeps
        delays = self.delays_s()
        for env in envs:
            if self.params[L.P_TUBE_WAVES, env] == 1.0 and delays[env] / substep_s < 1.0:
                length = self.params[L.P_TUBE_LENGTH_M, env]
                raise ValueError(
                    f"tube_waves = 1 (transmission line) of environment {env} needs a tube delay "
                    f"L_t/c of at least one substep ({substep_s:g} s); tube_length_m = {length:g} "
                    f"gives {delays[env]:g} s: use a tube of at least "
                    f"{length * substep_s / delays[env] if delays[env] > 0 else float('inf'):.3g} m "
                    f"or more substeps, or tube_waves = 0")

    def _slots_needed(self) -> int:
        return kernel.history_slots(float(self.delays_s().max()), self.control_dt_s,
                                    self.n_substeps)

    def set_params(self, envs: Sequence[int] | np.ndarray, columns: np.ndarray) -> None:
        """Replace the parameter columns of ``envs`` (call ``reset(envs)`` afterwards)."""
        envs = np.atleast_1d(np.asarray(envs, dtype=np.int64))
        columns = np.asarray(columns, dtype=np.float64).reshape(L.N_PARAMS, len(envs))
        if not np.all(np.isfinite(columns)):
            row, col = np.argwhere(~np.isfinite(columns))[0]
            raise ValueError(f"set_params: {L.PARAMETER_NAMES[row]} of environment {envs[col]} "
                             f"is {columns[row, col]}, must be finite")
        previous = self.params[:, envs].copy()
        self.params[:, envs] = columns
        try:
            self._check_tube_waves(envs)
        except ValueError:
            self.params[:, envs] = previous  # a refused change leaves the batch as it was
            raise
        slots = self._slots_needed()
        if slots > self.history.shape[0]:  # a longer tube than the buffer holds: grow it
            # unroll the ring so the newest sample stays at head; pad with the oldest
            order = (self.head - np.arange(self.history.shape[0])) % self.history.shape[0]
            newest_first = self.history[order]
            pad = np.repeat(newest_first[-1:], slots - len(order), axis=0)
            grown = np.empty((slots, L.N_HISTORY, self.n_envs))
            grown[(self.head - np.arange(slots)) % slots] = np.concatenate([newest_first, pad])
            self.history = grown

    # -- state ---------------------------------------------------------------------------
    def default_initial_state(self, env: int) -> dict:
        """Both chambers at ambient, piston at rest (at the clamp position when fixed), spool centred."""
        p = self.params[:, env]
        x = p[L.P_FIXED_POSITION_M] if int(p[L.P_PISTON_MODE]) == MODE_FIXED else 0.0
        return {"p1": p[L.P_AMBIENT_PRESSURE_PA], "p2": p[L.P_AMBIENT_PRESSURE_PA], "x": x,
                "v": 0.0, "x_s": 0.0}

    def reset(self, envs: Sequence[int] | np.ndarray | None = None,
              initial: Mapping[str, float] | None = None) -> None:
        """Put ``envs`` (default: all) in their initial state; the delay history equals it."""
        envs = range(self.n_envs) if envs is None else np.atleast_1d(envs)
        for env in envs:
            s = self.default_initial_state(int(env))
            if initial:
                unknown = set(initial) - set(INITIAL_STATE_KEYS)
                if unknown:
                    raise ValueError(f"initial state key(s) {sorted(unknown)} not known; "
                                     f"allowed: {list(INITIAL_STATE_KEYS)}")
                for key, value in initial.items():
                    value = float(value)
                    if not np.isfinite(value):
                        raise ValueError(f"initial['{key}'] = {value} must be finite")
                    s[key] = value
            p = self.params[:, int(env)]
            half = 0.5 * p[L.P_STROKE_M]
            if abs(s["x"]) > half:
                raise ValueError(f"initial['x'] = {s['x']} is outside the stroke: must be in "
                                 f"[{-half}, {half}] m")
            for key in ("p1", "p2"):
                if s[key] <= 0:
                    raise ValueError(f"initial['{key}'] = {s[key]} must be > 0 Pa (absolute)")
            if int(p[L.P_PISTON_MODE]) == MODE_FIXED:
                s["x"], s["v"] = p[L.P_FIXED_POSITION_M], 0.0
            col = self.state[:, int(env)]
            col[:] = 0.0
            col[L.S_X_S], col[L.S_P1], col[L.S_P2] = s["x_s"], s["p1"], s["p2"]
            col[L.S_X], col[L.S_V] = s["x"], s["v"]
            col[L.S_T1] = col[L.S_T2] = p[L.P_TEMPERATURE_K]  # gas temperatures (effects)
            col[L.S_EXHAUST_NODE] = p[L.P_AMBIENT_PRESSURE_PA]  # no exhaust flow yet
            self.history[:, L.H_X_S, int(env)] = s["x_s"]
            self.history[:, L.H_P1, int(env)] = s["p1"]
            self.history[:, L.H_P2, int(env)] = s["p2"]
            # the lines at rest: every wave is the pressure of its end (no flow)
            self.history[:, [L.H_WAVE_VALVE_1, L.H_WAVE_CHAMBER_1], int(env)] = s["p1"]
            self.history[:, [L.H_WAVE_VALVE_2, L.H_WAVE_CHAMBER_2], int(env)] = s["p2"]
            self.time_s[int(env)] = 0.0
            self._write_outputs(int(env))

    def _write_outputs(self, env: int) -> None:
        from .physics.piston import output_force, pneumatic_force  # jitted, cheap
        p, s = self.params[:, env], self.state[:, env]
        bore, rod = p[L.P_BORE_DIAMETER_M], p[L.P_ROD_DIAMETER_M]
        a1, ar = 0.25 * np.pi * bore ** 2, 0.25 * np.pi * rod ** 2
        f_p = pneumatic_force(s[L.S_P1], s[L.S_P2], a1, a1 - ar, ar, p[L.P_AMBIENT_PRESSURE_PA])
        o = self.outputs[:, env]
        o[L.O_P1], o[L.O_P2], o[L.O_X] = s[L.S_P1], s[L.S_P2], s[L.S_X]
        o[L.O_F] = output_force(int(p[L.P_PISTON_MODE]), f_p, s[L.S_X],
                                p[L.P_SPRING_STIFFNESS_N_PER_M], p[L.P_SPRING_REST_POSITION_M])
        o[L.O_V], o[L.O_X_S], o[L.O_EXHAUST] = s[L.S_V], s[L.S_X_S], s[L.S_EXHAUST]

    # -- stepping ------------------------------------------------------------------------
    def step(self, coil_current_a: np.ndarray) -> np.ndarray:
        """Advance all environments by one control period; returns ``outputs[O_*, env]`` (a view)."""
        coil_current_a = self._check_currents(coil_current_a, (self.n_envs,))
        fn = kernel.step_parallel if self.parallel else kernel.step_serial
        fn(self.params, self.state, self.history, self.head, coil_current_a, self.control_dt_s,
           self.n_substeps, self.outputs, self.constants_key, self.constants)
        self.advance_clock()
        return self.outputs

    def _check_currents(self, currents, shape) -> np.ndarray:
        """Coil currents as a C-contiguous float64 array of ``shape``, all finite."""
        a = np.ascontiguousarray(currents, dtype=np.float64)
        if a.shape != shape:
            raise ValueError(f"coil_current_a has shape {a.shape}, expected {shape} "
                             "(steps x environments for rollout, environments for step)")
        if not np.isfinite(a).all():
            raise ValueError(f"coil_current_a contains {a[~np.isfinite(a)][0]}: coil currents "
                             "must be finite (A)")
        return a

    def advance_clock(self, n_steps: int = 1) -> None:
        """Move the ring-buffer head and the clocks after the kernel advanced ``n_steps`` periods."""
        self.head = (self.head + n_steps * self.n_substeps) % self.history.shape[0]
        self.time_s += n_steps * self.control_dt_s

    def rollout(self, coil_current_a: np.ndarray) -> np.ndarray:
        """Open-loop run of ``coil_current_a[step, env]`` in one jitted call.

        Returns ``outputs[step, O_*, env]`` after each control period.
        """
        currents = np.asarray(coil_current_a, dtype=np.float64)
        if currents.ndim == 1 and self.n_envs == 1:
            currents = currents[:, None]
        currents = self._check_currents(currents, (currents.shape[0], self.n_envs))
        out = np.empty((currents.shape[0], L.N_OUTPUT, self.n_envs))
        kernel.rollout_serial(self.params, self.state, self.history, self.head, currents,
                              self.control_dt_s, self.n_substeps, out, self.constants_key,
                              self.constants)
        self.advance_clock(currents.shape[0])
        if currents.shape[0]:
            self.outputs[:] = out[-1]
        return out
