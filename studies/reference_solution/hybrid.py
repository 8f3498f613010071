"""The hybrid-system integrator of the reference solution (``simulate_reference``): the
state, the switching surfaces and the event-located integration that the package
docstring (:mod:`pneumatic_env.studies.reference_solution`) describes."""

from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK45, Radau

from .events import _active_events, _event_root, _EventSet, _Piece
from .model import (
    COUPLING_LITERAL,
    IX_P1,
    IX_P2,
    IX_V,
    IX_VD,
    IX_VS,
    IX_X,
    IX_XD,
    IX_XS,
    N_Y,
    PATH_CHAMBER,
    PISTON_FIXED,
    ModelConstants,
    chamber_pressure_rate,
    chamber_volumes,
    load_force,
    orifice_area,
    orifice_mass_flow,
    output_force,
    piston_acceleration,
    pneumatic_force,
    reynolds_number,
    spool_acceleration,
    tube_attenuation,
    tube_resistance,
)

FIRST_STEP_AFTER_EDGE = 1e-9  # s, first step after the delayed spool crosses a hole edge
EVENT_SAMPLES = 8  # points per integration step at which the event functions are checked
_METHODS = {"DOP853": DOP853, "Radau": Radau, "LSODA": LSODA, "RK45": RK45, "BDF": BDF}


class _HybridSimulation:
    def __init__(
        self,
        m: ModelConstants,
        currents: np.ndarray,
        dt: float,
        y0: np.ndarray,
        rtol: float,
        atol,
        method: str,
    ):
        if method not in _METHODS:
            raise ValueError(f"method must be one of {sorted(_METHODS)}, got {method!r}")
        self.m = m
        self.currents = currents
        self.dt = dt
        self.y = y0.copy()
        self.y0 = y0.copy()
        self.rtol = rtol
        self.atol = atol
        self.method = method
        self.t_end = len(currents) * dt
        self.use_tube = m.tau > 0.0
        self.literal = m.coupling == COUPLING_LITERAL and self.use_tube
        # literal coupling: dense outputs of the computed past
        self.hist_t0: list[float] = []
        self.hist_sol: list = []
        # segment-wise constants
        self.i_now = 0.0
        self.i_delayed = 0.0
        self.delayed_active = False
        # discrete state
        self.turbulent = [False] * 4
        self.piston = "fixed" if m.piston_mode == PISTON_FIXED else "rest"
        self.slip_dir = 0.0
        self.stop_side = 0.0  # -1/+1 while resting at an end stop
        self._cache_key = None
        self._cache_val = None
        self._surf_key = None
        self._surf_val = None
        self.kinds = self.surface_kinds()
        self.fired: dict[int, tuple[float, float]] = {}  # kink surface -> (time, side)
        self.fire_count: dict[int, int] = {}  # kink surface -> firings in this sub-interval
        # below this distance a kink surface counts as "on the surface" at a restart
        tiny = 10.0 * max(rtol, 1e-13)
        self.surface_noise = np.array(
            [
                0.0 if kind == "regime" else tiny * (m.r_h if j < 4 else m.p_a)
                for kind, j in self.kinds
            ]
        )
        self.n_events = 0
        self.small_first_step = 0.0

    # ---- delayed quantities -----------------------------------------------------------
    def delayed_pressures(self, t: float) -> tuple[float, float]:
        """``P1(t - tau), P2(t - tau)``; the initial state before ``t = 0``."""
        s = t - self.m.tau
        if s <= 0.0 or not self.hist_sol:
            return self.y0[IX_P1], self.y0[IX_P2]
        j = bisect.bisect_right(self.hist_t0, s) - 1
        j = min(max(j, 0), len(self.hist_sol) - 1)
        yy = self.hist_sol[j](s)
        return float(yy[IX_P1]), float(yy[IX_P2])

    # ---- right-hand side --------------------------------------------------------------
    def valve_pressures(self, t: float, y: np.ndarray) -> tuple[float, float]:
        """Chamber pressures the valve flows are evaluated with: current (command
        coupling) or delayed (literal coupling, Eq. 55 as printed)."""
        if self.literal:
            return self.delayed_pressures(t)
        return y[IX_P1], y[IX_P2]

    def valve_flows(self, t: float, y: np.ndarray) -> tuple[float, float, float, float]:
        """Signed valve flows into the chambers of the four paths (before the tube),
        evaluated with the delayed spool position ``x_s(t - tau)``."""
        m = self.m
        x_d = y[IX_XD]
        p1b, p2b = self.valve_pressures(t, y)
        a_in = orifice_area(m, x_d)
        a_ex = orifice_area(m, -x_d)
        return (
            orifice_mass_flow(m, a_in, m.p_s, p1b),
            orifice_mass_flow(m, a_ex, m.p_a, p1b),
            orifice_mass_flow(m, a_ex, m.p_s, p2b),
            orifice_mass_flow(m, a_in, m.p_a, p2b),
        )

    def evaluate(self, t: float, y: np.ndarray):
        """``(dy/dt, valve flows, applied force F_p - F_L)``, cached for the last point."""
        key = (t, y.tobytes())
        if key == self._cache_key:
            return self._cache_val
        m = self.m
        p1, p2, x, v = y[IX_P1], y[IX_P2], y[IX_X], y[IX_V]
        q = self.valve_flows(t, y)
        # tube: attenuate each path's flow by phi at the chamber pressure
        p_ch = (p1, p1, p2, p2)
        mdot_in = [0.0, 0.0]
        mdot_out = [0.0, 0.0]
        for j in range(4):
            qj = q[j]
            if qj == 0.0:
                continue
            if self.use_tube:
                re = reynolds_number(m, qj)
                qj *= tube_attenuation(m, tube_resistance(m, re, self.turbulent[j]), p_ch[j])
            c = PATH_CHAMBER[j]
            if qj > 0.0:
                mdot_in[c] += qj
            else:
                mdot_out[c] -= qj
        if m.a_leak > 0.0:  # leakage between the chambers, no tube (Sec. 2.2)
            ql = orifice_mass_flow(m, m.a_leak, p2, p1)
            if ql > 0.0:
                mdot_in[0] += ql
                mdot_out[1] += ql
            else:
                mdot_out[0] -= ql
                mdot_in[1] -= ql
        # piston
        f_applied = pneumatic_force(m, p1, p2) - load_force(m, x)
        if self.piston == "slip":
            xdot, vdot = v, piston_acceleration(m, f_applied, v, self.slip_dir)
        else:
            xdot, vdot = 0.0, 0.0
        v1, v2 = chamber_volumes(m, x)
        dy = np.empty(N_Y)
        dy[IX_XS] = y[IX_VS]
        dy[IX_VS] = spool_acceleration(m, y[IX_XS], y[IX_VS], self.i_now)
        if self.delayed_active:
            dy[IX_XD] = y[IX_VD]
            dy[IX_VD] = spool_acceleration(m, y[IX_XD], y[IX_VD], self.i_delayed)
        else:
            dy[IX_XD] = 0.0
            dy[IX_VD] = 0.0
        dy[IX_P1] = chamber_pressure_rate(m, p1, v1, m.a1 * xdot, mdot_in[0], mdot_out[0])
        dy[IX_P2] = chamber_pressure_rate(m, p2, v2, -m.a2 * xdot, mdot_in[1], mdot_out[1])
        dy[IX_X] = xdot
        dy[IX_V] = vdot
        self._cache_key = key
        self._cache_val = (dy, q, f_applied)
        return self._cache_val

    def rhs(self, t, y):
        return self.evaluate(t, y)[0]

    def applied_force(self, y) -> float:
        m = self.m
        return pneumatic_force(m, y[IX_P1], y[IX_P2]) - load_force(m, y[IX_X])

    # ---- events -----------------------------------------------------------------------
    # Switching surfaces g(t, y) = 0 of the right-hand side. "regime" surfaces switch the
    # tube flow regime of a path (a jump of the right-hand side); "kink" surfaces only
    # restart the integration where the right-hand side loses smoothness, so that no
    # step of the high-order method straddles them.
    def surface_kinds(self) -> list[tuple[str, int]]:
        m = self.m
        kinds: list[tuple[str, int]] = []
        if self.use_tube:
            kinds += [("regime", j) for j in range(4)]
        kinds += [("kink", j) for j in range(4)]  # delayed spool at the hole edges
        n_pairs = 5 if m.a_leak > 0.0 else 4
        kinds += [("kink", 4 + j) for j in range(n_pairs)]  # flow reversal (alpha switch)
        kinds += [("kink", 9 + j) for j in range(n_pairs)]  # choking ratio P_cr
        if m.r_lin < 1.0:
            kinds += [("kink", 14 + j) for j in range(n_pairs)]  # linearisation ratio
        return kinds

    def surfaces(self, t: float, y: np.ndarray) -> np.ndarray:
        key = (t, y.tobytes())
        if key == self._surf_key:
            return self._surf_val
        m = self.m
        x_d = y[IX_XD]
        p1b, p2b = self.valve_pressures(t, y)
        pairs = [(m.p_s, p1b), (m.p_a, p1b), (m.p_s, p2b), (m.p_a, p2b)]
        if m.a_leak > 0.0:
            pairs.append((y[IX_P2], y[IX_P1]))
        vals = []
        if self.use_tube:
            q = self.valve_flows(t, y)
            vals += [reynolds_number(m, qj) - m.re_t for qj in q]
        e0, e1 = m.p_w - m.r_h, m.p_w + m.r_h
        vals += [x_d - e0, -x_d - e0, x_d - e1, -x_d - e1]
        vals += [b - a for a, b in pairs]
        vals += [max(a, b) * m.p_cr - min(a, b) for a, b in pairs]
        if m.r_lin < 1.0:
            vals += [max(a, b) * m.r_lin - min(a, b) for a, b in pairs]
        self._surf_key = key
        self._surf_val = np.asarray(vals)
        return self._surf_val

    def make_events(self, t0: float) -> _EventSet:
        """The events to watch from ``t0`` on, in the present discrete state."""
        idx, directions, actions = [], [], []
        g0 = self.surfaces(t0, self.y)
        for e, (kind, j) in enumerate(self.kinds):
            if kind == "regime":
                direction = -1.0 if self.turbulent[j] else 1.0
            elif self.fire_count.get(e, 0) >= 3:
                # the solution hovers on a kink (e.g. a chamber pressure converging to
                # the supply pressure): stop restarting there until the next sub-interval
                continue
            elif e in self.fired and t0 - self.fired[e][0] <= 1e-12 * max(1.0, t0):
                direction = -self.fired[e][1]  # just crossed: watch the way back
            elif abs(g0[e]) <= self.surface_noise[e]:
                continue  # on the surface (e.g. a chamber at exactly ambient)
            elif g0[e] > 0.0:
                direction = -1.0
            else:
                direction = 1.0
            idx.append(e)
            directions.append(direction)
            actions.append((kind, j, e, direction))
        if self.piston == "slip":
            s = self.slip_dir
            directions += [-s, s]  # velocity back through zero; end stop reached
            actions += [("velocity_zero",), ("end_stop", s)]
        elif self.piston == "rest":
            for d in (1.0, -1.0):
                if d != self.stop_side:  # pushing into a stop does not move the piston
                    directions.append(1.0)
                    actions.append(("break_away", d))
        return _EventSet(self, np.array(idx, dtype=int), np.array(directions), actions)

    def piston_event_values(self, y: np.ndarray, actions) -> list[float]:
        """Event functions of the piston mode (see :meth:`make_events`)."""
        if self.piston == "slip":
            return [y[IX_V], y[IX_X] - self.slip_dir * 0.5 * self.m.stroke]
        if self.piston == "rest":
            f = self.applied_force(y)
            return [a[1] * f - self.m.f_stick for a in actions]
        return []

    def settle_at_rest(self) -> None:
        """The piston is at rest: stick, or break away at once if the applied force
        already exceeds the stick threshold in an allowed direction."""
        m = self.m
        self.y[IX_V] = 0.0
        self.piston = "rest"
        self.slip_dir = 0.0
        f = self.applied_force(self.y)
        for d in (1.0, -1.0):
            if d != self.stop_side and d * f > m.f_stick:
                self.piston = "slip"
                self.slip_dir = d
                self.stop_side = 0.0
                return

    def apply(self, action, t: float) -> None:
        kind = action[0]
        if kind == "regime":
            j = action[1]
            self.turbulent[j] = not self.turbulent[j]
        elif kind == "kink":
            e = action[2]
            self.fired[e] = (t, action[3])
            self.fire_count[e] = self.fire_count.get(e, 0) + 1
            if action[1] < 4:
                # a hole edge: the area grows like x_e^(3/2) from here, a singularity
                # that embedded error estimates miss; start with a tiny step
                self.small_first_step = FIRST_STEP_AFTER_EDGE
        elif kind == "velocity_zero":
            self.stop_side = 0.0
            self.settle_at_rest()
        elif kind == "end_stop":
            s = action[1]
            self.y[IX_X] = s * 0.5 * self.m.stroke
            self.stop_side = s
            self.settle_at_rest()
        elif kind == "break_away":
            self.piston = "slip"
            self.slip_dir = action[1]
            self.stop_side = 0.0
            self.y[IX_V] = 0.0
        else:  # pragma: no cover
            raise AssertionError(kind)
        self._cache_key = None
        self._surf_key = None

    def init_discrete_state(self) -> None:
        m = self.m
        y = self.y
        half = 0.5 * m.stroke
        if self.use_tube:
            q = self.valve_flows(0.0, y)
            self.turbulent = [reynolds_number(m, qj) >= m.re_t for qj in q]
        if m.piston_mode == PISTON_FIXED:
            self.piston = "fixed"
            return
        v = y[IX_V]
        if abs(y[IX_X]) >= half:
            self.stop_side = math.copysign(1.0, y[IX_X])
            y[IX_X] = self.stop_side * half
            if v * self.stop_side >= 0.0:
                self.settle_at_rest()
                return
        if v != 0.0:
            self.piston = "slip"
            self.slip_dir = math.copysign(1.0, v)
            self.stop_side = 0.0
        else:
            self.settle_at_rest()

    # ---- driver -----------------------------------------------------------------------
    def breakpoints(self) -> np.ndarray:
        n = len(self.currents)
        grid = np.arange(n + 1) * self.dt
        pts = list(grid)
        tau = self.m.tau
        if self.use_tube:
            pts += [t + tau for t in grid[:-1] if t + tau < self.t_end]
        pts = np.unique(np.asarray(pts))
        # merge points closer than a tiny tolerance, keeping control-grid points
        tol = 1e-12 * max(1.0, self.t_end)
        keep = [pts[0]]
        for p in pts[1:]:
            if p - keep[-1] > tol:
                keep.append(p)
            elif np.min(np.abs(grid - p)) < np.min(np.abs(grid - keep[-1])):
                keep[-1] = p
        pts = np.asarray(keep)
        if self.literal:  # method of steps: sub-intervals no longer than tau
            sub = [pts[0]]
            for a, b in zip(pts[:-1], pts[1:]):
                k = int(math.ceil((b - a) / tau - 1e-9))
                sub += list(np.linspace(a, b, k + 1)[1:])
            pts = np.asarray(sub)
        return pts

    def integrate(
        self,
        t0: float,
        t1: float,
        y0: np.ndarray,
        events: _EventSet | None,
        first_step: float | None = None,
    ) -> _Piece:
        """Integrate ``[t0, t1]`` in the present discrete state, stopping at the first
        event.

        The event functions are checked at ``EVENT_SAMPLES`` points of every step's
        dense output, not only at the step ends as ``solve_ivp`` does, so that a surface
        crossed twice within one step (a brief excursion of the Reynolds number above
        ``Re_t``, a velocity reversal) is not missed. The root is then found with
        ``brentq`` on the dense output.
        """
        solver = _METHODS[self.method](
            self.rhs, t0, y0, t1, rtol=self.rtol, atol=self.atol, first_step=first_step
        )
        if events is not None and len(events) == 0:
            events = None
        if events is not None:
            directions = events.directions
            g_old = events.values(t0, y0)
        dense_steps: list[tuple[float, float, object]] = []
        while True:
            t_old, y_old = solver.t, solver.y.copy()
            solver.step()
            if solver.status == "failed":
                raise RuntimeError(
                    f"integration failed at t = {t_old}: step size {solver.step_size}"
                )
            t_new = solver.t
            dense = solver.dense_output() if (events is not None or self.literal) else None
            if events is not None:
                s = t_old + (t_new - t_old) * np.arange(1, EVENT_SAMPLES + 1) / EVENT_SAMPLES
                s[-1] = t_new
                ys = dense(s)
                s_prev, g_prev = t_old, g_old
                for i in range(EVENT_SAMPLES):
                    y_i = ys[:, i] if i < EVENT_SAMPLES - 1 else solver.y
                    g = events.values(s[i], y_i)
                    active = _active_events(g_prev, g, directions)
                    if active.size:
                        roots = [_event_root(events, e, dense, s_prev, s[i]) for e in active]
                        j = int(np.argmin(roots))
                        t_ev = roots[j]
                        y_ev = y_old if t_ev <= t_old else dense(t_ev)
                        return _Piece(t_ev, y_ev, int(active[j]), t_old, y_old, dense_steps)
                    s_prev, g_prev = s[i], g
                g_old = g_prev
            if self.literal:
                dense_steps.append((t_old, t_new, dense))
            if solver.status == "finished":
                return _Piece(t_new, solver.y.copy(), None, t_old, y_old, dense_steps)

    def add_history(self, dense_steps) -> None:
        """Keep the dense outputs of the computed past (literal coupling)."""
        for t0, t1, dense in dense_steps:
            if t1 > t0:
                self.hist_t0.append(t0)
                self.hist_sol.append(dense)

    def current_at(self, t: float) -> float:
        k = int(math.floor(t / self.dt))
        return float(self.currents[min(max(k, 0), len(self.currents) - 1)])

    def run(self) -> dict:
        m = self.m
        n = len(self.currents)
        out = {key: np.empty(n + 1) for key in ("p1", "p2", "x", "v", "f", "x_s")}
        out["t"] = np.arange(n + 1) * self.dt
        self.init_discrete_state()

        def record(k):
            y = self.y
            out["p1"][k] = y[IX_P1]
            out["p2"][k] = y[IX_P2]
            out["x"][k] = y[IX_X]
            out["v"][k] = y[IX_V]
            out["f"][k] = output_force(m, y[IX_P1], y[IX_P2], y[IX_X])
            out["x_s"][k] = y[IX_XS]

        record(0)
        pts = self.breakpoints()
        k_out = 1
        for a, b in zip(pts[:-1], pts[1:]):
            mid = 0.5 * (a + b)
            self.i_now = self.current_at(mid)
            if self.use_tube:
                active = mid > m.tau
                if active and not self.delayed_active:
                    # the delayed spool's history ends at t = tau: from there on it
                    # repeats the spool's trajectory from the initial spool state
                    self.y[IX_XD] = self.y0[IX_XS]
                    self.y[IX_VD] = self.y0[IX_VS]
                self.delayed_active = active
                self.i_delayed = self.current_at(mid - m.tau) if active else 0.0
            else:
                self.delayed_active = True
                self.i_delayed = self.i_now
            self._cache_key = None
            self._surf_key = None
            self.fire_count.clear()
            t = a
            stalls = 0
            while b - t > 1e-14 * max(1.0, b):
                events = self.make_events(t)
                first_step = None
                if self.small_first_step:
                    first_step = min(self.small_first_step, 0.5 * (b - t))
                    self.small_first_step = 0.0
                res = self.integrate(t, b, self.y, events, first_step)
                t_new = res.t_end
                if res.event is not None and t_new > res.t_step:
                    # The step that found the event straddled the switching surface, so
                    # its interpolant at the root is polluted by right-hand-side values
                    # from beyond the surface: redo that step up to the root.
                    self.add_history(res.dense_steps)
                    redo = self.integrate(res.t_step, t_new, res.y_step, None)
                    self.add_history(redo.dense_steps)
                    self.y = redo.y_end.copy()
                else:
                    self.add_history(res.dense_steps)
                    self.y = res.y_end.copy()
                self._cache_key = None
                self._surf_key = None
                if res.event is not None:
                    self.apply(events.actions[res.event], t_new)
                    self.n_events += 1
                    stalls = stalls + 1 if t_new - t <= 1e-13 * max(1.0, t_new) else 0
                    if stalls > 50:
                        raise RuntimeError(f"event chattering at t = {t_new}")
                t = t_new
            while k_out <= n and abs(out["t"][k_out] - b) <= 1e-9 * self.dt:
                record(k_out)
                k_out += 1
        if k_out != n + 1:  # pragma: no cover
            raise AssertionError("missed an output time")
        return out
