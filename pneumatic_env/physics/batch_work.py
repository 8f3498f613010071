"""The batch path's work array (``batch_path.advance_chunk``): its rows, their state
tuples, and the currents of the coil lags at each RK4 stage (``lagged_coil_rows``)."""

import numpy as np
from numba import njit

from . import layout as L
from .constants import CHUNK_ENVS, load_constants
from .general_path import coil_at_substep_start
from .right_hand_side import N_RK, coil_at

# Rows of the batch path's work array, a flat array of N_WORK rows of CHUNK_ENVS lanes: the
# RK4 state rows, the state at the substep's start, the inputs of one substep and the
# lanes the general path redoes. The vectorised loops update the rows in place. Rows are
# CHUNK_ENVS apart, a compile-time constant, so LLVM can prove the lanes independent (with
# run-time row strides it gives up on the aliasing checks).
W_START = N_RK  # the RK4 state at the substep's start: N_RK rows
W_SPOOL_DELAYED = 2 * N_RK  # x_s(t - tau) at the substep's start, middle and end: 3 rows
W_CURRENT = W_SPOOL_DELAYED + 3
W_DIRECTION = W_CURRENT + 1
W_REDO = W_DIRECTION + 1  # 1.0 where the general path redoes the substep (stiff, or an event)
# with a coil lag in the chunk (``lagged_coil_rows``): the (coil, force) currents at the last
# boundary, those the substep starts from, and the force current driving the spool at its
# start, middle and end
W_COIL = W_REDO + 1  # 2 rows
W_COIL_START = W_COIL + 2  # 2 rows
W_DRIVE = W_COIL_START + 2  # 3 rows
N_WORK = W_DRIVE + 3


@njit(cache=True, forceinline=True, error_model="numpy")
def work_rows(work, first_row, j):
    """The RK4 state tuple in rows ``first_row ..`` of lane ``j`` of the flat work array."""
    i = first_row * CHUNK_ENVS + j
    k = CHUNK_ENVS
    return (
        work[i],
        work[i + k],
        work[i + 2 * k],
        work[i + 3 * k],
        work[i + 4 * k],
        work[i + 5 * k],
        work[i + 6 * k],
        work[i + 7 * k],
        work[i + 8 * k],
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def set_work_rows(work, first_row, j, y):
    """Store the state tuple ``y`` in rows ``first_row ..`` of lane ``j`` (row by row: a
    run-time tuple index would not vectorise)."""
    i = first_row * CHUNK_ENVS + j
    k = CHUNK_ENVS
    work[i], work[i + k], work[i + 2 * k] = y[0], y[1], y[2]
    work[i + 3 * k], work[i + 4 * k], work[i + 5 * k] = y[3], y[4], y[5]
    work[i + 6 * k], work[i + 7 * k], work[i + 8 * k] = y[6], y[7], y[8]


@njit(cache=True)
def chunk_work(state, first, stop):
    """A new work array for environments ``first .. stop-1`` (one chunk): their RK4 state
    rows and (coil, force) currents, the other rows zero."""
    work = np.zeros(N_WORK * CHUNK_ENVS)
    n = stop - first
    for row in range(N_RK):
        work[row * CHUNK_ENVS : row * CHUNK_ENVS + n] = state[row, first:stop]
    for row, state_row in ((W_COIL, L.S_COIL), (W_COIL + 1, L.S_COIL_FORCE)):
        work[row * CHUNK_ENVS : row * CHUNK_ENVS + n] = state[state_row, first:stop]
    return work


@njit(cache=True)
def lagged_coil_rows(constants, work, n_lanes):
    """Before a substep of a chunk with a coil lag, for every lane: the (coil, force)
    currents it starts from (``coil_at_substep_start``, into ``W_COIL_START``), the force
    current driving the spool at its start, middle and end (``coil_at``, ``W_DRIVE``) and
    the currents at its end (``W_COIL``), from the held command ``W_CURRENT``; on a lane
    without a lag, the command."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        command = work[W_CURRENT * k + j]
        start = coil_at_substep_start(
            c, command, (work[W_COIL * k + j], work[(W_COIL + 1) * k + j])
        )
        work[W_COIL_START * k + j], work[(W_COIL_START + 1) * k + j] = start
        for stage in range(3):
            work[(W_DRIVE + stage) * k + j] = coil_at(c, command, start, 0.5 * stage)[1]
        work[W_COIL * k + j], work[(W_COIL + 1) * k + j] = coil_at(c, command, start, 1.0)
