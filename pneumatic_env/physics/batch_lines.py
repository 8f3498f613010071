"""The transmission lines' valve ends on the batch path (``tube_waves``): their pressures
solved at a substep boundary in lockstep across a chunk's lanes.

At each substep boundary a line's valve-end pressure is the root of
``nodes._line_valve_end``'s function (an Illinois solve; twice per lane, one per line).
Lane by lane that solve was most of the line's cost (docs/identification.md). Here
``close_lines`` takes it in loops over the lanes: the waves and the valve's areas
(``_gather``, scalar: the history ring), the first guess, its bracket and the lanes done
at once (``_start``, vectorised), the Illinois steps of every lane still open in
lockstep (``_iteration``, vectorised: a lane done keeps its rows, the others take the
same steps in the same order as ``_line_valve_end``), then the chamber ends, the waves
sent and the exhaust (``general_path.send_line_waves``, scalar). Bit for bit the general
path's ``close_line_ends``.
"""

import numpy as np
from numba import njit

from . import layout as L
from .batch_nodes import _any_lane_open
from .batch_work import W_REDO, work_rows
from .constants import BATCH_GENERAL, C_BASE_ONLY, C_WAVES, CHUNK_ENVS, load_constants
from .general_path import send_line_waves
from .nodes import (
    LINE_PRESSURE_RTOL,
    SUPPLY_DROOP_MAX_ITERATIONS,
    _illinois_update,
    _line_valve_end_residual,
    line_valve_areas,
)
from .right_hand_side import arriving_waves

# rows of a chunk's valve-end array: the four arriving waves (valve end 1's and 2's
# first), then per valve end a block: its supply and exhaust areas, the bracket (lo, f(lo),
# hi, f(hi), the side replaced last), the result (pressure, flow into the line, exhaust
# flow) and whether the lane is done
R_WAVES = 0
E_SUPPLY, E_EXHAUST, E_LO, E_F_LO, E_HI, E_F_HI, E_SIDE = range(7)
E_PORT, E_Q, E_EXHAUST_FLOW, E_DONE = range(7, 11)
N_END = 11
R_END = 4
N_ROWS = R_END + 2 * N_END


@njit(cache=True, forceinline=True)
def _closing(constants, work, j):
    """Whether lane ``j`` is a batch-path line lane this boundary closes (not redone by
    the general path, which closes it itself)."""
    k = CHUNK_ENVS
    return (
        constants[C_BASE_ONLY * k + j] != BATCH_GENERAL
        and constants[C_WAVES * k + j] != 0.0
        and work[W_REDO * k + j] == 0.0
    )


@njit(cache=True, error_model="numpy")
def _gather(constants, work, history, first, n_lanes, slot, rows):
    """The waves arriving at each closing lane's four line ends and each valve end's
    inputs, into their rows; every other lane is marked done for both valve ends."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        if not _closing(constants, work, j):
            rows[(R_END + E_DONE) * k + j] = 1.0
            rows[(R_END + N_END + E_DONE) * k + j] = 1.0
            continue
        c = load_constants(constants, j)
        arriving = arriving_waves(c, history, first + j, slot, 0.0)
        for i in range(4):
            rows[(R_WAVES + i) * k + j] = arriving[i]
        area_a, area_b = line_valve_areas(c, work_rows(work, 0, j)[0])
        for block, supply, exhaust in ((R_END, area_a, area_b), (R_END + N_END, area_b, area_a)):
            rows[(block + E_SUPPLY) * k + j] = supply
            rows[(block + E_EXHAUST) * k + j] = exhaust
            rows[(block + E_DONE) * k + j] = 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def _start(constants, rows, n_lanes, block, wave_row):
    """``_line_valve_end`` up to its Illinois loop on every lane of the valve end whose
    rows start at ``block`` (its arriving wave in row ``wave_row``): the closed valve, the
    first guess and the bracket's far end; a lane done there gets its result."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        supply = rows[(block + E_SUPPLY) * k + j]
        exhaust = rows[(block + E_EXHAUST) * k + j]
        wave = rows[wave_row * k + j]
        skipped = rows[(block + E_DONE) * k + j] != 0.0
        closed = supply <= 0.0 and exhaust <= 0.0
        tolerance = LINE_PRESSURE_RTOL * c.supply_pa
        lo = max(min(c.ambient_pa, wave), c.pressure_floor)
        hi = max(c.supply_pa, wave)
        f_in = _line_valve_end_residual(c, supply, exhaust, wave, wave)[0]
        port = min(max(wave - f_in, lo), hi)
        f, q, exhaust_flow = _line_valve_end_residual(c, supply, exhaust, wave, port)
        first_done = abs(f) <= tolerance
        positive = f > 0.0
        far = lo if positive else hi
        f_far, q_far, exhaust_far = _line_valve_end_residual(c, supply, exhaust, wave, far)
        at_floor = positive and f_far >= 0.0
        rows[(block + E_LO) * k + j] = lo if positive else port
        rows[(block + E_F_LO) * k + j] = f_far if positive else f
        rows[(block + E_HI) * k + j] = port if positive else hi
        rows[(block + E_F_HI) * k + j] = f if positive else f_far
        rows[(block + E_SIDE) * k + j] = 0.0
        rows[(block + E_PORT) * k + j] = wave if closed else (port if first_done else lo)
        rows[(block + E_Q) * k + j] = 0.0 if closed else (q if first_done else q_far)
        rows[(block + E_EXHAUST_FLOW) * k + j] = (
            0.0 if closed else (exhaust_flow if first_done else exhaust_far)
        )
        done = skipped or closed or first_done or at_floor
        rows[(block + E_DONE) * k + j] = 1.0 if done else 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def _iteration(constants, rows, n_lanes, block, wave_row):
    """One Illinois step of ``_line_valve_end`` on every lane of the valve end at
    ``block`` not done (the others keep their rows): the new point, its result, and the
    bracket updated unless it stops there."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        done = rows[(block + E_DONE) * k + j] != 0.0
        lo, f_lo = rows[(block + E_LO) * k + j], rows[(block + E_F_LO) * k + j]
        hi, f_hi = rows[(block + E_HI) * k + j], rows[(block + E_F_HI) * k + j]
        side = rows[(block + E_SIDE) * k + j]
        supply = rows[(block + E_SUPPLY) * k + j]
        exhaust = rows[(block + E_EXHAUST) * k + j]
        wave = rows[wave_row * k + j]
        port = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        f, q, exhaust_flow = _line_valve_end_residual(c, supply, exhaust, wave, port)
        tolerance = LINE_PRESSURE_RTOL * c.supply_pa
        stop = abs(f) <= tolerance or hi - lo <= tolerance
        new = _illinois_update(lo, f_lo, hi, f_hi, port, f, side)
        kept = done or stop
        rows[(block + E_LO) * k + j] = lo if kept else new[0]
        rows[(block + E_F_LO) * k + j] = f_lo if kept else new[1]
        rows[(block + E_HI) * k + j] = hi if kept else new[2]
        rows[(block + E_F_HI) * k + j] = f_hi if kept else new[3]
        rows[(block + E_SIDE) * k + j] = side if kept else float(new[4])
        rows[(block + E_PORT) * k + j] = rows[(block + E_PORT) * k + j] if done else port
        rows[(block + E_Q) * k + j] = rows[(block + E_Q) * k + j] if done else q
        rows[(block + E_EXHAUST_FLOW) * k + j] = (
            rows[(block + E_EXHAUST_FLOW) * k + j] if done else exhaust_flow
        )
        rows[(block + E_DONE) * k + j] = 1.0 if kept else 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def _solve(constants, rows, n_lanes, block, wave_row):
    """The valve end at ``block`` (its arriving wave in row ``wave_row``) on every lane:
    its start, then lockstep Illinois steps while a lane is open (at most
    ``_line_valve_end``'s count)."""
    _start(constants, rows, n_lanes, block, wave_row)
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        if not _any_lane_open(rows, n_lanes, block + E_DONE):
            break
        _iteration(constants, rows, n_lanes, block, wave_row)


@njit(cache=True, forceinline=True)
def _end(rows, block, j):
    k = CHUNK_ENVS
    return (
        rows[(block + E_PORT) * k + j],
        rows[(block + E_Q) * k + j],
        rows[(block + E_EXHAUST_FLOW) * k + j],
    )


@njit(cache=True)
def close_lines(constants, work, history, first, n_lanes, slot, h):
    """``general_path.close_line_ends`` for the chunk's batch-path lanes with transmission
    lines that the general path does not redo: the waves their ends send at boundary
    ``slot`` and their exhaust mass (work row ``S_EXHAUST``), the valve ends solved in
    lockstep."""
    k = CHUNK_ENVS
    rows = np.zeros(N_ROWS * k)
    _gather(constants, work, history, first, n_lanes, slot, rows)
    _solve(constants, rows, n_lanes, R_END, R_WAVES)
    _solve(constants, rows, n_lanes, R_END + N_END, R_WAVES + 1)
    for j in range(n_lanes):
        if not _closing(constants, work, j):
            continue
        c = load_constants(constants, j)
        arriving = (
            rows[R_WAVES * k + j],
            rows[(R_WAVES + 1) * k + j],
            rows[(R_WAVES + 2) * k + j],
            rows[(R_WAVES + 3) * k + j],
        )
        end_1, end_2 = _end(rows, R_END, j), _end(rows, R_END + N_END, j)
        y = work_rows(work, 0, j)
        work[L.S_EXHAUST * k + j] = send_line_waves(
            c, history, first + j, slot, y, h, arriving, end_1, end_2
        )
