"""Array layout of the physics core: parameter rows, state rows, history channels.

The kernel works on struct-of-arrays with the environments innermost:
``params[P_*, n_envs]``, ``state[S_*, n_envs]`` and the tube-delay ring buffer
``history[slot, H_*, n_envs]``: the batch path writes one slot of a chunk's lanes at every
substep boundary and reads the lanes' delayed slots, which lie side by side for equal
delays. Row indices are module-level integer constants so
Numba compiles them as literals. ``PARAMETER_NAMES`` is the single list that the YAML
configs (``configs/``), the loader and the kernel agree on; every name carries its unit.

A physical effect that the paper's model lacks is a sub-model with its own parameter
rows whose neutral value switches it off (a zero area, a zero time constant, ...), so
one parameter set can switch an effect on for some environments of a batch and not
for others without recompiling the kernel.

``SimArrays`` bundles a batch's arrays and step settings as the step functions take them.
"""

from typing import NamedTuple

import numpy as np

PARAMETER_NAMES = (
    # air and thermodynamics (Sec. 2.2, Eq. 14, Eq. 40)
    "gas_constant_j_per_kg_k",
    "heat_capacity_ratio",
    "temperature_k",
    "ambient_pressure_pa",
    "supply_pressure_pa",
    "air_viscosity_pa_s",
    "alpha_in",
    "alpha_out",
    "alpha_motion",
    # valve spool (Eq. 38) and orifice (Eqs. 39, 44, 45)
    "spool_mass_kg",
    "spool_damping_n_s_per_m",
    "spool_spring_n_per_m",
    "coil_force_n_per_a",
    "coil_current_max_a",
    "discharge_coefficient",
    "hole_radius_m",
    "spool_half_width_m",
    "holes_per_path",
    # tube (Eqs. 30, 31, 33, 35)
    "tube_length_m",
    "tube_inner_diameter_m",
    "reynolds_turbulent",
    "tube_coupling",  # 0: command delay (default), 1: literal Eq. 55
    # cylinder (Eqs. 1, 15)
    "bore_diameter_m",
    "rod_diameter_m",
    "stroke_m",
    "dead_volume_cap_m3",
    "dead_volume_rod_m3",
    "piston_mass_kg",
    "static_friction_n",
    "dynamic_friction_n",
    "viscous_friction_n_s_per_m",
    "leakage_area_m2",
    # load (Eq. 1) and rod mode
    "piston_mode",  # 0: fixed (rod clamped to a load cell), 1: free, 2: spring
    "fixed_position_m",
    "load_mass_kg",
    "load_force_n",
    "spring_stiffness_n_per_m",
    "spring_rest_position_m",
    # numerics
    "flow_linear_ratio",  # pressure ratio above which the flow function is linearised
    # effects beyond the paper's model (docs/effects.md, physics/effects.py); each is off
    # at its neutral value (configs/effects.yaml)
    "tube_volume_fraction",  # 0: tube air not counted; 1: whole tube added to V0i
    "rod_seal_leak_area_m2",  # orifice chamber 2 <-> ambient
    "valve_null_leak_area_m2",  # added to every valve path's area
    "exhaust_discharge_ratio",  # C_f of the exhaust paths / C_f (1: same)
    "flow_law",  # 0: paper Eq. 52, 1: ISO 6358 (elliptic, critical ratio b)
    "iso_critical_ratio_b",
    "supply_resistance_pa_s_per_kg",  # supply droop P_s - R_sup mdot_supply
    "coil_time_constant_s",  # total coil lag T = tau_c + tau_f (one lag of T at shape 0)
    "coil_lag_shape",  # tau_c tau_f / T^2 in [0, 1/4]: 0 one lag, 1/4 two equal lags
    "wall_heat_transfer_w_per_k",  # lumped hA per chamber; > 0 switches the energy model on
    "stribeck_velocity_m_per_s",  # Stribeck velocity of the sliding friction
    "spool_coulomb_friction_n",  # spool friction: a play (hysteresis) of the spool's current
    "tube_waves",  # 0: the paper's tube (Eqs. 30, 31); 1: transmission line (waves, reflections)
    "exhaust_vent_area_m2",  # exhaust back-pressure: the valve exhausts through this vent
    "exhaust_volume_m3",  # the exhaust node's volume (0: quasi-static, the node holds no air)
    "lugre_stiffness_n_per_m",  # LuGre bristle stiffness sigma0; > 0 replaces Karnopp friction
    "lugre_damping_n_s_per_m",  # LuGre bristle damping sigma1 (used only with sigma0 > 0)
    "tube_air_model",  # the tube air of tube_volume_fraction: 0 a polytropic dead volume,
    # 1 an isothermal volume at the chamber's pressure
    "leakage_conductance_kg_per_pa_s",  # laminar leak chamber 1 <-> 2: G (P1 - P2)
)

# The parameters a cylinder file (configs/cylinders/) defines: bore through leakage.
CYLINDER_PARAMETERS = PARAMETER_NAMES[
    PARAMETER_NAMES.index("bore_diameter_m") : PARAMETER_NAMES.index("leakage_area_m2") + 1
]

# The value that switches each effect beyond the paper off (docs/effects.md).
EFFECT_NEUTRAL_VALUES = {
    "tube_volume_fraction": 0.0,
    "rod_seal_leak_area_m2": 0.0,
    "valve_null_leak_area_m2": 0.0,
    "exhaust_discharge_ratio": 1.0,
    "flow_law": 0.0,
    "supply_resistance_pa_s_per_kg": 0.0,
    "coil_time_constant_s": 0.0,
    "coil_lag_shape": 0.0,
    "wall_heat_transfer_w_per_k": 0.0,
    "stribeck_velocity_m_per_s": 0.0,
    "spool_coulomb_friction_n": 0.0,
    "tube_waves": 0.0,
    "exhaust_vent_area_m2": 0.0,
    "exhaust_volume_m3": 0.0,
    "lugre_stiffness_n_per_m": 0.0,
    "lugre_damping_n_s_per_m": 0.0,
    "tube_air_model": 0.0,
    "leakage_conductance_kg_per_pa_s": 0.0,
}

# Parameter rows: P_<NAME> is the row of ``name`` in PARAMETER_NAMES (written out so that
# editors and type checkers resolve them; ``_check_rows`` at the end keeps them in step).
P_GAS_CONSTANT_J_PER_KG_K = 0
P_HEAT_CAPACITY_RATIO = 1
P_TEMPERATURE_K = 2
P_AMBIENT_PRESSURE_PA = 3
P_SUPPLY_PRESSURE_PA = 4
P_AIR_VISCOSITY_PA_S = 5
P_ALPHA_IN = 6
P_ALPHA_OUT = 7
P_ALPHA_MOTION = 8
P_SPOOL_MASS_KG = 9
P_SPOOL_DAMPING_N_S_PER_M = 10
P_SPOOL_SPRING_N_PER_M = 11
P_COIL_FORCE_N_PER_A = 12
P_COIL_CURRENT_MAX_A = 13
P_DISCHARGE_COEFFICIENT = 14
P_HOLE_RADIUS_M = 15
P_SPOOL_HALF_WIDTH_M = 16
P_HOLES_PER_PATH = 17
P_TUBE_LENGTH_M = 18
P_TUBE_INNER_DIAMETER_M = 19
P_REYNOLDS_TURBULENT = 20
P_TUBE_COUPLING = 21
P_BORE_DIAMETER_M = 22
P_ROD_DIAMETER_M = 23
P_STROKE_M = 24
P_DEAD_VOLUME_CAP_M3 = 25
P_DEAD_VOLUME_ROD_M3 = 26
P_PISTON_MASS_KG = 27
P_STATIC_FRICTION_N = 28
P_DYNAMIC_FRICTION_N = 29
P_VISCOUS_FRICTION_N_S_PER_M = 30
P_LEAKAGE_AREA_M2 = 31
P_PISTON_MODE = 32
P_FIXED_POSITION_M = 33
P_LOAD_MASS_KG = 34
P_LOAD_FORCE_N = 35
P_SPRING_STIFFNESS_N_PER_M = 36
P_SPRING_REST_POSITION_M = 37
P_FLOW_LINEAR_RATIO = 38
P_TUBE_VOLUME_FRACTION = 39
P_ROD_SEAL_LEAK_AREA_M2 = 40
P_VALVE_NULL_LEAK_AREA_M2 = 41
P_EXHAUST_DISCHARGE_RATIO = 42
P_FLOW_LAW = 43
P_ISO_CRITICAL_RATIO_B = 44
P_SUPPLY_RESISTANCE_PA_S_PER_KG = 45
P_COIL_TIME_CONSTANT_S = 46
P_COIL_LAG_SHAPE = 47
P_WALL_HEAT_TRANSFER_W_PER_K = 48
P_STRIBECK_VELOCITY_M_PER_S = 49
P_SPOOL_COULOMB_FRICTION_N = 50
P_TUBE_WAVES = 51
P_EXHAUST_VENT_AREA_M2 = 52
P_EXHAUST_VOLUME_M3 = 53
P_LUGRE_STIFFNESS_N_PER_M = 54
P_LUGRE_DAMPING_N_S_PER_M = 55
P_TUBE_AIR_MODEL = 56
P_LEAKAGE_CONDUCTANCE_KG_PER_PA_S = 57
N_PARAMS = len(PARAMETER_NAMES)
PARAMETER_INDEX = {name: row for row, name in enumerate(PARAMETER_NAMES)}  # name -> row

# Integer-valued parameters (stored as float rows) and their allowed values.
DISCRETE_PARAMETERS = {
    "tube_coupling": {0: "command", 1: "literal"},
    "piston_mode": {0: "fixed", 1: "free", 2: "spring"},
    "flow_law": {0: "paper", 1: "iso6358"},
    "tube_waves": {0: "off", 1: "transmission_line"},
    "tube_air_model": {0: "dead_volume", 1: "isothermal"},
}

STATE_NAMES = (
    "spool_position_m",
    "spool_velocity_m_per_s",
    "p1_pa",
    "p2_pa",
    "piston_position_m",
    "piston_velocity_m_per_s",  # exactly 0.0 while the piston sticks or rests on a stop
    "exhaust_mass_kg",  # air let out of both chambers since reset (air consumption)
    "t1_k",  # chamber gas temperatures (temperature_k unless wall_heat_transfer_w_per_k > 0)
    "t2_k",
    "coil_current_a",  # coil current: the held command through the spool play and the coil
    # lag (the held command unless spool_coulomb_friction_n or coil_time_constant_s > 0)
    "spool_play_current_a",  # output of the spool-friction play (the command while it is off)
    "coil_force_current_a",  # the coil's force over K_f: the coil current through the force
    # lag (the coil current unless coil_lag_shape > 0); it drives the spool
    "exhaust_node_pa",  # pressure behind the valve's exhaust ports (ambient unless
    # exhaust_vent_area_m2 > 0 and exhaust_volume_m3 > 0)
    "bristle_deflection_m",  # LuGre friction's mean bristle deflection z (0 unless
    # lugre_stiffness_n_per_m > 0)
)
# State rows: S_<NAME> is the row of ``name`` in STATE_NAMES (written out, as above).
S_SPOOL_POSITION_M = 0
S_SPOOL_VELOCITY_M_PER_S = 1
S_P1_PA = 2
S_P2_PA = 3
S_PISTON_POSITION_M = 4
S_PISTON_VELOCITY_M_PER_S = 5
S_EXHAUST_MASS_KG = 6
S_T1_K = 7
S_T2_K = 8
S_COIL_CURRENT_A = 9
S_SPOOL_PLAY_CURRENT_A = 10
S_COIL_FORCE_CURRENT_A = 11
S_EXHAUST_NODE_PA = 12
S_BRISTLE_DEFLECTION_M = 13
N_STATE = len(STATE_NAMES)
S_X_S = S_SPOOL_POSITION_M
S_V_S = S_SPOOL_VELOCITY_M_PER_S
S_P1 = S_P1_PA
S_P2 = S_P2_PA
S_X = S_PISTON_POSITION_M
S_V = S_PISTON_VELOCITY_M_PER_S
S_EXHAUST = S_EXHAUST_MASS_KG
S_COIL = S_COIL_CURRENT_A
S_PLAY = S_SPOOL_PLAY_CURRENT_A
S_COIL_FORCE = S_COIL_FORCE_CURRENT_A
S_T1 = S_T1_K
S_T2 = S_T2_K
S_EXHAUST_NODE = S_EXHAUST_NODE_PA
S_BRISTLE = S_BRISTLE_DEFLECTION_M

# Channels kept in the tube-delay ring buffer, one sample per substep boundary. The wave
# channels (Pa) are the transmission line's wave variables (tube_waves = 1, docs/effects.md):
# the wave each tube end sends into the line, which arrives at the other end one delay later.
# The line's valve exhaust (kg/s) at each boundary integrates the exhaust mass by the
# trapezoid rule (``general_path.close_substep``).
HISTORY_NAMES = (
    "spool_position_m",
    "p1_pa",
    "p2_pa",
    "wave_from_valve_1_pa",
    "wave_from_valve_2_pa",
    "wave_from_chamber_1_pa",
    "wave_from_chamber_2_pa",
    "line_exhaust_kg_per_s",
)
(
    H_X_S,
    H_P1,
    H_P2,
    H_WAVE_VALVE_1,
    H_WAVE_VALVE_2,
    H_WAVE_CHAMBER_1,
    H_WAVE_CHAMBER_2,
    H_LINE_EXHAUST,
) = range(len(HISTORY_NAMES))  # one constant per name, in order (fails to unpack if not)
N_HISTORY = len(HISTORY_NAMES)

# Outputs written once per control step.
OUTPUT_NAMES = (
    "p1_pa",
    "p2_pa",
    "piston_position_m",
    "force_n",
    "piston_velocity_m_per_s",
    "spool_position_m",
    "exhaust_mass_kg",
)
O_P1, O_P2, O_X, O_F, O_V, O_X_S, O_EXHAUST = range(7)
N_OUTPUT = len(OUTPUT_NAMES)


def _check_rows(namespace: dict) -> None:
    """Every written-out row constant matches its table: ``P_<NAME>`` is the row of
    ``name`` in PARAMETER_NAMES and ``S_<NAME>`` in STATE_NAMES, one constant per name and
    no other; the O_* rows count their table in order (the H_* rows are unpacked from it)."""
    for prefix, names in (("P_", PARAMETER_NAMES), ("S_", STATE_NAMES)):
        written = {
            key: value
            for key, value in namespace.items()
            if key.startswith(prefix) and key[len(prefix) :] in {name.upper() for name in names}
        }
        expected = {prefix + name.upper(): row for row, name in enumerate(names)}
        if written != expected:
            wrong = sorted(set(expected.items()) ^ set(written.items()))
            raise AssertionError(
                f"layout: row constants {wrong} disagree with the table of {prefix}* names"
            )
    output_rows = (O_P1, O_P2, O_X, O_F, O_V, O_X_S, O_EXHAUST)
    if output_rows != tuple(range(len(OUTPUT_NAMES))):
        raise AssertionError(f"layout: rows {output_rows} do not count {OUTPUT_NAMES} in order")


_check_rows(globals())


class SimArrays(NamedTuple):
    """A batch's arrays and step settings (``BatchSimulator.arrays``), as the step functions
    (``batch_path``) take them."""

    params: np.ndarray  # (N_PARAMS, n_envs), P_* rows
    state: np.ndarray  # (N_STATE, n_envs), S_* rows
    history: np.ndarray  # ring buffer of the tube delay (slots, N_HISTORY, n_envs)
    head: np.ndarray  # (1,) int64: the ring buffer's newest slot (moved in place each step)
    outputs: np.ndarray  # (N_OUTPUT, n_envs), O_* rows
    constants_key: np.ndarray  # (n_envs,): substep of each env's cached constants (NaN: stale)
    constants: np.ndarray  # the batch path's cached per-env constants (constants_cache)
    control_dt_s: float  # the coil current is held over it
    n_substeps: int  # RK4 substeps per control period
