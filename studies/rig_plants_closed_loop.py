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
  line's RK4 steps instead of split between plant steps.
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

__all__ = ["COMMAND_EFFECTS", "CLOSED_LOOP_EFFECTS", "LINE_SPLIT_EFFECTS", "rig_plant"]

#: Effects that filter the command at the plant rate, in this order.
COMMAND_EFFECTS = ("coil_lag", "spool_friction")
#: Every effect the closed-loop plant can hold (several at once).
CLOSED_LOOP_EFFECTS = (*LINE_EFFECTS, *SPLIT_EFFECTS, *COMMAND_EFFECTS)
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

    def advance(self, fine_current_a: np.ndarray) -> None:
        """Advance one plant step per entry of ``fine_current_a`` (held over it)."""
        if not self.forms:
            self.row = self.sim.rollout(fine_current_a[:, None])[-1, :, 0].copy()
            self.plant_step += fine_current_a.size
            return
        for current in fine_current_a:
            for _ in range(self.steps_per_plant_step):
                for form in self.forms:
                    form.before_step(self.sim, self.plant_step, self.h_s)
                self.row = self.sim.step(np.array([current]))[:, 0].copy()
            for form in self.forms:
                form.correct_output(self.row)
            self.plant_step += 1

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

    def advance(self, fine_current_a: np.ndarray) -> None:
        """Advance one plant step per entry of ``fine_current_a`` (held over it)."""
        line = segmented_line_advance(
            self.c, self.n, self.y, fine_current_a, self.plant_dt_s, self.substeps
        )
        self._write_row(line[-1])

    def outputs(self) -> np.ndarray:
        return self.row


class RigPlant:
    """A plant of the virtual rig that advances a control period at a time."""

    def __init__(self, core, command_filters: list, plant_steps_per_control: int):
        self.core, self.command_filters = core, command_filters
        self.plant_steps_per_control = plant_steps_per_control

    def advance(self, coil_current_a: float) -> np.ndarray:
        """Hold ``coil_current_a`` over one control period; returns the outputs at its end."""
        fine = np.full(self.plant_steps_per_control, float(coil_current_a))
        for command_filter in self.command_filters:
            fine = command_filter(fine)
        self.core.advance(fine)
        return self.core.outputs()

    def outputs(self) -> np.ndarray:
        return self.core.outputs()


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
    unknown = [e for e in effects if e not in CLOSED_LOOP_EFFECTS]
    if unknown:
        raise ValueError(
            f"effects {unknown} have no closed-loop plant; "
            f"allowed: {', '.join(CLOSED_LOOP_EFFECTS)}"
        )
    active = {e: float(s) for e, s in effects.items() if float(s) > 0.0}
    on_line = any(e in LINE_EFFECTS for e in active)
    driven = [_DRIVEN_PARAMETER[e] for e in active if e in _DRIVEN_PARAMETER]
    if len(driven) != len(set(driven)):
        raise ValueError(f"effects {sorted(active)} drive the same kernel parameter twice")
    if on_line:
        bad = [e for e in active if e in SPLIT_EFFECTS and e not in LINE_SPLIT_EFFECTS]
        if bad:
            raise ValueError(f"effects {bad} do not compose with tube_waves (the segmented line)")
    piston = PISTON_MODE_NAMES[int(true["piston_mode"])]
    if piston == "fixed" and any(e in MOVING_EFFECTS for e in active):
        raise ValueError(f"effects {sorted(active)}: {MOVING_EFFECTS} need a moving piston")
    true = dict(true)
    line_true = dict(true)  # the line's plant: the forms switch kernel forms off in `true`
    truth: dict = {}
    forms = [
        _plant_form(e, s, cfg.number("virtual_rig", "effects", e), true, truth, cfg, piston)
        for e, s in active.items()
        if e in SPLIT_EFFECTS
    ]
    filters: list = []
    if "coil_lag" in active:
        period = cfg.number("virtual_rig", "coil_amplifier_period_s", positive=True)
        coil = _CoilLag(
            active["coil_lag"] * cfg.number("virtual_rig", "effects", "coil_lag"),
            plant_dt_s,
            period,
            cfg.number("virtual_rig", "coil_force_lag_share", minimum=0.0),
        )
        if ratio % coil.hold:
            raise ValueError("coil_lag: a control period must hold whole amplifier periods")
        filters.append(coil)
    if "spool_friction" in active:
        band = (
            active["spool_friction"]
            * cfg.number("virtual_rig", "effects", "spool_friction")
            / true["coil_force_n_per_a"]
        )
        breakaway = cfg.number("virtual_rig", "spool_breakaway_ratio", minimum=1.0)
        filters.append(_SpoolFriction(band, breakaway * band))
    if on_line:
        core = _LinePlant(line_true, forms[0] if forms else None, plant_dt_s, cfg)
    else:
        core = _KernelPlant(
            load_parameters(cylinder, params=true), forms, plant_dt_s, plant_substeps
        )
    return RigPlant(core, filters, ratio)
