"""The valve's pressure nodes on the batch path: the exhaust back-pressure (a vent with no
volume: ``exhaust_vent_area_m2`` > 0, ``exhaust_volume_m3`` 0) and the supply droop
(``supply_resistance_pa_s_per_kg`` > 0).

The pressure behind the valve's exhaust ports and the one at its supply port are roots the
general path solves at every RK4 stage (``nodes.exhaust_pressure_at_valve``,
``nodes.supply_pressure_at_valve``; each depends on its own paths only). A solver's loop
inside the substep's loop over lanes would keep LLVM from vectorising it, so a chunk with a
node takes each RK4 stage in three loops over its lanes instead (``node_substeps``): the
stage's state and the solvers' brackets (``_stage_bracket``), the Illinois iterations of
all lanes in lockstep (``_stage_iteration``, ``_supply_iteration``, vectorised: a lane that
has returned keeps its root, the others take the same steps in the same order as on the
general path), and the stage's slopes at the nodes' pressures (``_stage_slopes``, the
valve's four paths). Bit for bit the general path.
The first and last loops stay scalar: they read or write the slopes at rows that depend on
the stage at run time, which LLVM does not prove apart from the rows they write or read
(a stage made a compile-time constant would lift this).
"""

import numpy as np
from numba import njit

from .batch_rhs import batch_derivatives
from .batch_work import W_DIRECTION, W_DRIVE, W_SPOOL_DELAYED, set_work_rows, work_rows
from .constants import BATCH_GENERAL, C_BASE_ONLY, CHUNK_ENVS, load_constants
from .effects import drooped_supply_pressure
from .nodes import (
    SUPPLY_DROOP_MAX_ITERATIONS,
    SUPPLY_DROOP_RTOL,
    _exhaust_node_balance,
    _illinois_update,
    _supply_flow,
    supply_node_balance,
)
from .right_hand_side import N_RK, _axpy, _rk4_combine, inv_sqrt_temperatures
from .valve import orifice_area_inv_radius
from .vecmath import float_to_bits

# rows of a chunk's stage array: the stage's state, the four stages' slopes, the valve's
# two areas, and each solver's bracket, guess and whether the lane has returned (the
# exhaust node's rows, then the supply's in the same order: ``_illinois_rows``)
V_STATE = 0
V_SLOPES = N_RK  # 4 * N_RK rows
V_AREAS = 5 * N_RK  # 2 rows
V_LO, V_LO_F, V_HI, V_HI_F, V_SIDE, V_GUESS, V_DONE = range(V_AREAS + 2, V_AREAS + 9)
S_LO, S_LO_F, S_HI, S_HI_F, S_SIDE, S_GUESS, S_DONE = range(V_AREAS + 9, V_AREAS + 16)
N_NODE_ROWS = V_AREAS + 16
STAGE_FRACTIONS = (0.0, 0.5, 0.5, 1.0)  # of the substep, where each RK4 stage is taken
STAGE_INPUTS = (0, 1, 1, 2)  # the drive and delayed-spool row of each stage


@njit(cache=True, forceinline=True, error_model="numpy")
def _balance(c, pressure_pa, rows, j, inv_sqrt_t1, inv_sqrt_t2):
    """``exhaust_pressure_at_valve``'s function (no storage) at ``pressure_pa`` for lane ``j``."""
    k = CHUNK_ENVS
    p1, p2 = rows[(V_STATE + 2) * k + j], rows[(V_STATE + 3) * k + j]
    area_a, area_b = rows[V_AREAS * k + j], rows[(V_AREAS + 1) * k + j]
    balance = _exhaust_node_balance(
        c, pressure_pa, area_a, area_b, p1, p2, inv_sqrt_t1, inv_sqrt_t2
    )
    return 0.0 * (pressure_pa - c.ambient_pa) - balance


@njit(cache=True, forceinline=True, error_model="numpy")
def _supply_balance(c, pressure_pa, rows, j, inv_sqrt_t1, inv_sqrt_t2):
    """``supply_pressure_at_valve``'s function at ``pressure_pa`` for lane ``j``."""
    k = CHUNK_ENVS
    p1, p2 = rows[(V_STATE + 2) * k + j], rows[(V_STATE + 3) * k + j]
    area_a, area_b = rows[V_AREAS * k + j], rows[(V_AREAS + 1) * k + j]
    return supply_node_balance(c, pressure_pa, area_a, area_b, p1, p2, inv_sqrt_t1, inv_sqrt_t2)


@njit(cache=True, forceinline=True, error_model="numpy")
def _supply_bracket(c, rows, j, general, inv_sqrt_t1, inv_sqrt_t2):
    """The start of ``supply_pressure_at_valve`` for lane ``j``: the lanes that return before
    iterating (no resistance, no flow, a root at the bracket's low end) are done."""
    k = CHUNK_ENVS
    supply_pa, resistance = c.supply_pa, c.supply_resistance
    p1, p2 = rows[(V_STATE + 2) * k + j], rows[(V_STATE + 3) * k + j]
    area_a, area_b = rows[V_AREAS * k + j], rows[(V_AREAS + 1) * k + j]
    flow_at_supply = _supply_flow(c, supply_pa, area_a, area_b, p1, p2, inv_sqrt_t1, inv_sqrt_t2)
    hi = supply_pa
    f_hi = resistance * flow_at_supply
    lo = max(supply_pa - f_hi, min(p1, p2))
    f_lo = _supply_balance(c, lo, rows, j, inv_sqrt_t1, inv_sqrt_t2)
    no_droop = (resistance <= 0.0) | general | (flow_at_supply <= 0.0)
    guess = drooped_supply_pressure(supply_pa, flow_at_supply, resistance)
    guess = lo if f_lo >= 0.0 else guess
    rows[S_GUESS * k + j] = supply_pa if no_droop else guess
    rows[S_DONE * k + j] = 1.0 if no_droop | (f_lo >= 0.0) else 0.0
    rows[S_LO * k + j], rows[S_LO_F * k + j] = lo, f_lo
    rows[S_HI * k + j], rows[S_HI_F * k + j] = hi, f_hi
    rows[S_SIDE * k + j] = 0.0


@njit(cache=True, error_model="numpy")
def _stage_bracket(constants, work, rows, n_lanes, h, stage, vented, drooped):
    """The state of RK4 stage ``stage`` of every lane, the valve's areas, and the start of
    ``exhaust_pressure_at_valve`` (the lanes that return before iterating: no vent, both
    paths closed, a root at an end of the bracket, are done) and ``_supply_bracket``; in a
    chunk with no vent (``vented`` false) or no supply resistance (``drooped``) every lane
    is done at P_a or P_s there."""
    k = CHUNK_ENVS
    step = 0.5 * h if stage < 3 else h
    for j in range(n_lanes):
        c = load_constants(constants, j)
        y = work_rows(work, 0, j)
        if stage > 0:
            y = _axpy(y, step, work_rows(rows, V_SLOPES + (stage - 1) * N_RK, j))
        set_work_rows(rows, V_STATE, j, y)
        spool = work[(W_SPOOL_DELAYED + STAGE_INPUTS[stage]) * k + j]
        radius, inv_radius = c.hole_radius, c.inv_hole_radius
        area_a = orifice_area_inv_radius(spool, radius, inv_radius, c.half_width, c.holes)
        area_b = orifice_area_inv_radius(-spool, radius, inv_radius, c.half_width, c.holes)
        area_a = area_a + c.null_leak
        area_b = area_b + c.null_leak
        rows[V_AREAS * k + j], rows[(V_AREAS + 1) * k + j] = area_a, area_b
        inv_sqrt_t1, inv_sqrt_t2 = inv_sqrt_temperatures(c, y[7], y[8])
        general = constants[C_BASE_ONLY * k + j] == BATCH_GENERAL  # computed, ignored
        rows[S_GUESS * k + j], rows[S_DONE * k + j] = c.supply_pa, 1.0
        if drooped:
            _supply_bracket(c, rows, j, general, inv_sqrt_t1, inv_sqrt_t2)
        rows[V_GUESS * k + j], rows[V_DONE * k + j] = c.ambient_pa, 1.0
        if not vented:
            continue
        lo = min(c.ambient_pa, y[2], y[3])
        hi = max(c.ambient_pa, y[2], y[3])
        lo_f = _balance(c, lo, rows, j, inv_sqrt_t1, inv_sqrt_t2)
        hi_f = _balance(c, hi, rows, j, inv_sqrt_t1, inv_sqrt_t2)
        closed = (c.exhaust_vent == 0.0) | general | ((area_a <= 0.0) & (area_b <= 0.0))
        guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
        guess = hi if hi_f <= 0.0 else guess
        guess = lo if lo_f >= 0.0 else guess
        rows[V_GUESS * k + j] = c.ambient_pa if closed else guess
        done = closed | (lo_f >= 0.0) | (hi_f <= 0.0)
        rows[V_DONE * k + j] = 1.0 if done else 0.0
        rows[V_LO * k + j], rows[V_LO_F * k + j] = lo, lo_f
        rows[V_HI * k + j], rows[V_HI_F * k + j] = hi, hi_f
        rows[V_SIDE * k + j] = 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def _lane_and_temperatures(constants, rows, j):
    """Lane ``j``'s constants and 1/sqrt(T) of its chambers at the stage's state."""
    c = load_constants(constants, j)
    y7, y8 = rows[(V_STATE + 7) * CHUNK_ENVS + j], rows[(V_STATE + 8) * CHUNK_ENVS + j]
    inv_sqrt_t1, inv_sqrt_t2 = inv_sqrt_temperatures(c, y7, y8)
    return c, inv_sqrt_t1, inv_sqrt_t2


@njit(cache=True, forceinline=True, error_model="numpy")
def _illinois_rows(rows, j, lo_row, guess, f_guess, kept):
    """One Illinois step (``nodes._illinois_update``) of lane ``j`` on a solver's rows
    (``lo_row`` .. ``lo_row + 5``: lo, f(lo), hi, f(hi), the side replaced last, the
    guess), with f(guess) ``f_guess``; where ``kept`` the rows stay. Every row is loaded up
    front and selected below: no conditional load or store. Returns the next guess."""
    k = CHUNK_ENVS
    bracket = (
        rows[lo_row * k + j],
        rows[(lo_row + 1) * k + j],
        rows[(lo_row + 2) * k + j],
        rows[(lo_row + 3) * k + j],
        rows[(lo_row + 4) * k + j],  # 0.0, 1.0 or -1.0
    )
    lo, lo_f, hi, hi_f, side = _illinois_update(
        bracket[0], bracket[1], bracket[2], bracket[3], guess, f_guess, bracket[4]
    )
    new_guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
    rows[lo_row * k + j] = bracket[0] if kept else lo
    rows[(lo_row + 1) * k + j] = bracket[1] if kept else lo_f
    rows[(lo_row + 2) * k + j] = bracket[2] if kept else hi
    rows[(lo_row + 3) * k + j] = bracket[3] if kept else hi_f
    rows[(lo_row + 4) * k + j] = bracket[4] if kept else float(side)
    rows[(lo_row + 5) * k + j] = guess if kept else new_guess
    return new_guess


@njit(cache=True, error_model="numpy")
def _stage_iteration(constants, rows, n_lanes):
    """One Illinois step of ``exhaust_pressure_at_valve`` on every lane not done (the
    others keep their rows)."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c, inv_sqrt_t1, inv_sqrt_t2 = _lane_and_temperatures(constants, rows, j)
        guess = rows[V_GUESS * k + j]
        f_guess = _balance(c, guess, rows, j, inv_sqrt_t1, inv_sqrt_t2)
        kept = (rows[V_DONE * k + j] != 0.0) | (f_guess == 0.0)
        new_guess = _illinois_rows(rows, j, V_LO, guess, f_guess, kept)
        done = kept | (abs(new_guess - guess) <= SUPPLY_DROOP_RTOL * c.supply_pa)
        rows[V_DONE * k + j] = 1.0 if done else 0.0


@njit(cache=True, error_model="numpy")
def _supply_iteration(constants, rows, n_lanes):
    """One Illinois step of ``supply_pressure_at_valve`` on every lane not done (the
    others keep their rows): it returns its guess once the function is within the
    tolerance there."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c, inv_sqrt_t1, inv_sqrt_t2 = _lane_and_temperatures(constants, rows, j)
        guess = rows[S_GUESS * k + j]
        f_guess = _supply_balance(c, guess, rows, j, inv_sqrt_t1, inv_sqrt_t2)
        kept = (rows[S_DONE * k + j] != 0.0) | (abs(f_guess) <= SUPPLY_DROOP_RTOL * c.supply_pa)
        _illinois_rows(rows, j, S_LO, guess, f_guess, kept)
        rows[S_DONE * k + j] = 1.0 if kept else 0.0


@njit(cache=True, error_model="numpy")
def _any_lane_open(rows, n_lanes, done_row):
    """Whether any lane is still iterating on the solver whose done row is ``done_row``: an
    OR of the bits of (done - 1), 0.0 where done, a reduction LLVM vectorises (in the
    iteration's loop it would stop its vectorisation)."""
    bits = 0
    for j in range(n_lanes):
        bits |= float_to_bits(rows[done_row * CHUNK_ENVS + j] - 1.0)
    return bits != 0


@njit(cache=True, error_model="numpy")
def _stage_slopes(constants, work, rows, n_lanes, stage, leaks, selected):
    """The slopes of RK4 stage ``stage`` of every lane (``batch_derivatives`` with the four
    valve paths, the supply and the exhaust at their nodes' pressures), into their rows."""
    k = CHUNK_ENVS
    inputs = STAGE_INPUTS[stage]
    for j in range(n_lanes):
        c = load_constants(constants, j)
        slopes = batch_derivatives(
            c,
            work[(W_DRIVE + inputs) * k + j],
            work_rows(rows, V_STATE, j),
            work[W_DIRECTION * k + j],
            work[(W_SPOOL_DELAYED + inputs) * k + j],
            leaks,
            selected,
            True,
            rows[S_GUESS * k + j],
            rows[V_GUESS * k + j],
        )
        set_work_rows(rows, V_SLOPES + stage * N_RK, j, slopes)


@njit(cache=True, error_model="numpy")
def node_substeps(constants, work, n_lanes, h, leaks, selected, vented, drooped):
    """The RK4 substep of a chunk with an exhaust vent (``vented``) or a supply resistance
    (``drooped``) (``batch_path.chunk_substeps``; the spool driven by ``W_DRIVE``), stage by
    stage; the lanes' states in work rows 0 ..."""
    k = CHUNK_ENVS
    rows = np.zeros(N_NODE_ROWS * k)
    for stage in range(4):
        _stage_bracket(constants, work, rows, n_lanes, h, stage, vented, drooped)
        for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
            if not _any_lane_open(rows, n_lanes, V_DONE):
                break
            _stage_iteration(constants, rows, n_lanes)
        for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
            if not _any_lane_open(rows, n_lanes, S_DONE):
                break
            _supply_iteration(constants, rows, n_lanes)
        if leaks and selected:
            _stage_slopes(constants, work, rows, n_lanes, stage, True, True)
        elif leaks:
            _stage_slopes(constants, work, rows, n_lanes, stage, True, False)
        elif selected:
            _stage_slopes(constants, work, rows, n_lanes, stage, False, True)
        else:
            _stage_slopes(constants, work, rows, n_lanes, stage, False, False)
    for j in range(n_lanes):
        c = load_constants(constants, j)
        k1 = work_rows(rows, V_SLOPES, j)
        k2 = work_rows(rows, V_SLOPES + N_RK, j)
        k3 = work_rows(rows, V_SLOPES + 2 * N_RK, j)
        k4 = work_rows(rows, V_SLOPES + 3 * N_RK, j)
        y = _rk4_combine(c, work_rows(work, 0, j), k1, k2, k3, k4, h, work[W_DIRECTION * k + j])
        set_work_rows(work, 0, j, y)
