"""The integrator kernel: advances a batch of actuators by one control period.

Each environment is advanced through ``n_substeps`` classical Runge-Kutta (RK4) substeps
with the coil current held (zero-order hold). The tube delay reads a per-environment ring
buffer holding the spool position and chamber pressures at substep boundaries (and, with
the tubes as transmission lines, ``tube_waves``, the waves each tube end sends); delayed
values between boundaries are interpolated linearly. Piston friction and end stops are
handled between substeps (``piston.motion_direction`` / ``piston.end_of_substep``), so
each RK4 substep integrates a smooth right-hand side.

The effects beyond the paper's model (docs/effects.md, ``effects.py``) are switched per
environment by their parameter rows; ``env_constants`` turns each into a flag or a
neutral constant once per control period, so an effect that is off costs a branch.

Two paths share the sub-models. The batch path (``advance_chunk``, used by every step
function) advances chunks of ``CHUNK_ENVS`` environments running the paper's model one
RK4 substep at a time in a single loop over the chunk that LLVM compiles to SIMD code
(``base_derivatives``, branch-free, ``vecmath``), and so those with the effects it adds on
(``constants.batch_lane_kind``: leaks, coil lags, valve null leak, exhaust back-pressure,
supply droop, energy equation, tube air, ISO flow law; ``batch_derivatives``,
``batch_nodes``), and the transmission lines (their RK4 lane by lane, ``line_substeps``;
their valve ends at the substep boundaries in lockstep, ``batch_lines``). The
general path (``advance_env``, one environment through the whole control period,
``derivatives``) takes environments with other effects on, and redoes a lane's substep
that is stiff or crosses a piston event. Both give the same numbers bit for bit
(tests/test_physics.py, tests/test_batch_effects.py).

This module gathers the kernel's names from its seven parts:

=========================  =============================================================
``constants``              ``Constants``, ``env_constants`` and the batch path's cache
``nodes``                  algebraic nodes: valve-chamber flows, supply droop, exhaust
                           node, the valve ends of the transmission lines
``right_hand_side``        ``derivatives``, the delayed reads, RK4
``batch_rhs``              ``base_derivatives``, ``batch_derivatives``: the batch path's
                           right-hand side, its RK4 substep
``general_path``           ``advance_env``: refinement, piston events, outputs
``batch_path``             ``advance_chunk`` (SIMD chunks), the step functions
``batch_work``             the batch path's work rows, the coil lags' stage currents
=========================  =============================================================
"""

from .batch_path import (
    PARALLEL_CHUNKS_PER_HANDOUT,
    advance_chunk,
    history_slots,
    prepare_substep,
    rollout_serial,
    step_parallel,
    step_serial,
)
from .batch_rhs import base_derivatives, batch_derivatives, rk4_base_substep
from .batch_work import (
    N_WORK,
    W_CURRENT,
    W_DIRECTION,
    W_REDO,
    W_SPOOL_DELAYED,
    W_START,
    chunk_work,
)
from .constants import (
    BATCH_BASE,
    BATCH_GENERAL,
    BATCH_LEAKS,
    C_BASE_ONLY,
    C_DELAY_SUBSTEPS,
    C_SPOOL_PLAY_BAND,
    CHUNK_ENVS,
    N_CACHED_CONSTANTS,
    N_CONSTANTS,
    PRESSURE_FLOOR_FRACTION,
    TEMPERATURE_FLOOR_FRACTION,
    Constants,
    base_model_only,
    batch_lane_kind,
    constants_cache,
    env_constants,
    load_constants,
    refresh_constants,
    store_constants,
)
from .general_path import (
    LUGRE_COUPLING_LIMIT,
    MAX_EVENTS_PER_SUBSTEP,
    MAX_REFINEMENT,
    MIN_EVENT_FRACTION,
    OUTPUT_STATE_ROWS,
    STIFFNESS_LIMIT,
    advance_env,
    exhaust_node_after_substep,
    line_exhaust_at_rest,
    refinement,
    spool_command,
    stiffness_ratio,
    write_outputs,
)
from .nodes import (
    LINE_PRESSURE_RTOL,
    SUPPLY_DROOP_MAX_ITERATIONS,
    SUPPLY_DROOP_RTOL,
    exhaust_pressure_at_valve,
    line_flows,
    supply_pressure_at_valve,
    valve_chamber_flows,
)
from .right_hand_side import (
    N_RK,
    delayed_value,
    derivatives,
    ring_slot,
)

__all__ = [
    # constants
    "Constants",
    "env_constants",
    "base_model_only",
    "batch_lane_kind",
    "BATCH_GENERAL",
    "BATCH_BASE",
    "BATCH_LEAKS",
    "CHUNK_ENVS",
    "N_CONSTANTS",
    "N_CACHED_CONSTANTS",
    "C_BASE_ONLY",
    "C_SPOOL_PLAY_BAND",
    "C_DELAY_SUBSTEPS",
    "PRESSURE_FLOOR_FRACTION",
    "TEMPERATURE_FLOOR_FRACTION",
    "constants_cache",
    "refresh_constants",
    "store_constants",
    "load_constants",
    # algebraic nodes
    "valve_chamber_flows",
    "supply_pressure_at_valve",
    "exhaust_pressure_at_valve",
    "line_flows",
    "SUPPLY_DROOP_RTOL",
    "SUPPLY_DROOP_MAX_ITERATIONS",
    "LINE_PRESSURE_RTOL",
    # right-hand side
    "N_RK",
    "derivatives",
    "base_derivatives",
    "batch_derivatives",
    "delayed_value",
    "ring_slot",
    "rk4_base_substep",
    # general path
    "advance_env",
    "refinement",
    "stiffness_ratio",
    "spool_command",
    "exhaust_node_after_substep",
    "line_exhaust_at_rest",
    "write_outputs",
    "OUTPUT_STATE_ROWS",
    "STIFFNESS_LIMIT",
    "MAX_EVENTS_PER_SUBSTEP",
    "MIN_EVENT_FRACTION",
    "LUGRE_COUPLING_LIMIT",
    "MAX_REFINEMENT",
    # batch path
    "advance_chunk",
    "step_serial",
    "step_parallel",
    "rollout_serial",
    "history_slots",
    "chunk_work",
    "prepare_substep",
    "PARALLEL_CHUNKS_PER_HANDOUT",
    "N_WORK",
    "W_START",
    "W_SPOOL_DELAYED",
    "W_CURRENT",
    "W_DIRECTION",
    "W_REDO",
]
