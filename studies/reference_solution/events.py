"""The event functions of the hybrid integrator (:mod:`.hybrid`): the set watched during one
integration, the result of an event-stopped integration and the location of a root."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import brentq


class SwitchingSurfaces(Protocol):
    """What an event set evaluates: the simulation's switching surfaces and its piston-mode
    event functions (``hybrid._HybridSimulation``)."""

    def surfaces(self, t: float, y: np.ndarray) -> np.ndarray: ...

    def piston_event_values(self, y: np.ndarray, actions: list) -> list[float]: ...


class _EventSet:
    """The event functions watched during one integration, evaluated all at once:
    selected switching surfaces, then the piston-mode events."""

    def __init__(
        self,
        sim: SwitchingSurfaces,
        surface_index: np.ndarray,
        directions: np.ndarray,
        actions: list,
    ):
        self.sim = sim
        self.surface_index = surface_index
        self.directions = directions
        self.actions = actions
        self.piston_actions = actions[len(surface_index) :]

    def __len__(self) -> int:
        return len(self.actions)

    def values(self, t: float, y: np.ndarray) -> np.ndarray:
        g = self.sim.surfaces(t, y)[self.surface_index]
        if self.piston_actions:
            g = np.concatenate([g, self.sim.piston_event_values(y, self.piston_actions)])
        return g


@dataclass
class _Piece:
    """Result of one event-stopped integration."""

    t_end: float
    y_end: np.ndarray
    event: int | None  # index of the event that stopped it
    t_step: float  # start of the last step
    y_step: np.ndarray
    dense_steps: list  # (t0, t1, dense output) of the completed steps (literal only)


def _active_events(g_old: np.ndarray, g_new: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Events whose function changed sign in their direction (solve_ivp's convention)."""
    up = (g_old <= 0) & (g_new >= 0)
    down = (g_old >= 0) & (g_new <= 0)
    return np.nonzero(
        (up & (direction > 0)) | (down & (direction < 0)) | ((up | down) & (direction == 0))
    )[0]


def _event_root(events: _EventSet, e: int, dense, t_a: float, t_b: float) -> float:
    """Root of event ``e`` along the dense output in ``[t_a, t_b]``."""

    def f(t):
        return events.values(t, dense(t))[e]

    fa, fb = f(t_a), f(t_b)
    if fa == 0.0:
        # The function starts on the surface (a slip phase starts at v = 0). It first
        # moves to the side the event watches crossings from, possibly only briefly
        # (the force can turn back within microseconds): find a point on that side.
        side = -events.directions[e]
        for t in t_a + (t_b - t_a) * np.geomspace(1e-9, 1.0, 40)[:-1]:
            ft = f(t)
            if ft * side > 0.0:
                t_a, fa = t, ft
                break
        else:
            return t_a
    if fb == 0.0:
        return t_b
    if fa * fb > 0.0:  # a sign change of round-off size between samples
        return t_a if abs(fa) < abs(fb) else t_b
    return brentq(f, t_a, t_b, xtol=4 * np.finfo(float).eps, rtol=4 * np.finfo(float).eps)
