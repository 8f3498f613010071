"""The kernel's batch path: chunks of ``CHUNK_ENVS`` environments running the paper's model
(with the effects of ``constants.batch_lane_kind``) advance one RK4 substep at a time
in single loops over the chunk that LLVM compiles to SIMD code (``advance_chunk``); a lane
whose substep is stiff or crosses a piston event is redone by the general path, and
environments with other effects on take ``general_path.advance_env``. The step functions
(``step_serial``, ``step_parallel``, ``rollout_serial``) run the chunks of a batch.
"""

import math

import numpy as np
from numba import njit, prange

from . import layout as L
from .batch_lines import close_lines
from .batch_nodes import node_substeps
from .batch_rhs import rk4_base_substep, rk4_line_substep
from .batch_work import (
    W_COIL,
    W_COIL_START,
    W_CURRENT,
    W_DIRECTION,
    W_DRIVE,
    W_REDO,
    W_SPOOL_DELAYED,
    W_START,
    chunk_work,
    lagged_coil_rows,
    set_work_rows,
    work_rows,
)
from .constants import (
    BATCH_GENERAL,
    C_BASE_ONLY,
    C_DELAY_SUBSTEPS,
    C_SPOOL_PLAY_BAND,
    C_WAVES,
    CHUNK_ENVS,
    chunk_effects,
    load_constants,
    refresh_constants,
)
from .effects import spool_play_current
from .general_path import (
    OUTPUT_STATE_ROWS,
    STIFFNESS_LIMIT,
    advance_env,
    close_substep,
    refinement,
    split_substep,
    stiffness_ratio,
)
from .layout import SimArrays
from .piston import (
    MODE_FIXED,
    end_of_substep,
    event_fraction,
    external_force,
    motion_direction,
    output_force,
    pneumatic_force,
)
from .right_hand_side import N_RK, chamber_end_waves, ring_slot
from .vecmath import float_to_bits

# The parallel steps run inside BatchSimulator.call_step_kernel, which has the threads
# take chunks one at a time as each gets free (dynamic scheduling, numba's
# ``parallel_chunksize``) rather than split them evenly up front: a core slowed by other
# processes then takes fewer chunks instead of holding the others up at the region's end.
PARALLEL_CHUNKS_PER_HANDOUT = 1


@njit(cache=True, error_model="numpy")
def begin_substeps(constants, work, n_lanes, h):
    """Before a vectorised substep, for every lane of a chunk: keep the state at the
    substep's start, set the piston's direction over the substep (``motion_direction``;
    0 with the rod fixed), and mark the lane for the general path where ``refinement``
    would split the substep (stiff flow). A loop LLVM vectorises."""
    for j in range(n_lanes):
        c = load_constants(constants, j)
        y = work_rows(work, 0, j)
        set_work_rows(work, W_START, j, y)
        applied = pneumatic_force(
            y[2], y[3], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa
        ) - external_force(c.mode, y[4], c.load_force, c.spring_k, c.spring_rest)
        direction = motion_direction(y[4], y[5], applied, c.stick_threshold, c.half_stroke)
        work[W_DIRECTION * CHUNK_ENVS + j] = 0.0 if c.mode == MODE_FIXED else direction
        stiff = stiffness_ratio(c, y, h) > STIFFNESS_LIMIT  # refinement(c, y, h) > 1
        work[W_REDO * CHUNK_ENVS + j] = 1.0 if stiff else 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def _substeps_vectorised(constants, work, n_lanes, h, leaks, selected, four_paths, driven):
    """RK4 substep of ``batch_rhs.batch_derivatives`` for every lane of a chunk, with the
    leaks (``leaks``: orifices, laminar), the effects selected per lane (``selected``)
    and the valve's four paths (``four_paths``), the spool driven by the held command
    ``W_CURRENT`` or, ``driven``, by the currents in ``W_DRIVE`` (the coil lags'); a
    loop LLVM vectorises once the flags (constants where this is inlined) have folded
    away."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        command = work[W_CURRENT * k + j]
        drive = (command, command, command)
        if driven:
            drive = (
                work[W_DRIVE * k + j],
                work[(W_DRIVE + 1) * k + j],
                work[(W_DRIVE + 2) * k + j],
            )
        spool_delayed = (
            work[W_SPOOL_DELAYED * k + j],
            work[(W_SPOOL_DELAYED + 1) * k + j],
            work[(W_SPOOL_DELAYED + 2) * k + j],
        )
        direction = work[W_DIRECTION * k + j]
        y = work_rows(work, 0, j)
        y = rk4_base_substep(c, y, drive, direction, spool_delayed, h, leaks, selected, four_paths)
        set_work_rows(work, 0, j, y)


@njit(cache=True, error_model="numpy")
def base_substeps_vectorised(constants, work, n_lanes, h):
    """RK4 substep of ``base_derivatives`` for every lane of a chunk; a loop LLVM vectorises.

    ``error_model="numpy"`` lets a division by zero give inf instead of raising, so the
    divisions do not stop vectorisation.
    """
    _substeps_vectorised(constants, work, n_lanes, h, False, False, False, False)


@njit(cache=True, error_model="numpy")
def chunk_substeps(
    constants, work, n_lanes, h, leaks, selected, lagged, four_paths, vented, drooped
):
    """The chunk's RK4 loop: ``base_substeps_vectorised``, or with the effects its lanes
    have (flags true where any lane has them; on another lane a leak path, or a valve
    path without a null leak, is closed and adds 0.0, an effect selected per lane is not
    selected), the spool then driven by ``W_DRIVE`` (the command, or with ``lagged`` the
    coil lags' currents, ``lagged_coil_rows``), or stage by stage with a pressure node (an
    exhaust vent, ``vented``, or a supply resistance, ``drooped``:
    ``batch_nodes.node_substeps``)."""
    if vented or drooped:
        node_substeps(constants, work, n_lanes, h, leaks, selected, vented, drooped)
    elif not (leaks or selected or lagged or four_paths):
        base_substeps_vectorised(constants, work, n_lanes, h)
    elif four_paths:
        _driven_substeps(constants, work, n_lanes, h, leaks, selected, True)
    else:
        _driven_substeps(constants, work, n_lanes, h, leaks, selected, False)


@njit(cache=True, forceinline=True, error_model="numpy")
def _driven_substeps(constants, work, n_lanes, h, leaks, selected, four_paths):
    """``_substeps_vectorised`` driven by ``W_DRIVE``, the flags made constants (one
    vectorised loop per combination)."""
    if leaks and selected:
        _substeps_vectorised(constants, work, n_lanes, h, True, True, four_paths, True)
    elif leaks:
        _substeps_vectorised(constants, work, n_lanes, h, True, False, four_paths, True)
    elif selected:
        _substeps_vectorised(constants, work, n_lanes, h, False, True, four_paths, True)
    else:
        _substeps_vectorised(constants, work, n_lanes, h, False, False, four_paths, True)


@njit(cache=True, error_model="numpy")
def line_substeps(constants, work, history, first, n_lanes, head_sub, h, leaks, selected):
    """RK4 substep of the chunk's batch-path lanes with the tubes as transmission lines
    (``batch_rhs.rk4_line_substep``), from the substep's start (``W_START``), driven by
    ``W_DRIVE``; the waves arriving at their chamber ends read from the history ring lane by
    lane (``chamber_end_waves``). A scalar loop: the lines' flows take a Newton solve."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        if constants[C_BASE_ONLY * k + j] == BATCH_GENERAL or constants[C_WAVES * k + j] == 0.0:
            continue
        c = load_constants(constants, j)
        env = first + j
        drive = (work[W_DRIVE * k + j], work[(W_DRIVE + 1) * k + j], work[(W_DRIVE + 2) * k + j])
        arriving = (
            chamber_end_waves(c, history, env, head_sub, 0.0),
            chamber_end_waves(c, history, env, head_sub, 0.5),
            chamber_end_waves(c, history, env, head_sub, 1.0),
        )
        y = work_rows(work, W_START, j)
        direction = work[W_DIRECTION * k + j]
        y = rk4_line_substep(c, y, drive, direction, arriving, h, leaks, selected)
        set_work_rows(work, 0, j, y)


@njit(cache=True, error_model="numpy")
def end_substeps(constants, work, n_lanes):
    """After a vectorised substep, for every lane of a chunk: mark the lane for the general
    path where the sliding piston met an event (a stop or a velocity reversal,
    ``event_fraction``), and apply the end stops (``end_of_substep``). A loop LLVM
    vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        direction = work[W_DIRECTION * k + j]
        x0, v0 = work[(W_START + L.S_X) * k + j], work[(W_START + L.S_V) * k + j]
        x, v = work[L.S_X * k + j], work[L.S_V * k + j]
        event = direction != 0.0 and event_fraction(x0, v0, x, v, direction, c.half_stroke) >= 0.0
        work[W_REDO * k + j] = 1.0 if event else work[W_REDO * k + j]
        work[L.S_X * k + j], work[L.S_V * k + j] = end_of_substep(x, v, c.half_stroke)


@njit(cache=True, forceinline=True, error_model="numpy")
def delay_slots(head_sub, stage, delay_substeps, n_slots):
    """Where the batch path reads x_s(t - tau) at substep fraction ``stage / 2`` (0, 1/2,
    1; at or before head + 1): (query, lower slot, upper slot, weight of the upper)."""
    query = 0.5 * stage - delay_substeps
    base = math.floor(query)
    lower_slot = head_sub + int(base)  # in [-n_slots, n_slots)
    lower_slot = lower_slot + n_slots if lower_slot < 0 else lower_slot
    upper_slot = lower_slot + 1
    upper_slot = 0 if upper_slot == n_slots else upper_slot
    return query, lower_slot, upper_slot, query - base


@njit(cache=True, error_model="numpy")
def lanes_share_delay(constants, n_lanes):
    """Whether every lane of a chunk has the same tube delay (one tube length: the usual
    case), so that its delayed reads share their ring slots."""
    k = CHUNK_ENVS
    delay = constants[C_DELAY_SUBSTEPS * k]
    same = True
    for j in range(1, n_lanes):
        same &= constants[C_DELAY_SUBSTEPS * k + j] == delay
    return same


@njit(cache=True, error_model="numpy")
def interpolate_row(work, lower_row, upper_row, n_lanes, row, weight, at_start):
    """Work row ``row`` of every lane from two rows of the ring buffer, ``lower_row +
    weight * (upper_row - lower_row)``, or the substep's start (``at_start``: a delay of
    exactly one substep). A loop LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        lower = lower_row[j]
        interpolated = lower + weight * (upper_row[j] - lower)
        work[row * k + j] = work[W_START * k + j] if at_start else interpolated


@njit(cache=True, error_model="numpy")
def delayed_spool_rows(constants, work, history, first, n_lanes, head_sub, same_delay):
    """For every lane of a chunk, the delayed spool position x_s(t - tau) at the substep's
    start, middle and end (``delayed_value`` with a delay of at least one substep, as
    ``base_model_only`` requires). With ``same_delay`` (``lanes_share_delay``) the lanes read the
    same ring slots, contiguous rows (``interpolate_row``); otherwise each lane its own
    (branch-free, so no lane waits on a mispredicted branch; gathers, which LLVM keeps
    scalar)."""
    n_slots = history.shape[0]
    k = CHUNK_ENVS
    stop = first + n_lanes
    if same_delay:
        for stage in range(3):
            query, lower_slot, upper_slot, weight = delay_slots(
                head_sub, stage, constants[C_DELAY_SUBSTEPS * k], n_slots
            )
            interpolate_row(
                work,
                history[lower_slot, L.H_X_S, first:stop],
                history[upper_slot, L.H_X_S, first:stop],
                n_lanes,
                W_SPOOL_DELAYED + stage,
                weight,
                query >= 0.0,
            )
        return
    for j in range(n_lanes):
        delay_substeps = constants[C_DELAY_SUBSTEPS * k + j]
        x_s = work[W_START * k + j]
        for stage in range(3):
            query, lower_slot, upper_slot, weight = delay_slots(
                head_sub, stage, delay_substeps, n_slots
            )
            lower = history[lower_slot, L.H_X_S, first + j]
            upper = history[upper_slot, L.H_X_S, first + j]
            interpolated = lower + weight * (upper - lower)
            # a query at head + 1 (a delay of exactly one substep) is the start's own value
            work[(W_SPOOL_DELAYED + stage) * k + j] = x_s if query >= 0.0 else interpolated


@njit(cache=True, error_model="numpy", inline="always")
def _any_lane_set(work, row, n_lanes):
    """Whether any lane of work row ``row`` (0.0 or 1.0 flags) is set: an OR of their bits,
    a reduction LLVM vectorises, so the lanes are scanned one by one only when one is."""
    bits = 0
    for j in range(n_lanes):
        bits |= float_to_bits(work[row * CHUNK_ENVS + j])
    return bits != 0


@njit(cache=True, error_model="numpy")
def copy_fast_lanes(constants, work, n_lanes, work_row, target_row, keep_redone):
    """Copy row ``work_row`` of a chunk's lanes into ``target_row`` (one row of the chunk's
    state, outputs or delay history at one ring slot) for the lanes of the batch path;
    the lanes of ``advance_env`` keep theirs, and so do the lanes the general path redid
    when ``keep_redone`` (it wrote their history itself). A loop LLVM vectorises (one row
    per loop: with more rows written, it would not check their aliasing at run time)."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        # both entries loaded and bitwise logic: no branch, so no conditional load
        kept, advanced = target_row[j], work[work_row * k + j]
        keep = (constants[C_BASE_ONLY * k + j] == 0.0) | (
            keep_redone & (work[W_REDO * k + j] != 0.0)
        )
        target_row[j] = kept if keep else advanced


@njit(cache=True, error_model="numpy")
def fast_commands(constants, work, n_lanes, command_row, play_row):
    """The held command of each batch-path lane of a chunk as the spool sees it through
    its play (``spool_command``), into row ``W_CURRENT``; ``play_row`` is the chunk's
    state row ``spool_play_current_a`` (the lanes of ``advance_env`` keep theirs). A loop
    LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        held = play_row[j]
        played = spool_play_current(held, command_row[j], constants[C_SPOOL_PLAY_BAND * k + j])
        play_row[j] = held if constants[C_BASE_ONLY * k + j] == 0.0 else played
        work[W_CURRENT * k + j] = played
        # the drive without a coil lag (``chunk_substeps``)
        work[W_DRIVE * k + j] = work[(W_DRIVE + 1) * k + j] = work[(W_DRIVE + 2) * k + j] = played


@njit(cache=True, error_model="numpy")
def fast_output_forces(constants, work, n_lanes, force_row):
    """The force output (Eq. 1, ``output_force``) of each batch-path lane of a chunk into
    ``force_row`` (the chunk's outputs row ``O_F``; the lanes of ``advance_env`` keep
    theirs). A loop LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        y = work_rows(work, 0, j)
        force = output_force(
            c.mode,
            pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa),
            y[4],
            c.spring_k,
            c.spring_rest,
        )
        kept = force_row[j]
        force_row[j] = kept if constants[C_BASE_ONLY * k + j] == 0.0 else force


@njit(cache=True)
def prepare_substep(constants, work, history, first, n_lanes, head_sub, same_delay, h):
    """The inputs of a chunk's RK4 loop for the substep after ring slot ``head_sub``: the
    start state, direction and stiff lanes (``begin_substeps``), then the delayed spool
    positions (``delayed_spool_rows``)."""
    begin_substeps(constants, work, n_lanes, h)
    delayed_spool_rows(constants, work, history, first, n_lanes, head_sub, same_delay)


@njit(cache=True)
def advance_chunk(sim, first, stop, coil_current_a):
    """Advance environments ``first .. stop-1`` of ``sim`` (``layout.SimArrays``) by one
    control period with the coil currents ``coil_current_a`` (n_envs,) held; write their
    outputs.

    ``first`` is a multiple of ``CHUNK_ENVS``. Environments of ``constants.batch_lane_kind``
    ``BATCH_BASE`` or ``BATCH_LEAKS`` advance together: per substep, one vectorised loop
    keeps the start state and finds the piston's direction and the stiff lanes
    (``begin_substeps``), the delayed spool positions are read (``delayed_spool_rows``) and,
    with a coil lag in the chunk, the currents driving the spool (``lagged_coil_rows``), one
    vectorised RK4 substep (``chunk_substeps``, with the effects the chunk's lanes have:
    ``constants.chunk_effects``) advances every lane, and one
    vectorised loop finds the lanes whose piston met an event and applies the stops
    (``end_substeps``). A lane whose substep needs splitting (stiff flow, ``refinement``) or
    crosses a piston event is redone from the substep's start by the general path
    (``split_substep``). Other environments take ``advance_env``. Either way an
    environment's result does not depend on the rest of the batch.
    """
    n = stop - first
    state, history, n_substeps = sim.state, sim.history, sim.n_substeps
    h = sim.control_dt_s / n_substeps
    n_slots = history.shape[0]
    chunk_constants = sim.constants[first // CHUNK_ENVS]
    refresh_constants(sim.params, first, stop, h, sim.constants_key, chunk_constants)
    fast = chunk_constants[C_BASE_ONLY * CHUNK_ENVS :]
    for j in range(n):
        if fast[j] == BATCH_GENERAL:
            advance_env(sim, first + j, coil_current_a[first + j])
    effects = chunk_effects(chunk_constants, n)  # leaky .. drooped, lines, only lines
    # lanes advance_env advanced are computed below too, and ignored
    work = chunk_work(state, first, stop)
    fast_commands(chunk_constants, work, n, coil_current_a[first:stop], state[L.S_PLAY, first:stop])
    same_delay = lanes_share_delay(chunk_constants, n)
    for sub in range(n_substeps):
        head_sub = ring_slot(sim.head[0] + sub, n_slots)
        prepare_substep(chunk_constants, work, history, first, n, head_sub, same_delay, h)
        if effects[2]:
            lagged_coil_rows(chunk_constants, work, n)
        if not effects[7]:
            chunk_substeps(chunk_constants, work, n, h, *effects[:6])
        if effects[6]:  # the line lanes again, from the substep's start
            line_substeps(chunk_constants, work, history, first, n, head_sub, h, *effects[:2])
        end_substeps(chunk_constants, work, n)
        slot = ring_slot(head_sub + 1, n_slots)
        for row, channel in ((L.S_X_S, L.H_X_S), (L.S_P1, L.H_P1), (L.S_P2, L.H_P2)):
            copy_fast_lanes(chunk_constants, work, n, row, history[slot, channel, first:stop], True)
        if effects[6]:
            close_lines(chunk_constants, work, history, first, n, slot, h)
        if _any_lane_set(work, W_REDO, n):
            _redo_lanes(chunk_constants, work, history, first, n, head_sub, slot, h, effects[2])
    _store_fast_lanes(chunk_constants, work, state, sim.outputs, first, stop, effects[2])


@njit(cache=True)
def _redo_lanes(chunk_constants, work, history, first, n_lanes, head_sub, slot, h, lagged):
    """Redo by the general path (``split_substep``) the substep after ring slot
    ``head_sub`` of the batch-path lanes of a chunk marked in work row ``W_REDO`` (stiff,
    or a piston event), from the substep's start (its currents in ``W_COIL_START`` when
    the chunk has a coil lag, ``lagged``)."""
    fast = chunk_constants[C_BASE_ONLY * CHUNK_ENVS :]
    for j in range(n_lanes):
        if fast[j] != 0.0 and work[W_REDO * CHUNK_ENVS + j] != 0.0:
            env = first + j
            c = load_constants(chunk_constants, j)
            y0 = work_rows(work, W_START, j)
            current = work[W_CURRENT * CHUNK_ENVS + j]
            coil_start = (current, current)
            if lagged:
                coil_start = (
                    work[W_COIL_START * CHUNK_ENVS + j],
                    work[(W_COIL_START + 1) * CHUNK_ENVS + j],
                )
            y, _ = split_substep(
                c,
                history,
                env,
                head_sub,
                h,
                current,
                coil_start,
                y0,
                refinement(c, y0, h),
                c.ambient_pa,
                0.0,
            )
            set_work_rows(work, 0, j, close_substep(c, history, env, slot, y, h))


@njit(cache=True)
def _store_fast_lanes(chunk_constants, work, state, outputs, first, stop, lagged):
    """The state and outputs of the batch-path lanes of environments ``first .. stop-1``
    (one chunk) as ``general_path._store_state`` writes them; the (coil, force) currents
    are the command's without a coil lag in the chunk (``lagged``)."""
    n = stop - first
    for row in range(N_RK):
        copy_fast_lanes(chunk_constants, work, n, row, state[row, first:stop], False)
    for offset, row in enumerate((L.S_COIL, L.S_COIL_FORCE)):
        coil_row = W_COIL + offset if lagged else W_CURRENT
        copy_fast_lanes(chunk_constants, work, n, coil_row, state[row, first:stop], False)
    for output_row, row in OUTPUT_STATE_ROWS:
        copy_fast_lanes(chunk_constants, work, n, row, outputs[output_row, first:stop], False)
    fast_output_forces(chunk_constants, work, n, outputs[L.O_F, first:stop])


@njit(cache=True)
def step_serial(sim, coil_current_a):
    """Advance every environment of ``sim`` (``layout.SimArrays``, or its plain tuple, which
    Numba's dispatcher types faster) by one control period on one thread, the coil
    currents ``coil_current_a`` (n_envs,) held."""
    sim = SimArrays(*sim)
    n_envs = sim.state.shape[1]
    for first in range(0, n_envs, CHUNK_ENVS):
        advance_chunk(sim, first, min(first + CHUNK_ENVS, n_envs), coil_current_a)


@njit(cache=True, parallel=True)
def step_parallel(sim, coil_current_a):
    """As ``step_serial``, chunks in parallel (``BatchSimulator.call_step_kernel`` hands
    them out)."""
    sim = SimArrays(*sim)
    n_envs = sim.state.shape[1]
    for chunk in prange((n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS):
        first = chunk * CHUNK_ENVS
        advance_chunk(sim, first, min(first + CHUNK_ENVS, n_envs), coil_current_a)


@njit(cache=True, nogil=True)
def rollout_serial(sim, coil_current_a, outputs):
    """Run a whole open-loop current sequence ``coil_current_a[step, env]`` through ``sim``
    (as ``step_serial``) in one call; ``outputs[step, O_*, env]`` receives the outputs
    after each control period. ``sim.head`` is left where it was."""
    sim = SimArrays(*sim)
    head = sim.head[0]
    for step in range(coil_current_a.shape[0]):
        sim.head[0] = head + step * sim.n_substeps
        at_step = SimArrays(
            sim.params,
            sim.state,
            sim.history,
            sim.head,
            outputs[step],
            sim.constants_key,
            sim.constants,
            sim.control_dt_s,
            sim.n_substeps,
        )
        step_serial(at_step, coil_current_a[step])
    sim.head[0] = head


def history_slots(max_delay_s, control_dt_s, n_substeps):
    """Ring-buffer length for delays up to ``max_delay_s`` (a whole number of substeps + 2)."""
    return int(np.ceil(max_delay_s / (control_dt_s / n_substeps))) + 2
