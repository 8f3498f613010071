"""Piston and load (Eq. 1) with Karnopp stick-slip friction (Eq. 47 corrected) and end stops."""

from numba import njit

MODE_FIXED = 0
MODE_FREE = 1
MODE_SPRING = 2


@njit(cache=True, forceinline=True, error_model="numpy")
def pneumatic_force(p1_pa, p2_pa, area_cap_m2, area_rod_m2, rod_area_m2, ambient_pressure_pa):
    """Right-hand side of Eq. 1: F_p = P1 A1 - P2 A2 - P_a A_r."""
    return p1_pa * area_cap_m2 - p2_pa * area_rod_m2 - ambient_pressure_pa * rod_area_m2


@njit(cache=True, forceinline=True, error_model="numpy")
def external_force(
    mode, piston_position_m, load_force_n, spring_stiffness_n_per_m, spring_rest_position_m
):
    """F_L of Eq. 1 (positive resists extension): a constant force, plus the spring's push."""
    if mode == MODE_SPRING:
        return load_force_n + spring_stiffness_n_per_m * (
            piston_position_m - spring_rest_position_m
        )
    return load_force_n


@njit(cache=True)
def output_force(
    mode, pneumatic_force_n, piston_position_m, spring_stiffness_n_per_m, spring_rest_position_m
):
    """The force channel: the load cell (fixed rod), the spring force (spring), else F_p."""
    if mode == MODE_SPRING:
        return spring_stiffness_n_per_m * (piston_position_m - spring_rest_position_m)
    return pneumatic_force_n


@njit(cache=True)
def motion_direction(
    piston_position_m, piston_velocity_m_per_s, applied_force_n, stick_threshold_n, half_stroke_m
):
    """Direction of motion over the next substep: -1, +1, or 0 when the piston is held.

    A moving piston keeps its direction. A piston at rest (velocity exactly zero) stays
    held while static friction can balance the applied force (Karnopp: threshold
    max(F_sf, F_df)) or while the force presses it into an end stop; otherwise it breaks
    away in the direction of the force.
    """
    if piston_velocity_m_per_s > 0.0:
        return 1.0
    if piston_velocity_m_per_s < 0.0:
        return -1.0
    if abs(applied_force_n) <= stick_threshold_n:
        return 0.0
    if applied_force_n > 0.0 and piston_position_m >= half_stroke_m:
        return 0.0
    if applied_force_n < 0.0 and piston_position_m <= -half_stroke_m:
        return 0.0
    return 1.0 if applied_force_n > 0.0 else -1.0


@njit(cache=True, forceinline=True, error_model="numpy")
def piston_acceleration(
    applied_force_n,
    piston_velocity_m_per_s,
    direction,
    dynamic_friction_n,
    viscous_friction_n_s_per_m,
    inverse_moving_mass_per_kg,
):
    """Eq. 1 while sliding: (F_p - F_L - beta v - F_df dir) / (M_p + M_L), given
    1 / (M_p + M_L); zero while held."""
    if direction == 0.0:
        return 0.0
    return (
        applied_force_n
        - viscous_friction_n_s_per_m * piston_velocity_m_per_s
        - dynamic_friction_n * direction
    ) * inverse_moving_mass_per_kg


@njit(cache=True, forceinline=True, error_model="numpy")
def event_fraction(x0_m, v0_m_per_s, x1_m, v1_m_per_s, direction, half_stroke_m):
    """Where in a sliding step [0, 1] the piston reaches a stop or its velocity reverses.

    Linear interpolation of the attempted step's position (stop) and velocity (reversal);
    -1 when neither happens within the step. Inlined and free of raising divisions, so the
    batch path's event test (``batch_path.end_substeps``) vectorises.
    """
    theta = -1.0
    stop = direction * half_stroke_m
    if (x1_m - stop) * direction >= 0.0 and x1_m != x0_m:
        theta = min(max((stop - x0_m) / (x1_m - x0_m), 0.0), 1.0)
    if v1_m_per_s * direction <= 0.0 and v1_m_per_s != v0_m_per_s:
        reversal = min(max(v0_m_per_s / (v0_m_per_s - v1_m_per_s), 0.0), 1.0)
        if theta < 0.0 or reversal < theta:
            theta = reversal
    return theta


@njit(cache=True)
def apply_event(
    piston_position_m, piston_velocity_m_per_s, direction, half_stroke_m, stop_reached=False
):
    """The state right after an event found by ``event_fraction``.

    At a stop the piston stops there (inelastic); otherwise the velocity has reached zero
    and ``motion_direction`` decides next whether static friction holds it.
    ``stop_reached``: the attempted step crossed the stop still moving toward it, so the
    event is the stop. The piston is put on it even where the interpolated event left it
    short by rounding (picometres): a piston left just short, at rest and pushed on, would
    start every later substep with the same event again (issue 34: a free rod resting on
    its stop cost 5 RK4 steps per substep).
    """
    x = piston_position_m
    if stop_reached or (x - direction * half_stroke_m) * direction >= -1e-12 * half_stroke_m:
        x = direction * half_stroke_m
    return min(max(x, -half_stroke_m), half_stroke_m), 0.0


@njit(cache=True, forceinline=True, error_model="numpy")
def end_of_substep(piston_position_m, piston_velocity_m_per_s, half_stroke_m):
    """Keep the piston within +-L/2 (inelastic stops) after a substep (inlined: it
    vectorises in ``batch_path.end_substeps``)."""
    x = piston_position_m
    v = piston_velocity_m_per_s
    if x >= half_stroke_m:
        x = half_stroke_m
        if v > 0.0:
            v = 0.0
    elif x <= -half_stroke_m:
        x = -half_stroke_m
        if v < 0.0:
            v = 0.0
    return x, v
