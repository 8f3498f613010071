"""The kernel's per-environment constants: the ``Constants`` named tuple, derived once per
control period from a parameter column (``env_constants``), and the batch path's cache of
them (``constants_cache``, ``refresh_constants``, ``store_constants`` / ``load_constants``).

The effects beyond the paper's model (docs/effects.md, ``effects.py``) are switched per
environment by their parameter rows; ``env_constants`` turns each into a flag or a
neutral constant, so an effect that is off costs a branch.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit

from . import layout as L
from .derived import circle_area_m2, linear_flow_slope, piston_areas_m2, tube_delay_s
from .effects import coil_decay, coil_time_constants, dead_volume_with_tube, spool_play_band
from .flow import FLOW_LAW_ISO, FLOW_LAW_PAPER, flow_constants
from .piston import MODE_FIXED
from .tube import line_flow_coefficients, reynolds_per_mass_flow, sound_speed, viscous_scale

CHUNK_ENVS = 64  # environments advanced together by the batch path (their arrays stay in L1/L2)

Constants = namedtuple(
    "Constants",
    (
        "gas_rt",
        "inv_sqrt_t",
        "k",
        "c1",
        "c2",
        "critical_ratio",
        "linear_ratio",
        "linear_slope",
        "supply_pa",
        "ambient_pa",
        "viscosity",
        "alpha_in",
        "alpha_out",
        "alpha_motion",
        "inv_spool_mass",
        "spool_damping",
        "spool_spring",
        "coil_force",
        "discharge",
        "hole_radius",
        "half_width",
        "holes",
        "delay_s",
        "delay_substeps",
        "tube_diameter",
        "reynolds_turbulent",
        "literal",
        "area_cap",
        "area_rod",
        "rod_area",
        "half_stroke",
        "dead_cap",
        "dead_rod",
        "inv_moving_mass",
        "dynamic_friction",
        "stick_threshold",
        "viscous",
        "leak_area",
        "mode",
        "load_force",
        "spring_k",
        "spring_rest",
        # effects (docs/effects.md)
        "discharge_ex",
        "null_leak",
        "seal_leak",
        "leak_conductance",  # kg/(Pa s): the laminar leak between the chambers
        "flow_law",
        "supply_resistance",
        "exhaust_vent",
        "exhaust_capacity",
        "coil_lag",
        "coil_decay_half",
        "coil_decay_full",
        "coil_force_lag",
        "force_rate",
        "force_rate_difference",
        "energy",
        "gas",
        "temperature",
        "heat_conductance",
        "static_friction",
        "stribeck",
        "stribeck_v",
        "spool_play_band",
        "lugre",
        "lugre_stiffness",
        "lugre_damping",
        "waves",
        "line_impedance",
        "line_friction",
        "tube_air",  # m^3 of isothermal tube air per chamber (tube_air_model = 1), else 0
        # numerical guards (docs/convergence.md): pressures and gas temperatures stay positive
        "pressure_floor",
        "temperature_floor",
        "stiffness_volume",  # lambda_max * V (m^3/s): see refinement()
        # reciprocals and products the right-hand side would otherwise divide by per evaluation
        # (a division takes a divider's latency; a product does not), as inv_spool_mass (1/M_s)
        # and inv_moving_mass (1/(M_p + M_L)) above: 1/k, 1/R_h, R T tau / 2, Re per kg/s,
        # mu / D^2
        "inv_k",
        "inv_hole_radius",
        "half_rt_delay",
        "reynolds_per_flow",
        "viscous_scale",
        # the transmission line's ``tube.line_flow_coefficients``
        "line_laminar_friction",
        "line_turbulent_friction",
        "line_transition_flow",
    ),
)


PRESSURE_FLOOR_FRACTION = 1e-3  # of ambient: a guard that keeps log/pow arguments positive
TEMPERATURE_FLOOR_FRACTION = 1e-3  # of the wall temperature, the same guard for T1, T2


@njit(cache=True)
def env_constants(params, env, substep_s):
    """Per-environment constants derived once per control period from the parameter column.

    Every field is a float (flags are 0.0 / 1.0), so the batch kernel can hold them as the
    rows of one array (``store_constants`` / ``load_constants``). The fields are given by
    name: a swapped or missing one fails to compile.
    """
    p = params[:, env]
    k = p[L.P_HEAT_CAPACITY_RATIO]
    gas = p[L.P_GAS_CONSTANT_J_PER_KG_K]
    temperature = p[L.P_TEMPERATURE_K]
    c1, c2, critical_ratio = flow_constants(k, gas)
    linear_ratio = p[L.P_FLOW_LINEAR_RATIO]
    flow_law = int(p[L.P_FLOW_LAW])
    if flow_law == FLOW_LAW_ISO:
        critical_ratio = p[L.P_ISO_CRITICAL_RATIO_B]
    linear_slope = linear_flow_slope(linear_ratio, k, c1, c2, critical_ratio, flow_law)
    tube_length = p[L.P_TUBE_LENGTH_M]
    tube_diameter = p[L.P_TUBE_INNER_DIAMETER_M]
    delay_s = tube_delay_s(tube_length, k, gas, temperature)
    area_cap, area_rod, rod_area = piston_areas_m2(p[L.P_BORE_DIAMETER_M], p[L.P_ROD_DIAMETER_M])
    # the tube's air (tube_volume_fraction) as a dead volume, or isothermal (tube_air_model)
    tube_fraction = p[L.P_TUBE_VOLUME_FRACTION]
    tube_air = 0.0
    if p[L.P_TUBE_AIR_MODEL] == 1.0:
        tube_air = tube_fraction * circle_area_m2(tube_diameter) * tube_length
        tube_fraction = 0.0
    coil_tau, force_tau = coil_time_constants(p[L.P_COIL_TIME_CONSTANT_S], p[L.P_COIL_LAG_SHAPE])
    heat_conductance = p[L.P_WALL_HEAT_TRANSFER_W_PER_K]
    stribeck_v = p[L.P_STRIBECK_VELOCITY_M_PER_S]
    literal_flag = 1.0 if p[L.P_TUBE_COUPLING] == 1.0 else 0.0
    coil_lag_flag = 1.0 if coil_tau > 0.0 else 0.0
    force_lag_flag = 1.0 if force_tau > 0.0 else 0.0
    force_rate = substep_s / force_tau if force_tau > 0.0 else 0.0  # substeps per tau_f
    force_rate_difference = 0.0  # substep (1/tau_f - 1/tau_c), with both lags on
    if force_tau > 0.0 and coil_tau > 0.0:
        force_rate_difference = force_rate - substep_s / coil_tau
    energy_flag = 1.0 if heat_conductance > 0.0 else 0.0
    stribeck_flag = 1.0 if stribeck_v > 0.0 else 0.0
    lugre_flag = 1.0 if p[L.P_LUGRE_STIFFNESS_N_PER_M] > 0.0 else 0.0
    # Karnopp's stick threshold; LuGre friction has none (its bristles hold the rod)
    stick_threshold = max(p[L.P_STATIC_FRICTION_N], p[L.P_DYNAMIC_FRICTION_N])
    if lugre_flag:
        stick_threshold = 0.0
    waves_flag = 1.0 if p[L.P_TUBE_WAVES] == 1.0 else 0.0
    tube_area = circle_area_m2(tube_diameter)
    line_impedance = sound_speed(k, gas, temperature) / tube_area
    line_friction = tube_length * gas * temperature / tube_area
    line_coefficients = (0.0, 0.0, 0.0)  # used with the lines only: no pow per period else
    if waves_flag:
        line_coefficients = line_flow_coefficients(
            line_friction, tube_diameter, p[L.P_AIR_VISCOSITY_PA_S], p[L.P_REYNOLDS_TURBULENT]
        )
    return Constants(
        gas_rt=gas * temperature,
        inv_sqrt_t=1.0 / math.sqrt(temperature),
        k=k,
        c1=c1,
        c2=c2,
        critical_ratio=critical_ratio,
        linear_ratio=linear_ratio,
        linear_slope=linear_slope,
        supply_pa=p[L.P_SUPPLY_PRESSURE_PA],
        ambient_pa=p[L.P_AMBIENT_PRESSURE_PA],
        viscosity=p[L.P_AIR_VISCOSITY_PA_S],
        alpha_in=p[L.P_ALPHA_IN],
        alpha_out=p[L.P_ALPHA_OUT],
        alpha_motion=p[L.P_ALPHA_MOTION],
        inv_spool_mass=1.0 / p[L.P_SPOOL_MASS_KG],
        spool_damping=p[L.P_SPOOL_DAMPING_N_S_PER_M],
        spool_spring=p[L.P_SPOOL_SPRING_N_PER_M],
        coil_force=p[L.P_COIL_FORCE_N_PER_A],
        discharge=p[L.P_DISCHARGE_COEFFICIENT],
        hole_radius=p[L.P_HOLE_RADIUS_M],
        half_width=p[L.P_SPOOL_HALF_WIDTH_M],
        holes=p[L.P_HOLES_PER_PATH],
        delay_s=delay_s,
        delay_substeps=delay_s / substep_s,
        tube_diameter=tube_diameter,
        reynolds_turbulent=p[L.P_REYNOLDS_TURBULENT],
        literal=literal_flag,
        area_cap=area_cap,
        area_rod=area_rod,
        rod_area=rod_area,
        half_stroke=0.5 * p[L.P_STROKE_M],
        dead_cap=dead_volume_with_tube(
            p[L.P_DEAD_VOLUME_CAP_M3], tube_fraction, tube_diameter, tube_length
        ),
        dead_rod=dead_volume_with_tube(
            p[L.P_DEAD_VOLUME_ROD_M3], tube_fraction, tube_diameter, tube_length
        ),
        inv_moving_mass=1.0 / (p[L.P_PISTON_MASS_KG] + p[L.P_LOAD_MASS_KG]),
        dynamic_friction=p[L.P_DYNAMIC_FRICTION_N],
        stick_threshold=stick_threshold,
        viscous=p[L.P_VISCOUS_FRICTION_N_S_PER_M],
        leak_area=p[L.P_LEAKAGE_AREA_M2],
        mode=float(int(p[L.P_PISTON_MODE])),
        load_force=p[L.P_LOAD_FORCE_N],
        spring_k=p[L.P_SPRING_STIFFNESS_N_PER_M],
        spring_rest=p[L.P_SPRING_REST_POSITION_M],
        discharge_ex=p[L.P_DISCHARGE_COEFFICIENT] * p[L.P_EXHAUST_DISCHARGE_RATIO],
        null_leak=p[L.P_VALVE_NULL_LEAK_AREA_M2],
        seal_leak=p[L.P_ROD_SEAL_LEAK_AREA_M2],
        leak_conductance=p[L.P_LEAKAGE_CONDUCTANCE_KG_PER_PA_S],
        flow_law=float(flow_law),
        supply_resistance=p[L.P_SUPPLY_RESISTANCE_PA_S_PER_KG],
        exhaust_vent=p[L.P_EXHAUST_VENT_AREA_M2],
        exhaust_capacity=p[L.P_EXHAUST_VOLUME_M3] / (gas * temperature),
        coil_lag=coil_lag_flag,
        coil_decay_half=coil_decay(coil_tau, 0.5 * substep_s),
        coil_decay_full=coil_decay(coil_tau, substep_s),
        coil_force_lag=force_lag_flag,
        force_rate=force_rate,
        force_rate_difference=force_rate_difference,
        energy=energy_flag,
        gas=gas,
        temperature=temperature,
        heat_conductance=heat_conductance,
        static_friction=p[L.P_STATIC_FRICTION_N],
        stribeck=stribeck_flag,
        stribeck_v=stribeck_v,
        spool_play_band=spool_play_band(p[L.P_SPOOL_COULOMB_FRICTION_N], p[L.P_COIL_FORCE_N_PER_A]),
        lugre=lugre_flag,
        lugre_stiffness=p[L.P_LUGRE_STIFFNESS_N_PER_M],
        lugre_damping=p[L.P_LUGRE_DAMPING_N_S_PER_M],
        waves=waves_flag,
        line_impedance=line_impedance,
        line_friction=line_friction,
        tube_air=tube_air,
        pressure_floor=PRESSURE_FLOOR_FRACTION * p[L.P_AMBIENT_PRESSURE_PA],
        temperature_floor=TEMPERATURE_FLOOR_FRACTION * temperature,
        stiffness_volume=(
            gas
            * temperature
            * max(p[L.P_ALPHA_IN], k)
            * p[L.P_DISCHARGE_COEFFICIENT]
            * max(1.0, p[L.P_EXHAUST_DISCHARGE_RATIO])
            * (
                # the valve's paths reach a chamber directly only without the lines
                (1.0 - waves_flag)
                * (
                    p[L.P_HOLES_PER_PATH] * math.pi * p[L.P_HOLE_RADIUS_M] ** 2
                    + p[L.P_VALVE_NULL_LEAK_AREA_M2]
                )
                + p[L.P_LEAKAGE_AREA_M2]
                + p[L.P_ROD_SEAL_LEAK_AREA_M2]
            )
            * (linear_slope + c1)
            / math.sqrt(temperature)
            # the laminar leak: |dm/dP| = G per chamber
            + gas * temperature * max(p[L.P_ALPHA_IN], k) * p[L.P_LEAKAGE_CONDUCTANCE_KG_PER_PA_S]
            # a line's chamber end: |dm/dP| <= 2 / Z_c (``tube.line_chamber_flow``: 1 / Z_c,
            # up to twice that where the friction's fall with the pressure adds to it)
            + waves_flag * 2.0 * gas * temperature * max(p[L.P_ALPHA_IN], k) / line_impedance
        ),
        inv_k=1.0 / k,
        inv_hole_radius=1.0 / p[L.P_HOLE_RADIUS_M],
        half_rt_delay=0.5 * gas * temperature * delay_s,
        reynolds_per_flow=reynolds_per_mass_flow(tube_diameter, p[L.P_AIR_VISCOSITY_PA_S]),
        viscous_scale=viscous_scale(tube_diameter, p[L.P_AIR_VISCOSITY_PA_S]),
        line_laminar_friction=line_coefficients[0],
        line_turbulent_friction=line_coefficients[1],
        line_transition_flow=line_coefficients[2],
    )


@njit(cache=True)
def _batch_path_effects_only(c):
    """``base_model_only`` but for the effects the batch path adds on: the leaks (the
    orifices ``leakage_area_m2``, ``rod_seal_leak_area_m2`` and the laminar
    ``leakage_conductance_kg_per_pa_s``; ``BATCH_LEAKS``), the coil
    lags (``coil_time_constant_s``; the currents at its RK4 stages, ``lagged_coil_rows``),
    the valve's null leak (``valve_null_leak_area_m2``: all four valve paths, in a chunk
    with one), the pressure nodes (the exhaust back-pressure, a vent with no volume; the
    supply droop: ``batch_nodes``), the energy equation, the tubes' isothermal air and the
    ISO 6358 flow law (``batch_rhs``, selected per lane), and the tubes as transmission
    lines (``tube_waves``, without the pressure nodes: ``batch_path.line_substeps``). A
    clamped rod takes no friction, so the Stribeck and LuGre laws change nothing there
    (the bristles hold at v = 0): the batch path takes it."""
    return (
        (c.exhaust_vent == 0.0 or c.exhaust_capacity == 0.0)
        and c.literal == 0.0
        and ((c.stribeck == 0.0 and c.lugre == 0.0) or c.mode == MODE_FIXED)
        and (c.waves == 0.0 or (c.exhaust_vent == 0.0 and c.supply_resistance == 0.0))
        and c.half_width >= c.hole_radius
        and c.delay_substeps >= 1.0
    )


@njit(cache=True)
def _leakless(c):
    """No leak between the chambers (orifice or laminar) and none at the rod seal."""
    return c.leak_area == 0.0 and c.seal_leak == 0.0 and c.leak_conductance == 0.0


@njit(cache=True)
def base_model_only(c):
    """Whether an environment runs the paper's model with no effect that needs ``derivatives``.

    Then the spool overlap (p_w >= R_h, Eq. 43) keeps the supply and exhaust paths of a
    chamber from being open together, and ``base_derivatives`` gives the same result with
    two valve paths instead of four. Three effects are in it (the exhaust discharge ratio,
    the tube volume as a dead volume, the spool friction, whose play acts before the
    substeps); the leaks (orifices, laminar), the coil lags, the valve's null leak, the exhaust
    back-pressure, the supply droop, the energy equation, the tubes' isothermal air, the
    ISO flow law and the transmission lines take the batch path too
    (``batch_lane_kind``); the others send the environment to the general path.
    """
    return (
        _batch_path_effects_only(c)
        and c.waves == 0.0
        and c.exhaust_vent == 0.0
        and c.supply_resistance == 0.0
        and c.null_leak == 0.0
        and _leakless(c)
        and c.coil_lag == 0.0
        and c.coil_force_lag == 0.0
        and c.energy == 0.0
        and c.tube_air == 0.0
        and c.flow_law == FLOW_LAW_PAPER
    )


# How the batch path advances an environment (``batch_lane_kind``, the cache's row
# C_BASE_ONLY): by the general path, with ``base_derivatives``, or with
# ``base_derivatives`` and the leaks (cross-piston orifice and laminar leak, rod-seal
# orifice); either batch kind with or without the coil lags, the valve's null leak and
# the effects ``batch_rhs`` selects per lane.
BATCH_GENERAL = 0.0
BATCH_BASE = 1.0
BATCH_LEAKS = 2.0


@njit(cache=True)
def batch_lane_kind(c):
    """``BATCH_BASE`` where ``base_model_only`` holds but for the effects the batch path
    adds on other than the leaks (``_batch_path_effects_only``), ``BATCH_LEAKS``
    where it would but for the leaks (orifices, laminar), else ``BATCH_GENERAL``."""
    if not _batch_path_effects_only(c):
        return BATCH_GENERAL
    return BATCH_BASE if _leakless(c) else BATCH_LEAKS


N_CONSTANTS = len(Constants._fields)


@njit(cache=True)
def store_constants(c, constants, lane):
    """Write the fields of ``c`` into lane ``lane`` of a flat chunk array (``N_CONSTANTS`` rows
    of ``CHUNK_ENVS`` lanes): in a loop over lanes each field is one contiguous vector load."""
    for i in range(N_CONSTANTS):
        constants[i * CHUNK_ENVS + lane] = c[i]


@njit(cache=True, forceinline=True, error_model="numpy")
def load_constants(constants, lane):
    """The ``Constants`` of column ``lane`` (inverse of ``store_constants``), field by field."""
    # one argument per field, in order: a new Constants field makes this fail to compile
    k = CHUNK_ENVS
    return Constants(
        constants[0 * k + lane],
        constants[1 * k + lane],
        constants[2 * k + lane],
        constants[3 * k + lane],
        constants[4 * k + lane],
        constants[5 * k + lane],
        constants[6 * k + lane],
        constants[7 * k + lane],
        constants[8 * k + lane],
        constants[9 * k + lane],
        constants[10 * k + lane],
        constants[11 * k + lane],
        constants[12 * k + lane],
        constants[13 * k + lane],
        constants[14 * k + lane],
        constants[15 * k + lane],
        constants[16 * k + lane],
        constants[17 * k + lane],
        constants[18 * k + lane],
        constants[19 * k + lane],
        constants[20 * k + lane],
        constants[21 * k + lane],
        constants[22 * k + lane],
        constants[23 * k + lane],
        constants[24 * k + lane],
        constants[25 * k + lane],
        constants[26 * k + lane],
        constants[27 * k + lane],
        constants[28 * k + lane],
        constants[29 * k + lane],
        constants[30 * k + lane],
        constants[31 * k + lane],
        constants[32 * k + lane],
        constants[33 * k + lane],
        constants[34 * k + lane],
        constants[35 * k + lane],
        constants[36 * k + lane],
        constants[37 * k + lane],
        constants[38 * k + lane],
        constants[39 * k + lane],
        constants[40 * k + lane],
        constants[41 * k + lane],
        constants[42 * k + lane],
        constants[43 * k + lane],
        constants[44 * k + lane],
        constants[45 * k + lane],
        constants[46 * k + lane],
        constants[47 * k + lane],
        constants[48 * k + lane],
        constants[49 * k + lane],
        constants[50 * k + lane],
        constants[51 * k + lane],
        constants[52 * k + lane],
        constants[53 * k + lane],
        constants[54 * k + lane],
        constants[55 * k + lane],
        constants[56 * k + lane],
        constants[57 * k + lane],
        constants[58 * k + lane],
        constants[59 * k + lane],
        constants[60 * k + lane],
        constants[61 * k + lane],
        constants[62 * k + lane],
        constants[63 * k + lane],
        constants[64 * k + lane],
        constants[65 * k + lane],
        constants[66 * k + lane],
        constants[67 * k + lane],
        constants[68 * k + lane],
        constants[69 * k + lane],
        constants[70 * k + lane],
        constants[71 * k + lane],
        constants[72 * k + lane],
        constants[73 * k + lane],
        constants[74 * k + lane],
        constants[75 * k + lane],
        constants[76 * k + lane],
        constants[77 * k + lane],
        constants[78 * k + lane],
        constants[79 * k + lane],
        constants[80 * k + lane],
        constants[81 * k + lane],
    )


# The batch path caches the per-environment constants (``env_constants``) between control
# periods: per chunk, the N_CONSTANTS rows of ``store_constants`` and a row C_BASE_ONLY
# (``batch_lane_kind``: 0.0 for the general path); per environment, a key: the substep length they
# were derived for, NaN when stale. The parameters do not change behind the cache's back:
# ``BatchSimulator.params`` is read-only, and ``set_params`` / ``set_parameter`` mark the
# changed environments' keys stale. (A key of whole parameter columns, compared every
# control period, streamed 0.9 kB per environment and period through the caches.)
C_BASE_ONLY = N_CONSTANTS
C_SPOOL_PLAY_BAND = Constants._fields.index("spool_play_band")  # read per control period
C_DELAY_SUBSTEPS = Constants._fields.index("delay_substeps")  # read per substep
C_COIL_LAG = Constants._fields.index("coil_lag")  # read per control period
C_ENERGY = Constants._fields.index("energy")  # read per control period
C_TUBE_AIR = Constants._fields.index("tube_air")  # read per control period
C_FLOW_LAW = Constants._fields.index("flow_law")  # read per control period
C_NULL_LEAK = Constants._fields.index("null_leak")  # read per control period
C_EXHAUST_VENT = Constants._fields.index("exhaust_vent")  # read per control period
C_SUPPLY_RESISTANCE = Constants._fields.index("supply_resistance")  # read per control period
C_WAVES = Constants._fields.index("waves")  # read per control period
N_CACHED_CONSTANTS = N_CONSTANTS + 1


@njit(cache=True)
def chunk_effects(chunk_constants, n_lanes):
    """Whether any lane of a chunk has the leaks (``BATCH_LEAKS``), an effect
    ``batch_rhs`` selects per lane (energy equation, tube air, ISO flow law), a coil lag,
    the valve's null leak (``batch_rhs._valve_flows``' four paths), an exhaust vent, a
    supply resistance (the pressure nodes of ``batch_nodes``); then whether any and
    whether every batch-path lane has the tubes as transmission lines
    (``batch_path.line_substeps``)."""
    k = CHUNK_ENVS
    leaky = selected = lagged = four_paths = vented = drooped = lines = False
    only_lines = True
    for j in range(n_lanes):
        leaky |= chunk_constants[C_BASE_ONLY * k + j] == BATCH_LEAKS
        selected |= (
            (chunk_constants[C_ENERGY * k + j] != 0.0)
            | (chunk_constants[C_TUBE_AIR * k + j] > 0.0)
            | (chunk_constants[C_FLOW_LAW * k + j] != FLOW_LAW_PAPER)
        )
        lagged |= chunk_constants[C_COIL_LAG * k + j] != 0.0
        four_paths |= chunk_constants[C_NULL_LEAK * k + j] != 0.0
        batch = chunk_constants[C_BASE_ONLY * k + j] != BATCH_GENERAL
        vented |= (chunk_constants[C_EXHAUST_VENT * k + j] > 0.0) & batch
        drooped |= (chunk_constants[C_SUPPLY_RESISTANCE * k + j] > 0.0) & batch
        line = chunk_constants[C_WAVES * k + j] != 0.0
        lines |= line & batch
        only_lines &= line | (not batch)
    return leaky, selected, lagged, four_paths, vented, drooped, lines, only_lines


LANE_KIND_BITS = 2  # lane_classes: the batch lane kind, then one bit per chunk_effects flag
_FLAGS = ("leaky", "selected", "lagged", "four_paths", "vented", "drooped", "lines")


@njit(cache=True)
def lane_classes(params, substep_s):
    """Per environment of ``params``: an integer naming the loops a chunk of it alone
    would run (its ``batch_lane_kind``, then its ``chunk_effects`` flags as bits). A
    chunk runs the costliest loop any of its lanes needs for every lane (a pressure node
    costs about 12 x the paper's model per substep), so a caller that batches unlike
    columns (the identification's screening) keeps like ones together; an
    environment's result never depends on the rest of its batch."""
    n = params.shape[1]
    out = np.empty(n, np.int64)
    lane = np.zeros(N_CACHED_CONSTANTS * CHUNK_ENVS)
    for env in range(n):
        c = env_constants(params, env, substep_s)
        store_constants(c, lane, 0)
        kind = batch_lane_kind(c)
        lane[C_BASE_ONLY * CHUNK_ENVS] = kind
        code = int(kind)
        bit = 1 << LANE_KIND_BITS
        for flag in chunk_effects(lane, 1)[:7]:
            if flag:
                code |= bit
            bit <<= 1
        out[env] = code
    return out


def lane_class_cost(code: int) -> float:
    """Rough cost per substep of a ``lane_classes`` class against the paper's model, to
    schedule the costliest batches first (measured, docs/identification.md: a pressure
    node 11-16 x, a transmission line 14-17 x, the general path's effects 1-9 x)."""
    flag = {name: bool(code >> (LANE_KIND_BITS + i) & 1) for i, name in enumerate(_FLAGS)}
    if flag["vented"] or flag["drooped"]:
        return 12.0
    if flag["lines"]:
        return 15.0
    return 4.0 if code & ((1 << LANE_KIND_BITS) - 1) == int(BATCH_GENERAL) else 1.0


def constants_cache(n_envs):
    """An empty cache of the batch path's constants for ``n_envs`` environments, every
    entry stale: (key (n_envs,), constants (chunks, N_CACHED_CONSTANTS * CHUNK_ENVS))."""
    n_chunks = (n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS
    return (np.full(n_envs, np.nan), np.zeros((n_chunks, N_CACHED_CONSTANTS * CHUNK_ENVS)))


@njit(cache=True)
def refresh_constants(params, first, stop, substep_s, key, constants):
    """Recompute the cached constants of environments ``first .. stop-1`` (one chunk;
    ``constants`` is its row of the cache) whose key is not ``substep_s`` (a NaN key, set
    when their parameters changed, never is)."""
    for j in range(stop - first):
        env = first + j
        if not key[env] == substep_s:
            c = env_constants(params, env, substep_s)
            store_constants(c, constants, j)
            constants[C_BASE_ONLY * CHUNK_ENVS + j] = batch_lane_kind(c)
            key[env] = substep_s
