"""A batch of simulated actuators: owns the state arrays and calls the jitted kernel.

This is the one Python object between the kernel and every user of it (the Gymnasium
environments, recording replay, the paper's experiments, identification).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

import numba
import numpy as np

from .physics import kernel
from .physics import layout as L
from .physics.derived import tube_delay_s
from .physics.layout import SimArrays
from .physics.piston import MODE_FIXED

INITIAL_STATE_KEYS = ("p1", "p2", "x", "v", "x_s")
# parameters that set the tube delay tau = L_t / c (Eq. 31) or the transmission line: a
# change goes through set_params' checks (the ring buffer may have to grow)
DELAY_PARAMETERS = (
    "tube_length_m",
    "heat_capacity_ratio",
    "gas_constant_j_per_kg_k",
    "temperature_k",
    "tube_waves",
)
PARALLEL_MIN_ENVS = 256  # below this, threads cost more than they save (see docs/speed.md)


class BatchSimulator:
    """``n_envs`` actuators advanced together, one parameter column per environment.

    Parameters
    ----------
    params : array (N_PARAMS, n_envs) from ``params.parameter_array`` (copied).
    control_dt_s : control period; the coil current is held over it.
    n_substeps : RK4 substeps per control period.
    parallel : whether steps run the threaded kernel (default: ``n_envs >=
        PARALLEL_MIN_ENVS``); it does so only on more than one Numba thread.

    ``self.params`` is read-only: change parameters with ``set_params`` (whole columns) or
    ``set_parameter`` (one parameter, e.g. a drifting supply pressure during a run), which
    check the values and mark the kernel's cached constants of those environments stale.

    Attributes
    ----------
    arrays : the batch's ``layout.SimArrays``, as the step functions take them; its fields
        are also attributes of the simulator:
    state : array (N_STATE, n_envs), rows ``layout.S_*``.
    outputs : array (N_OUTPUT, n_envs) after the last step, rows ``layout.O_*``.
    history : the tube-delay ring buffer (slots, N_HISTORY, n_envs); ``head`` its newest slot.
    time_s : array (n_envs,), simulated time since each environment's reset.
    """

    arrays: SimArrays
    n_envs: int
    parallel: bool
    time_s: np.ndarray

    def __init__(
        self,
        params: np.ndarray,
        control_dt_s: float = 1e-3,
        n_substeps: int = 20,
        parallel: bool | None = None,
    ) -> None:
        params = np.array(params, dtype=np.float64, order="C", ndmin=2)
        if params.shape[0] != L.N_PARAMS:
            raise ValueError(
                f"params has {params.shape[0]} rows, expected {L.N_PARAMS} "
                "(one per name in pneumatic_env.physics.layout.PARAMETER_NAMES)"
            )
        if not np.all(np.isfinite(params)):
            bad = np.argwhere(~np.isfinite(params))[0]
            raise ValueError(
                f"params[{L.PARAMETER_NAMES[bad[0]]}] of environment {bad[1]} "
                f"is {params[tuple(bad)]}, must be finite"
            )
        if not (control_dt_s > 0 and np.isfinite(control_dt_s)):
            raise ValueError(f"control_dt_s = {control_dt_s} is not allowed: must be > 0")
        if int(n_substeps) != n_substeps or n_substeps < 1:
            raise ValueError(f"n_substeps = {n_substeps} is not allowed: must be an integer >= 1")
        params.flags.writeable = False
        self.n_envs = params.shape[1]
        self.parallel = self.n_envs >= PARALLEL_MIN_ENVS if parallel is None else bool(parallel)
        # the kernel's per-environment constants, refreshed where set_params or set_parameter
        # marked them stale
        constants_key, constants = kernel.constants_cache(self.n_envs)
        no_history = np.zeros((0, L.N_HISTORY, self.n_envs))  # sized below, from the delays
        self.arrays = SimArrays(
            params,
            np.zeros((L.N_STATE, self.n_envs)),
            no_history,
            np.zeros(1, dtype=np.int64),
            np.zeros((L.N_OUTPUT, self.n_envs)),
            constants_key,
            constants,
            float(control_dt_s),
            int(n_substeps),
        )
        self.history = np.zeros((self._slots_needed(), L.N_HISTORY, self.n_envs))
        self.time_s = np.zeros(self.n_envs)
        self._check_tube_waves(range(self.n_envs))
        self.reset()

    # -- the fields of ``arrays`` ---------------------------------------------------------
    @property
    def params(self) -> np.ndarray:
        return self.arrays.params

    @property
    def state(self) -> np.ndarray:
        return self.arrays.state

    @property
    def history(self) -> np.ndarray:
        return self.arrays.history

    @history.setter
    def history(self, history: np.ndarray) -> None:
        self.arrays = self.arrays._replace(history=history)

    @property
    def head(self) -> int:
        return int(self.arrays.head[0])

    @head.setter
    def head(self, head: int) -> None:
        self.arrays.head[0] = head

    @property
    def outputs(self) -> np.ndarray:
        return self.arrays.outputs

    @property
    def constants_key(self) -> np.ndarray:
        return self.arrays.constants_key

    @property
    def constants(self) -> np.ndarray:
        return self.arrays.constants

    @property
    def control_dt_s(self) -> float:
        return self.arrays.control_dt_s

    @property
    def n_substeps(self) -> int:
        return self.arrays.n_substeps

    # -- parameters ----------------------------------------------------------------------
    def delays_s(self) -> np.ndarray:
        """Tube delay tau = L_t / c of each environment (Eq. 31), s."""
        p = self.params
        return np.array(
            [
                tube_delay_s(
                    p[L.P_TUBE_LENGTH_M, i],
                    p[L.P_HEAT_CAPACITY_RATIO, i],
                    p[L.P_GAS_CONSTANT_J_PER_KG_K, i],
                    p[L.P_TEMPERATURE_K, i],
                )
                for i in range(self.n_envs)
            ],
            dtype=np.float64,
        )

    def _check_tube_waves(self, envs: Iterable[int]) -> None:
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
                    f"{length * substep_s / delays[env] if delays[env] > 0 else np.inf:.3g} m "
                    f"or more substeps, or tube_waves = 0"
                )

    def _slots_needed(self) -> int:
        return kernel.history_slots(
            float(self.delays_s().max()), self.control_dt_s, self.n_substeps
        )

    def set_params(self, envs: Sequence[int] | np.ndarray, columns: np.ndarray) -> None:
        """Replace the parameter columns of ``envs`` (call ``reset(envs)`` afterwards)."""
        envs = np.atleast_1d(np.asarray(envs, dtype=np.int64))
        columns = np.asarray(columns, dtype=np.float64).reshape(L.N_PARAMS, len(envs))
        if not np.all(np.isfinite(columns)):
            row, col = np.argwhere(~np.isfinite(columns))[0]
            raise ValueError(
                f"set_params: {L.PARAMETER_NAMES[row]} of environment {envs[col]} "
                f"is {columns[row, col]}, must be finite"
            )
        previous = self.params[:, envs].copy()
        self._write_params((slice(None), envs), columns, envs)
        try:
            self._check_tube_waves(envs)
        except ValueError:
            # a refused change leaves the batch as it was
            self._write_params((slice(None), envs), previous, envs)
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

    def set_parameter(
        self, name: str, envs: Sequence[int] | np.ndarray | int, value: float
    ) -> None:
        """Set parameter ``name`` of ``envs`` to ``value`` from the next step on (no reset
        needed; a parameter in ``DELAY_PARAMETERS`` goes through ``set_params``)."""
        if name not in L.PARAMETER_INDEX:
            raise ValueError(
                f"set_parameter: name = {name!r} is not a parameter; allowed: "
                "the names in pneumatic_env.physics.layout.PARAMETER_NAMES"
            )
        value = float(value)
        if not np.isfinite(value):
            raise ValueError(f"set_parameter: {name} = {value} is not allowed: must be finite")
        envs = np.atleast_1d(np.asarray(envs, dtype=np.int64))
        row = L.PARAMETER_INDEX[name]
        if name in DELAY_PARAMETERS:
            columns = self.params[:, envs].copy()
            columns[row] = value
            self.set_params(envs, columns)
        else:
            self._write_params((row, envs), value, envs)

    def _write_params(self, index, values, envs: np.ndarray) -> None:
        """``params[index] = values``, and the cached constants of ``envs`` marked stale."""
        self.params.flags.writeable = True
        try:
            self.params[index] = values
        finally:
            self.params.flags.writeable = False
        self.constants_key[envs] = np.nan

    # -- state ---------------------------------------------------------------------------
    def _initial_columns(self, envs: np.ndarray, initial: Mapping[str, float] | None) -> dict:
        """{key: array over ``envs``} of the initial state: both chambers at ambient, piston at
        rest (at the clamp position when fixed), spool centred, with ``initial`` applied."""
        p = self.params[:, envs]
        fixed = p[L.P_PISTON_MODE].astype(np.int64) == MODE_FIXED
        columns = {
            "p1": p[L.P_AMBIENT_PRESSURE_PA].copy(),
            "p2": p[L.P_AMBIENT_PRESSURE_PA].copy(),
            "x": np.where(fixed, p[L.P_FIXED_POSITION_M], 0.0),
            "v": np.zeros(len(envs)),
            "x_s": np.zeros(len(envs)),
        }
        if initial:
            unknown = set(initial) - set(INITIAL_STATE_KEYS)
            if unknown:
                raise ValueError(
                    f"initial state key(s) {sorted(unknown)} not known; "
                    f"allowed: {list(INITIAL_STATE_KEYS)}"
                )
            for key, value in initial.items():
                value = float(value)
                if not np.isfinite(value):
                    raise ValueError(f"initial['{key}'] = {value} must be finite")
                columns[key][:] = value
        half = 0.5 * p[L.P_STROKE_M]
        outside = np.flatnonzero(np.abs(columns["x"]) > half)
        if outside.size:
            x, h = columns["x"][outside[0]], half[outside[0]]
            raise ValueError(f"initial['x'] = {x} is outside the stroke: must be in [{-h}, {h}] m")
        for key in ("p1", "p2"):
            if np.any(columns[key] <= 0):
                raise ValueError(
                    f"initial['{key}'] = {columns[key].min()} must be > 0 Pa (absolute)"
                )
        columns["x"] = np.where(fixed, p[L.P_FIXED_POSITION_M], columns["x"])
        columns["v"] = np.where(fixed, 0.0, columns["v"])
        return columns

    def reset(
        self,
        envs: Sequence[int] | np.ndarray | None = None,
        initial: Mapping[str, float] | None = None,
    ) -> None:
        """Put ``envs`` (default: all) in their initial state; the delay history equals it."""
        envs = (
            np.arange(self.n_envs)
            if envs is None
            else np.atleast_1d(np.asarray(envs, dtype=np.int64))
        )
        s = self._initial_columns(envs, initial)
        self.state[:, envs] = 0.0
        self.state[L.S_X_S, envs], self.state[L.S_P1, envs] = s["x_s"], s["p1"]
        self.state[L.S_P2, envs], self.state[L.S_X, envs] = s["p2"], s["x"]
        self.state[L.S_V, envs] = s["v"]
        temperature = self.params[L.P_TEMPERATURE_K, envs]
        self.state[L.S_T1, envs] = self.state[L.S_T2, envs] = temperature  # gas (effects)
        self.state[L.S_EXHAUST_NODE, envs] = self.params[L.P_AMBIENT_PRESSURE_PA, envs]
        self.history[:, L.H_X_S, envs] = s["x_s"]
        self.history[:, L.H_P1, envs] = s["p1"]
        self.history[:, L.H_P2, envs] = s["p2"]
        # the lines at rest: every wave is the pressure of its end (no flow)
        for row in (L.H_WAVE_VALVE_1, L.H_WAVE_CHAMBER_1):
            self.history[:, row, envs] = s["p1"]
        for row in (L.H_WAVE_VALVE_2, L.H_WAVE_CHAMBER_2):
            self.history[:, row, envs] = s["p2"]
        kernel.line_exhaust_at_rest(self.params, self.state, self.history, envs)
        self.time_s[envs] = 0.0
        kernel.write_outputs(self.params, self.state, envs, self.outputs)

    # -- stepping ------------------------------------------------------------------------
    def step(self, coil_current_a: np.ndarray) -> np.ndarray:
        """Advance all environments by one control period; returns ``outputs[O_*, env]``
        (a view)."""
        coil_current_a = self._check_currents(coil_current_a, (self.n_envs,))
        self.call_step_kernel(
            kernel.step_serial, kernel.step_parallel, (tuple(self.arrays), coil_current_a)
        )
        self.advance_clock()
        return self.outputs

    def call_step_kernel(
        self, serial: Callable[..., None], parallel: Callable[..., None], args: tuple
    ) -> None:
        """``parallel(*args)`` when this batch runs on threads (``self.parallel`` and more
        than one Numba thread), its chunks handed to the threads one at a time
        (``kernel.PARALLEL_CHUNKS_PER_HANDOUT``), else ``serial(*args)`` (on one thread the
        parallel kernel only adds its scheduling: 3 % at N = 1024): the one place of the
        threading policy of every step function."""
        if self.parallel and numba.get_num_threads() > 1:
            with numba.parallel_chunksize(kernel.PARALLEL_CHUNKS_PER_HANDOUT):
                parallel(*args)
        else:
            serial(*args)

    def _check_currents(self, currents, shape) -> np.ndarray:
        """Coil currents as a C-contiguous float64 array of ``shape``, all finite."""
        a = np.ascontiguousarray(currents, dtype=np.float64)
        if a.shape != shape:
            raise ValueError(
                f"coil_current_a has shape {a.shape}, expected {shape} "
                "(steps x environments for rollout, environments for step)"
            )
        if not np.isfinite(a).all():
            raise ValueError(
                f"coil_current_a contains {a[~np.isfinite(a)][0]}: coil currents must be finite (A)"
            )
        return a

    def advance_clock(self, n_steps: int = 1) -> None:
        """Move the ring-buffer head and the clocks after the kernel advanced ``n_steps``
        control periods."""
        arrays = self.arrays
        head = arrays.head  # .item(): Python int arithmetic, faster than NumPy scalars
        head[0] = (head.item() + n_steps * arrays.n_substeps) % arrays.history.shape[0]
        self.time_s += n_steps * arrays.control_dt_s

    def rollout(self, coil_current_a: np.ndarray) -> np.ndarray:
        """Open-loop run of ``coil_current_a[step, env]`` in one jitted call.

        Returns ``outputs[step, O_*, env]`` after each control period.
        """
        currents = np.asarray(coil_current_a, dtype=np.float64)
        if currents.ndim == 1 and self.n_envs == 1:
            currents = currents[:, None]
        currents = self._check_currents(currents, (currents.shape[0], self.n_envs))
        out = np.empty((currents.shape[0], L.N_OUTPUT, self.n_envs))
        kernel.rollout_serial(tuple(self.arrays), currents, out)
        self.advance_clock(currents.shape[0])
        if currents.shape[0]:
            self.outputs[:] = out[-1]
        return out
