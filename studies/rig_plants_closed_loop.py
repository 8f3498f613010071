"""The virtual rig's plant stepped a control period at a time, for a closed loop.

:func:`.virtual_rig.run_rig` runs its plant open loop, on a whole excitation at once;
:func:`rig_plant` builds the same plant (the same forms: :mod:`.rig_plants`,
:mod:`.segmented_line`) as an object that advances one held command at a time, with
several effects at once:

- command effects filter the current at the plant rate, a chunk at a time (``coil_lag``'s
  amplifier hold and lags, then ``spool_friction``'s stick-slip play);
- split effects (:data:`.virtual_rig.SPLIT_EFFECTS`) act around the kernel's steps, in the
  order given; two forms may not drive the same kernel parameter;
- ``tube_waves`` replaces the kernel by the segmented line. Of the split effects only
  ``heat_transfer`` composes with it, inside the line: its chambers then follow the
  energy equation with the rig's wall conductance hA_ref (rho / rho_ref)^n
  (``_WallExchange``'s), the air entering at the wall's temperature, integrated with the
  line's RK4 steps instead of split between plant steps;
- ``pressure_sensor_lag`` filters the measured pressures at the plant rate
  (:meth:`RigPlant.measured`), the true outputs stay as they are.

:meth:`RigPlant.rollout` drives the plant open loop and returns every plant step's
outputs: :mod:`.rig_multi_effect` records with it.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter, lfilter_zi

from pneumatic_env.identification.config import IdentificationConfig
from pneumatic_env.ids import PISTON_MODE_NAMES
from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import layout as L
from pneumatic_env.simulator import BatchSimulator

from .rig_plants import _coil_filter, _plant_form, _stick_slip_play, _WallExchange
from .segmented_line import line_constants, line_rows, segmented_line_advance, segmented_line_rest
from .virtual_rig import LINE_EFFECTS, MOVING_EFFECTS, SPLIT_EFFECTS

__all__ = [
    "COMMAND_EFFECTS",
    "CLOSED_LOOP_EFFECTS",
    "LINE_SPLIT_EFFECTS",
    "SENSOR_EFFECTS",
    "RigPlant",
    "rig_plant",
]

#: Effects that filter the command at the plant rate, in this order.
COMMAND_EFFECTS = ("coil_lag", "spool_friction")
#: Effects on the measured channels (a filter at the plant rate).
SENSOR_EFFECTS = ("pressure_sensor_lag",)
#: Every effect the closed-loop plant can hold (several at once).
CLOSED_LOOP_EFFECTS = (*LINE_EFFECTS, *SPLIT_EFFECTS, *COMMAND_EFFECTS, *SENSOR_EFFECTS)
#: Split effects that compose with the segmented line (they act on its chambers' state).
LINE_SPLIT_EFFECTS = ("heat_transfer",)
#: Kernel parameters a split form drives (two forms may not drive the same one).
_DRIVEN_PARAMETER = {
    "supply_ripple": "supply_pressure_pa",
    "supply_droop": "supply_pressure_pa",
    "exhaust_muffler": "load_force_n",
    "lugre": "load_force_n",
}


class _CoilLag:
    """``coil_lag``: the rig's amplifier hold and current and force lags (``_coil_plant``),
    run a chunk of whole amplifier periods at a time, from rest at the first command."""

    def __init__(self, total_tau_s, dt_s, amplifier_period_s, force_share):
        self.hold = max(1, int(round(amplifier_period_s / dt_s)))
        self.num, self.den = _coil_filter(total_tau_s, dt_s, force_share)
        self.state: np.ndarray | None = None

    def __call__(self, current_a: np.ndarray) -> np.ndarray:
        held = np.repeat(current_a[:: self.hold], self.hold)[: current_a.size]
        if self.state is None:
            self.state = lfilter_zi(self.num, self.den) * held[0]
        y, self.state = lfilter(self.num, self.den, held, zi=self.state)
        # the value at the end of the last step: the filter's state (num[0] = 0, zero-order hold)
        return np.append(y[1:], self.state[0])


class _SpoolFriction:
    """``spool_friction``: the rig's stick-slip play (``_stick_slip_play``) on the current."""

    def __init__(self, band_a: float, breakaway_a: float):
        self.band_a, self.breakaway_a = band_a, breakaway_a
        self.state = [0.0, 0.0]

    def __call__(self, current_a: np.ndarray) -> np.ndarray:
        return _stick_slip_play(current_a, self.band_a, self.breakaway_a, self.state)


class _KernelPlant:
    """The kernel at the plant step, with split forms around its steps (as ``run_rig``)."""

    def __init__(self, true: dict, forms: list, plant_dt_s: float, plant_substeps: int):
        self.forms = forms
        self.steps_per_plant_step = plant_substeps if any(f.every_substep for f in forms) else 1
        self.h_s = plant_dt_s / self.steps_per_plant_step
        self.sim = BatchSimulator(
            parameter_array([true]), self.h_s, plant_substeps // self.steps_per_plant_step
        )
        self.row = self.sim.outputs[:, 0].copy()
        self.plant_step = 0

    def advance(self, fine_current_a: np.ndarray) -> np.ndarray:
        """Advance one plant step per entry of ``fine_current_a`` (held over it); returns
        the outputs at the end of each (rows)."""
        if not self.forms:
            rows = self.sim.rollout(fine_current_a[:, None])[:, :, 0]
            self.row = rows[-1].copy()
            self.plant_step += fine_current_a.size
            return rows
        rows = np.empty((fine_current_a.size, L.N_OUTPUT))
        for k, current in enumerate(fine_current_a):
            for _ in range(self.steps_per_plant_step):
                for form in self.forms:
                    form.before_step(self.sim, self.plant_step, self.h_s)
                rows[k] = self.sim.step(np.array([current]))[:, 0]
            for form in self.forms:
                form.correct_output(rows[k])
            self.plant_step += 1
        self.row = rows[-1].copy()
        return rows

    def outputs(self) -> np.ndarray:
        """The outputs (``layout.O_*``) at the end of the last plant step."""
        return self.row


class _LinePlant:
    """The segmented line (``tube_waves``); with ``heat_transfer`` its chambers follow the
    energy equation with the rig's density-dependent wall conductance (inside the line's
    RK4 steps, not split)."""

    def __init__(
        self, true: dict, wall: _WallExchange | None, plant_dt_s: float, cfg: IdentificationConfig
    ):
        segments = max(
            2,
            int(
                round(
                    true["tube_length_m"]
                    / cfg.number("virtual_rig", "line_segment_length_m", positive=True)
                )
            ),
        )
        heat = (
            None
            if wall is None
            else (wall.conductance_ref, wall.density_ref, wall.density_exponent)
        )
        self.n, self.c = segments, line_constants(true, segments, heat)
        self.y = segmented_line_rest(self.c, segments)
        self.substeps = int(cfg.number("virtual_rig", "line_substeps", positive=True))
        self.plant_dt_s = plant_dt_s
        self.exhaust_row = line_rows(segments)["exhaust_kg"]
        self.row = np.zeros(L.N_OUTPUT)
        self._write_row(segmented_line_advance(self.c, self.n, self.y, np.empty(0), 1.0, 1)[0])

    def _write_row(self, line_row: np.ndarray) -> None:
        self.row[[L.O_P1, L.O_P2, L.O_F, L.O_X]] = line_row
        self.row[L.O_EXHAUST] = self.y[self.exhaust_row]

    def advance(self, fine_current_a: np.ndarray) -> np.ndarray:
        """Advance one plant step per entry of ``fine_current_a`` (held over it); returns
        the outputs at the end of each (rows; the line's pressures, force and position,
        the other columns as at the end)."""
        line = segmented_line_advance(
            self.c, self.n, self.y, fine_current_a, self.plant_dt_s, self.substeps
        )
        self._write_row(line[-1])
        rows = np.tile(self.row, (fine_current_a.size, 1))
        rows[:, [L.O_P1, L.O_P2, L.O_F, L.O_X]] = line[1:]  # line[0]: the start
        return rows

    def outputs(self) -> np.ndarray:
        return self.row


class _PressureSensorLag:
    """``pressure_sensor_lag``: the rig's two cascaded lags of tau/2 (``_two_lags``) on the
    measured pressures at the plant rate, a chunk at a time, from rest at the first
    value."""

    def __init__(self, total_tau_s: float, dt_s: float, first_pa: np.ndarray):
        self.a = np.exp(-dt_s / (0.5 * total_tau_s))
        # one state per (lag, channel); at rest each lag's output is its input
        self.state = [[self.a * float(v)] for v in first_pa for _ in range(2)]
        self.measured = np.array(first_pa, dtype=float)

    def __call__(self, pressures_pa: np.ndarray) -> np.ndarray:
        """Lagged pressures (rows: plant steps; columns: p1, p2)."""
        out = np.empty_like(pressures_pa)
        for ch in range(pressures_pa.shape[1]):
            y = pressures_pa[:, ch]
            for stage in range(2):
                k = 2 * ch + stage
                y, self.state[k] = lfilter([1.0 - self.a], [1.0, -self.a], y, zi=self.state[k])
            out[:, ch] = y
        self.measured = out[-1].copy()
        return out


class RigPlant:
    """A plant of the virtual rig that advances a control period at a time; ``truth``:
    its parameters with the nearest kernel form of each effect (as ``run_rig``'s)."""

    def __init__(
        self,
        core,
        command_filters: list,
        plant_steps_per_control: int,
        sensor_lag: _PressureSensorLag | None = None,
        truth: dict | None = None,
    ):
        self.core, self.command_filters = core, command_filters
        self.plant_steps_per_control = plant_steps_per_control
        self.sensor_lag = sensor_lag
        self.truth = truth or {}

    def rollout(self, command_a: np.ndarray) -> np.ndarray:
        """Advance one plant step per entry of ``command_a`` (the command held over it),
        through the command filters; returns the outputs at the end of each (rows)."""
        fine = np.asarray(command_a, dtype=float)
        for command_filter in self.command_filters:
            fine = command_filter(fine)
        rows = self.core.advance(fine)
        if self.sensor_lag is not None:
            self.sensor_lag(rows[:, [L.O_P1, L.O_P2]])
        return rows

    def advance(self, coil_current_a: float) -> np.ndarray:
        """Hold ``coil_current_a`` over one control period; returns the outputs at its end."""
        self.rollout(np.full(self.plant_steps_per_control, float(coil_current_a)))
        return self.core.outputs()

    def outputs(self) -> np.ndarray:
        return self.core.outputs()

    def measured(self) -> np.ndarray:
        """The outputs as the rig's sensors give them now (the pressures through the
        sensor lag, if there is one; before noise)."""
        row = self.core.outputs().copy()
        if self.sensor_lag is not None:
            row[[L.O_P1, L.O_P2]] = self.sensor_lag.measured
        return row


def rig_plant(
    true: dict,
    cylinder: str,
    effects: dict[str, float],
    control_dt_s: float,
    plant_dt_s: float,
    plant_substeps: int,
    cfg: IdentificationConfig,
) -> RigPlant:
    """The rig's plant with parameters ``true`` and ``effects`` ({name: strength}, strength
    1 = ``virtual_rig.effects``), stepped at ``plant_dt_s`` (``plant_substeps`` RK4 steps
    each; the line's own ``line_substeps``), a whole number of plant steps per control
    period ``control_dt_s``."""
    ratio = int(round(control_dt_s / plant_dt_s))
    if ratio < 1 or abs(ratio * plant_dt_s - control_dt_s) > 1e-9 * control_dt_s:
        raise ValueError(
            f"plant_dt_s = {plant_dt_s!r} must divide the control period {control_dt_s!r}"
        )
    active = _checked_effects(effects, true)
    reference = lambda e: cfg.number("virtual_rig", "effects", e)  # noqa: E731
    piston = PISTON_MODE_NAMES[int(true["piston_mode"])]
    true = dict(true)
    line_true = dict(true)  # the line's plant: the forms switch kernel forms off in `true`
    truth: dict = dict(true)
    forms = [
        _plant_form(e, s, reference(e), true, truth, cfg, piston)
        for e, s in active.items()
        if e in SPLIT_EFFECTS
    ]
    filters = _command_filters(active, true, plant_dt_s, ratio, truth, cfg)
    if any(e in LINE_EFFECTS for e in active):
        truth.update(tube_waves=reference("tube_waves"), tube_volume_fraction=0.0)
        core = _LinePlant(line_true, forms[0] if forms else None, plant_dt_s, cfg)
    else:
        core = _KernelPlant(
            load_parameters(cylinder, params=true), forms, plant_dt_s, plant_substeps
        )
    lag = None
    if "pressure_sensor_lag" in active:
        tau = active["pressure_sensor_lag"] * reference("pressure_sensor_lag")
        lag = _PressureSensorLag(tau, plant_dt_s, core.outputs()[[L.O_P1, L.O_P2]])
    return RigPlant(core, filters, ratio, lag, truth)


def _checked_effects(effects: dict[str, float], true: dict) -> dict[str, float]:
    """The effects of strength > 0, or a clear refusal of a set the plant cannot hold."""
    unknown = [e for e in effects if e not in CLOSED_LOOP_EFFECTS]
    if unknown:
        raise ValueError(
            f"effects {unknown} have no closed-loop plant; "
            f"allowed: {', '.join(CLOSED_LOOP_EFFECTS)}"
        )
    active = {e: float(s) for e, s in effects.items() if float(s) > 0.0}
    driven = [_DRIVEN_PARAMETER[e] for e in active if e in _DRIVEN_PARAMETER]
    if len(driven) != len(set(driven)):
        raise ValueError(f"effects {sorted(active)} drive the same kernel parameter twice")
    if any(e in LINE_EFFECTS for e in active):
        bad = [e for e in active if e in SPLIT_EFFECTS and e not in LINE_SPLIT_EFFECTS]
        if bad:
            raise ValueError(f"effects {bad} do not compose with tube_waves (the segmented line)")
    piston = PISTON_MODE_NAMES[int(true["piston_mode"])]
    if piston == "fixed" and any(e in MOVING_EFFECTS for e in active):
        raise ValueError(f"effects {sorted(active)}: {MOVING_EFFECTS} need a moving piston")
    return active


def _command_filters(
    active: dict[str, float],
    true: dict,
    plant_dt_s: float,
    plant_steps_per_control: int,
    truth: dict,
    cfg: IdentificationConfig,
) -> list:
    """The command effects' filters in :data:`COMMAND_EFFECTS` order; their nearest
    kernel forms go into ``truth`` (as ``virtual_rig._coil_drive``)."""
    rig = lambda *path, **kw: cfg.number("virtual_rig", *path, **kw)  # noqa: E731
    filters: list = []
    if "coil_lag" in active:
        tau = active["coil_lag"] * rig("effects", "coil_lag")
        share = rig("coil_force_lag_share", minimum=0.0)
        coil = _CoilLag(tau, plant_dt_s, rig("coil_amplifier_period_s", positive=True), share)
        if plant_steps_per_control % coil.hold:
            raise ValueError("coil_lag: a control period must hold whole amplifier periods")
        truth.update(coil_time_constant_s=tau, coil_lag_shape=share * (1.0 - share))
        filters.append(coil)
    if "spool_friction" in active:
        coulomb_n = active["spool_friction"] * rig("effects", "spool_friction")
        truth["spool_coulomb_friction_n"] = coulomb_n
        band = coulomb_n / true["coil_force_n_per_a"]
        breakaway = rig("spool_breakaway_ratio", minimum=1.0)
        filters.append(_SpoolFriction(band, breakaway * band))
    return filters
