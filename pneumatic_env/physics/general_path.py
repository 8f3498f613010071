"""The kernel's general path: one environment through a whole control period
(``advance_env``), for environments with effects that need the general right-hand side and
for a batch-path lane whose substep is stiff or crosses a piston event.

Each of the ``n_substeps`` RK4 substeps holds the coil current (zero-order hold); a
substep is split into equal parts where the flow is stiff (``refinement``) and at piston
events (``_advance_interval``): friction and end stops are handled between RK4 steps
(``piston.motion_direction`` / ``piston.end_of_substep``), so each step integrates a smooth
right-hand side. The delay history is written at the substep boundaries only.
"""

import math

from numba import njit

from . import layout as L
from .chamber import chamber_volumes
from .constants import env_constants
from .effects import lugre_bristle_step, spool_play_current
from .nodes import (
    exhaust_pressure_at_valve,
    line_chamber_flows,
    line_flows,
    line_valve_ends,
    scalar_area,
    sent_wave,
)
from .piston import (
    MODE_FIXED,
    apply_event,
    end_of_substep,
    event_fraction,
    external_force,
    motion_direction,
    output_force,
    pneumatic_force,
)
from .right_hand_side import (
    N_RK,
    SubstepDrive,
    arriving_waves,
    coil_at,
    inv_sqrt_temperatures,
    ring_slot,
    rk4_step,
    sliding_friction,
    valve_inputs,
)

# advance_env integrates the state rows 0 .. S_T2 with RK4 and sets S_COIL, S_PLAY,
# S_COIL_FORCE, S_EXHAUST_NODE and S_BRISTLE exactly.
assert (
    L.S_T1,
    L.S_T2,
    L.S_COIL,
    L.S_PLAY,
    L.S_COIL_FORCE,
    L.S_EXHAUST_NODE,
    L.S_BRISTLE,
    L.N_STATE,
) == (7, 8, 9, 10, 11, 12, 13, 14), "kernel assumes this state layout"

MAX_EVENTS_PER_SUBSTEP = 4
MIN_EVENT_FRACTION = 1e-6  # events closer than this to the interval start are applied at once
# largest h * lambda_max before a substep is split (RK4's real-axis stability limit: 2.79)
STIFFNESS_LIMIT = 2.0
LUGRE_COUPLING_LIMIT = 0.5  # largest h sqrt(sigma0 / M) and h sigma1 / M of a LuGre part
MAX_REFINEMENT = 64  # a substep is split into at most this many equal parts


@njit(cache=True, forceinline=True, error_model="numpy")
def stiffness_ratio(c, y, h):
    """h * lambda_max of a substep of ``h`` seconds from ``y`` (see ``refinement``)."""
    x, v = y[4], y[5]
    x_min = min(max(x - abs(v) * h, -c.half_stroke), c.half_stroke)
    x_max = min(max(x + abs(v) * h, -c.half_stroke), c.half_stroke)
    v1, _ = chamber_volumes(x_min, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod)
    _, v2 = chamber_volumes(x_max, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod)
    return h * c.stiffness_volume / min(v1, v2)


@njit(cache=True)
def refinement(c, y, h):
    """Equal parts (a power of two) to split a substep into so that h * lambda <= the limit.

    lambda bounds the flow-pressure stiffness dPdot/dP of a chamber (Eqs. 14, 39, 52):
    R T alpha C_f A_max (max |m_r'| + C1) / (sqrt(T) V_min), with V_min the smaller
    chamber volume this substep can reach (``stiffness_ratio``). It is large only when a
    chamber is nearly empty (piston near a stop), where a fixed substep would chatter.
    With LuGre friction the parts also keep the bristles' explicit coupling to the rod
    (``split_substep``) within ``LUGRE_COUPLING_LIMIT``: h sqrt(sigma0 / M) for the
    pre-sliding spring, h sigma1 / M for its damping.
    """
    ratio = stiffness_ratio(c, y, h)
    if c.lugre and c.mode != MODE_FIXED:  # the bristles act on the rod once per part
        ratio = max(
            ratio,
            STIFFNESS_LIMIT
            / LUGRE_COUPLING_LIMIT
            * h
            * max(
                math.sqrt(c.lugre_stiffness * c.inv_moving_mass),
                c.lugre_damping * c.inv_moving_mass,
            ),
        )
    parts = 1
    while ratio > STIFFNESS_LIMIT and parts < MAX_REFINEMENT:
        parts *= 2
        ratio *= 0.5
    return parts


@njit(cache=True)
def _advance_interval(c, drive, frac_start, frac_end, y, y0):
    """Integrate substep fractions [frac_start, frac_end] of the ``SubstepDrive`` ``drive``,
    splitting at piston events.

    When the sliding piston's attempted step crosses an end stop or its velocity reverses,
    the step is redone up to the event (located by linear interpolation), the event is
    applied (inelastic stop, or v = 0 and the stick test), and the rest is integrated.
    """
    frac0 = frac_start
    for _ in range(MAX_EVENTS_PER_SUBSTEP):
        direction = 0.0
        if c.mode != MODE_FIXED:
            applied = (
                pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
                - external_force(c.mode, y[4], c.load_force, c.spring_k, c.spring_rest)
                - drive.lugre_friction_n
            )
            direction = motion_direction(y[4], y[5], applied, c.stick_threshold, c.half_stroke)
        dfrac = frac_end - frac0
        trial = rk4_step(c, drive, frac0, dfrac, y, y0, direction)
        theta = -1.0
        if direction != 0.0:
            theta = event_fraction(y[4], y[5], trial[4], trial[5], direction, c.half_stroke)
        if theta < 0.0:
            return trial
        if theta * dfrac > MIN_EVENT_FRACTION:
            y = rk4_step(c, drive, frac0, theta * dfrac, y, y0, direction)
            frac0 += theta * dfrac
        stop_reached = (trial[4] - direction * c.half_stroke) * direction >= 0.0 and (
            trial[5] * direction > 0.0
        )
        x, v = apply_event(y[4], y[5], direction, c.half_stroke, stop_reached)
        y = (y[0], y[1], y[2], y[3], x, v, y[6], y[7], y[8])
    # out of events: the rest of the interval with the piston held
    return rk4_step(c, drive, frac0, frac_end - frac0, y, y0, 0.0)


@njit(cache=True)
def split_substep(
    c, history, env, head_sub, h, command_a, coil_start, y0, parts, exhaust_node_pa, bristle_m
):
    """One substep from ``y0`` by the general path, in ``parts`` equal parts
    (``refinement``), each split further at piston events (``_advance_interval``).

    With LuGre friction the bristles (deflection ``bristle_m``) are advanced before each
    part, exactly for the rod's velocity at its start (``lugre_bristle_step``), and their
    mean friction is held over the part (operator splitting). Returns the state and the
    bristles' deflection.
    """
    y = y0
    for part in range(parts):
        lugre_friction_n = 0.0
        if c.lugre:
            bristle_m, lugre_friction_n = lugre_bristle_step(
                bristle_m,
                y[5],
                h / parts,
                c.lugre_stiffness,
                c.lugre_damping,
                sliding_friction(c, y[5]),
            )
        drive = SubstepDrive(
            history, env, head_sub, h, command_a, coil_start, exhaust_node_pa, lugre_friction_n
        )
        y = _advance_interval(c, drive, part / parts, (part + 1) / parts, y, y0)
    return y, bristle_m


@njit(cache=True, forceinline=True)
def _record_history(history, env, slot, x_s, p1, p2):
    """Write the delay history of ``env`` at ring-buffer slot ``slot`` (a substep boundary)."""
    history[slot, L.H_X_S, env] = x_s
    history[slot, L.H_P1, env] = p1
    history[slot, L.H_P2, env] = p2


@njit(cache=True)
def close_substep(c, history, env, slot, y, h):
    """The end of a substep of ``h`` s: the inelastic stops (``end_of_substep``) and the
    delay history at the new boundary (written at substep boundaries only, whatever the
    splitting).

    With the tubes as transmission lines, the waves the line ends send, and the lines'
    valve exhaust: solved here once per boundary, it adds to the exhaust mass by the
    trapezoid rule over the substep (the RK4 stages need only the chamber ends).
    """
    x, v = end_of_substep(y[4], y[5], c.half_stroke)
    exhaust_kg = y[6]
    if c.waves:  # the waves the line ends send at this boundary
        exhaust_kg = close_line_ends(c, history, env, slot, y, h)
    _record_history(history, env, slot, y[0], y[2], y[3])
    return (y[0], y[1], y[2], y[3], x, v, exhaust_kg, y[7], y[8])


@njit(cache=True)
def close_line_ends(c, history, env, slot, y, h):
    """The transmission lines at the substep boundary ``slot`` (state ``y``): the waves
    their four ends send and their valve exhaust, written to the history, and the
    exhaust mass (``y[6]``) with the exhaust added by the trapezoid rule over the substep
    of ``h`` s."""
    arriving = arriving_waves(c, history, env, slot, 0.0)
    end_1, end_2 = line_valve_ends(c, y[0], arriving)
    return send_line_waves(c, history, env, slot, y, h, arriving, end_1, end_2)


@njit(cache=True)
def send_line_waves(c, history, env, slot, y, h, arriving, end_1, end_2):
    """``close_line_ends`` given the waves ``arriving`` at the four line ends and the
    solved valve ends (pressure, flow into the line, exhaust flow; ``nodes._line_valve_end``)
    ``end_1``, ``end_2``: the chamber ends' flows, the waves the four ends send and the
    lines' valve exhaust, written to the history; the exhaust mass by the trapezoid rule."""
    port_1, q_1, exhaust_1 = end_1
    port_2, q_2, exhaust_2 = end_2
    flow_1, flow_2 = line_chamber_flows(c, (arriving[2], arriving[3]), y[2], y[3])
    vented = exhaust_1 + exhaust_2
    start = history[ring_slot(slot - 1, history.shape[0]), L.H_LINE_EXHAUST, env]
    history[slot, L.H_LINE_EXHAUST, env] = vented
    history[slot, L.H_WAVE_VALVE_1, env] = sent_wave(c, port_1, q_1)
    history[slot, L.H_WAVE_VALVE_2, env] = sent_wave(c, port_2, q_2)
    history[slot, L.H_WAVE_CHAMBER_1, env] = sent_wave(c, y[2], -flow_1)
    history[slot, L.H_WAVE_CHAMBER_2, env] = sent_wave(c, y[3], -flow_2)
    return y[6] + 0.5 * h * (start + vented)


@njit(cache=True)
def spool_command(play_band_a, state, env, command_a):
    """The held command as the spool sees it through its Coulomb friction's play of
    half-width ``play_band_a`` (``effects.spool_play_current``), updated in the state row
    ``spool_play_current_a``.

    The command is held over the control period, so the play moves once, at its start.
    A coil lag (``coil_time_constant_s``) then acts on the play's output.
    """
    played = spool_play_current(state[L.S_PLAY, env], command_a, play_band_a)
    state[L.S_PLAY, env] = played
    return played


@njit(cache=True)
def exhaust_node_after_substep(c, history, env, slot, y, exhaust_node_pa, h):
    """The exhaust node's pressure after a substep of ``h`` s when it has a volume V
    (``exhaust_volume_m3``; docs/effects.md): one backward-Euler step of
    dP_e/dt = (R T / V) ``_exhaust_node_balance``(P_e) with the valve's inputs at the
    boundary ``slot`` (state ``y``), solved by ``exhaust_pressure_at_valve``; stable for
    any volume, and the quasi-static node as V -> 0."""
    spool_delayed, valve_p1, valve_p2 = valve_inputs(c, history, env, slot, 0.0, y, y)
    inv_sqrt_t1, inv_sqrt_t2 = inv_sqrt_temperatures(c, y[7], y[8])
    return exhaust_pressure_at_valve(
        c,
        scalar_area(c, spool_delayed) + c.null_leak,
        scalar_area(c, -spool_delayed) + c.null_leak,
        valve_p1,
        valve_p2,
        inv_sqrt_t1,
        inv_sqrt_t2,
        c.exhaust_capacity / h,
        exhaust_node_pa,
    )


@njit(cache=True, inline="always")
def coil_at_substep_start(c, command_a, coil):
    """The (coil, force) currents a substep starts from (``coil_at``'s ``coil_start``):
    ``coil``, those at the last boundary, where a lag holds them; the command without."""
    coil_now = coil[0] if c.coil_lag else command_a
    return coil_now, coil[1] if c.coil_force_lag else coil_now


@njit(cache=True)
def advance_env(sim, env, coil_current_a):
    """Advance environment ``env`` of ``sim`` (``layout.SimArrays``) by one control period
    with the coil current ``coil_current_a`` held; write its outputs row.

    ``n_substeps`` RK4 substeps, each split into equal parts where ``refinement`` finds the
    flow stiff, and at piston events (``_advance_interval``). The delay history is written
    at the substep boundaries only, so its length does not depend on the splitting.
    """
    state, history, n_substeps = sim.state, sim.history, sim.n_substeps
    h = sim.control_dt_s / n_substeps
    c = env_constants(sim.params, env, h)
    coil_current_a = spool_command(c.spool_play_band, state, env, coil_current_a)
    n_slots = history.shape[0]
    y = (
        state[L.S_X_S, env],
        state[L.S_V_S, env],
        state[L.S_P1, env],
        state[L.S_P2, env],
        state[L.S_X, env],
        state[L.S_V, env],
        state[L.S_EXHAUST, env],
        state[L.S_T1, env],
        state[L.S_T2, env],
    )
    coil = (state[L.S_COIL, env], state[L.S_COIL_FORCE, env])
    exhaust_node_pa = state[L.S_EXHAUST_NODE, env]
    bristle_m = state[L.S_BRISTLE, env]
    for sub in range(n_substeps):
        head_sub = ring_slot(sim.head[0] + sub, n_slots)
        coil_start = coil_at_substep_start(c, coil_current_a, coil)
        y, bristle_m = split_substep(
            c,
            history,
            env,
            head_sub,
            h,
            coil_current_a,
            coil_start,
            y,
            refinement(c, y, h),
            exhaust_node_pa,
            bristle_m,
        )
        coil = coil_at(c, coil_current_a, coil_start, 1.0)
        slot = ring_slot(head_sub + 1, n_slots)
        y = close_substep(c, history, env, slot, y, h)
        if c.exhaust_vent > 0.0 and c.exhaust_capacity > 0.0:
            exhaust_node_pa = exhaust_node_after_substep(
                c, history, env, slot, y, exhaust_node_pa, h
            )
    state[L.S_EXHAUST_NODE, env] = exhaust_node_pa
    state[L.S_BRISTLE, env] = bristle_m
    _store_state(c, state, env, y, coil, sim.outputs)


# the outputs that are state rows: (outputs row, state row)
OUTPUT_STATE_ROWS = (
    (L.O_P1, L.S_P1),
    (L.O_P2, L.S_P2),
    (L.O_X, L.S_X),
    (L.O_V, L.S_V),
    (L.O_X_S, L.S_X_S),
    (L.O_EXHAUST, L.S_EXHAUST),
)


@njit(cache=True)
def _store_state(c, state, env, y, coil, outputs):
    """Write the integrated rows and the (coil, force) currents back, and the outputs row
    (Eq. 1)."""
    for row in range(N_RK):
        state[row, env] = y[row]
    state[L.S_COIL, env] = coil[0]
    state[L.S_COIL_FORCE, env] = coil[1]
    _store_outputs(c, y, env, outputs)


@njit(cache=True)
def _store_outputs(c, y, env, outputs):
    """The outputs row of ``env`` from its state rows ``y`` (the force by Eq. 1)."""
    for output_row, row in OUTPUT_STATE_ROWS:
        outputs[output_row, env] = y[row]
    f_p = pneumatic_force(y[L.S_P1], y[L.S_P2], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
    outputs[L.O_F, env] = output_force(c.mode, f_p, y[L.S_X], c.spring_k, c.spring_rest)


@njit(cache=True)
def write_outputs(params, state, envs, outputs):
    """The outputs rows of ``envs`` from their state (after a reset)."""
    for env in envs:
        _store_outputs(env_constants(params, env, 1.0), state[:, env], env, outputs)


@njit(cache=True)
def line_exhaust_at_rest(params, state, history, envs):
    """The lines' valve exhaust (kg/s) of ``envs`` in their state with the lines at rest
    (each wave the pressure of its end), written to every history slot: where the first
    substep's trapezoid (``close_substep``) starts; 0 without ``tube_waves``."""
    for env in envs:
        vented = 0.0
        if params[L.P_TUBE_WAVES, env] == 1.0:  # env_constants' waves flag, read directly
            c = env_constants(params, env, 1.0)
            p1, p2 = state[L.S_P1, env], state[L.S_P2, env]
            vented = line_flows(c, state[L.S_X_S, env], (p1, p2, p1, p2), p1, p2)[2]
        history[:, L.H_LINE_EXHAUST, env] = vented
