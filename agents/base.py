"""The controller interface shared by the classical baselines and the learned policies.

A controller sees only the observation ``[p1, p2, x, f, ref(k), ref(k+1..k+H)]``
(``pneumatic_env.envs.observation``) and may use the model parameters (the env's
``base_params``); the simulator's state is never read. It is batched:
``act`` maps observations of shape ``(n, obs_dim)`` to coil currents ``(n,)`` in A, keeping
one internal state (integrator, filters, predictor buffers) per row.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pneumatic_env import params as P
from pneumatic_env.envs.observation import (
    OBS_F,
    OBS_P1,
    OBS_P2,
    OBS_REF,
    OBS_X,
    ObservationScales,
    observation_dim,
    observation_scales,
    observation_to_si,
)
from pneumatic_env.physics.derived import valve_currents_a

__all__ = [
    "OBS_P1",
    "OBS_P2",
    "OBS_X",
    "OBS_F",
    "OBS_REF",
    "ControllerContext",
    "Controller",
    "ZeroController",
    "ControllerSpec",
    "check_gain",
    "valve_currents",
]


@dataclass(frozen=True)
class ControllerContext:
    """What a controller may know about the env: model parameters and the observation layout."""

    base_params: dict
    dt_s: float
    preview_steps: int
    scale_n: float  # reference scale of the task (pneumatic_env.envs.tasks.scale_of)
    normalize_observation: bool
    force_scale_n: float | None = None  # divides the force channel when normalised

    @classmethod
    def from_env(cls, env) -> ControllerContext:
        """From a single env (any wrappers) or a native vector env, by their read-only
        properties."""
        e = env.unwrapped
        return cls(
            base_params=dict(e.base_params),
            dt_s=e.control_dt_s,
            preview_steps=e.preview_steps,
            scale_n=e.reference_scale,
            normalize_observation=e.normalize_observation,
            force_scale_n=e.force_scale_n,
        )

    @property
    def i_max_a(self) -> float:
        return float(self.base_params["coil_current_max_a"])

    @property
    def obs_dim(self) -> int:
        return observation_dim(self.preview_steps)

    @property
    def observation_scales(self) -> ObservationScales:
        """The env's ``observation_scales`` (``pneumatic_env.envs.observation``)."""
        return observation_scales(
            self.base_params,
            self.force_scale_n or self.scale_n,
            self.scale_n,
            self.normalize_observation,
        )

    def param_array(self) -> np.ndarray:
        """The (N_PARAMS, 1) parameter column for the jitted model functions."""
        return P.parameter_array([self.base_params])


def valve_currents(params: dict) -> tuple[float, float]:
    """Coil currents (A) at the edge of the dead band and at full opening (Eqs. 43, 44, 46).

    The supply path opens when x_s > p_w - R_h and is fully open at x_s = p_w + R_h; Eq. 46
    (x_s = K_fc i / (2 k_s)) turns both spool positions into currents
    (``pneumatic_env.physics.derived.valve_currents_a``).
    """
    return valve_currents_a(
        params["spool_half_width_m"],
        params["hole_radius_m"],
        params["spool_spring_n_per_m"],
        params["coil_force_n_per_a"],
    )


def check_gain(owner: str, name: str, value, *, ge: float | None = 0.0, gt: float | None = None):
    """A gain as float or float array, finite and within bounds; clear error otherwise."""
    arr = np.asarray(value, dtype=np.float64)
    rule = (
        f"must be a finite number > {gt:g}"
        if gt is not None
        else f"must be a finite number >= {ge:g}"
        if ge is not None
        else "must be finite"
    )
    if (
        not np.all(np.isfinite(arr))
        or (gt is not None and np.any(arr <= gt))
        or (ge is not None and np.any(arr < ge))
    ):
        raise ValueError(f"{owner}: {name} = {value!r} is not allowed: {rule}")
    return arr if arr.ndim else float(arr)


class Controller:
    """Base class: ``reset(envs=None)``, ``act(obs) -> current (A)``, batched over rows.

    Subclasses implement ``_reset_rows(rows)`` (clear the state of those rows) and
    ``_act(obs_si) -> current`` on float64 observations in SI units, shape (n, obs_dim).
    ``env_options`` are the env keyword arguments the controller needs (observation layout).
    """

    name = "controller"

    def __init__(self, context: ControllerContext):
        self.context = context
        self.n_envs: int | None = None
        self.smoothing_steps: int | np.ndarray = 0  # set_reference_smoothing
        self._past_reference: np.ndarray | None = None  # (n, W): ref(k - W .. k - 1)

    @property
    def env_options(self) -> dict:
        return {
            "preview_steps": self.context.preview_steps,
            "normalize_observation": self.context.normalize_observation,
        }

    def reset(self, envs=None) -> None:
        """Forget the state of every env (``envs=None``) or of the listed env indices."""
        if envs is None or self.n_envs is None:
            self.n_envs = None
            return
        rows = np.atleast_1d(np.asarray(envs, dtype=np.int64))
        if rows.size:
            if self._past_reference is not None:
                self._past_reference[rows] = np.nan
            self._reset_rows(rows)

    def act(self, obs) -> np.ndarray:
        """Coil current (A) per observation row; a single observation gives shape (1,)."""
        o = np.asarray(obs, dtype=np.float64)
        if o.ndim == 1:
            o = o[None, :]
        if o.ndim != 2 or o.shape[1] != self.context.obs_dim:
            raise ValueError(
                f"{type(self).__name__}.act: observation has shape "
                f"{np.shape(obs)}, expected (n, {self.context.obs_dim}) or "
                f"({self.context.obs_dim},) = [p1, p2, x, f, ref, "
                f"{self.context.preview_steps} preview samples]"
            )
        if self.n_envs != o.shape[0]:
            self.n_envs = o.shape[0]
            self._allocate(self.n_envs)
            width = int(np.max(self.smoothing_steps))
            self._past_reference = np.full((self.n_envs, width), np.nan) if width else None
        si = self.observation_si(o)
        current = self._act(self.smoothed_reference(si))
        past = self._past_reference
        if past is not None:  # ref(k) joins the last W references, in place
            now = si[:, OBS_REF : OBS_REF + 1]
            np.copyto(past, now, where=np.isnan(past))  # a new episode's: its first
            past[:, :-1] = past[:, 1:]
            past[:, -1:] = now
        return current

    def set_reference_smoothing(self, owner: str, steps) -> None:
        """``reference_smoothing_steps`` W (an integer >= 0 or one per env, at most the
        preview): the controller tracks the centred moving average of the reference over
        k - W .. k + W control periods (``smoothed_reference``); 0 leaves it as it is."""
        w = np.asarray(steps)
        h = self.context.preview_steps
        ok = np.issubdtype(w.dtype, np.number) and bool(  # not bool, not text
            np.all(np.isfinite(w) & (w == np.rint(w)) & (w >= 0) & (w <= h))
        )
        if not ok:
            raise ValueError(
                f"{owner}: reference_smoothing_steps = {steps!r} is not allowed: an integer "
                f"from 0 to the preview ({h} control periods), or one per env"
            )
        self.smoothing_steps = w.astype(np.int64) if w.ndim else int(w)

    def smoothed_reference(self, obs: np.ndarray, rows=None) -> np.ndarray:
        """SI rows ``obs`` (of the env rows ``rows``, default all) with ref(k + j), j = 0..H,
        replaced by its centred mean over ref(k + j - W .. k + j + W): the last W references
        before k (before a new episode: its first reference) and the preview, held at its last value
        beyond it. A step in the reference becomes a ramp over 2 W + 1 periods centred on
        it, which a loop that cannot follow a step tracks with a smaller RMS error. A copy;
        ``obs`` itself where W = 0."""
        if self._past_reference is None:
            return obs
        rows = slice(None) if rows is None else np.asarray(rows)
        past = self._past_reference[rows]
        ref = obs[:, OBS_REF:]
        width, h = past.shape[1], ref.shape[1]
        past = np.where(np.isnan(past), ref[:, :1], past)
        extended = np.concatenate([past, ref, np.repeat(ref[:, -1:], width, axis=1)], axis=1)
        cum = np.concatenate([np.zeros((ref.shape[0], 1)), np.cumsum(extended, axis=1)], axis=1)
        w = np.asarray(self.smoothing_steps)
        w = np.broadcast_to(w if w.ndim == 0 else w[rows], (ref.shape[0],))[:, None]
        centre = width + np.arange(h)[None, :]
        r = np.arange(ref.shape[0])[:, None]
        out = obs.copy()
        mean = (cum[r, centre + w + 1] - cum[r, centre - w]) / (2 * w + 1)
        out[:, OBS_REF:] = np.where(w > 0, mean, ref)  # rows with W = 0 as they were
        return out

    def observation_si(self, obs: np.ndarray) -> np.ndarray:
        """Undo ``normalize_observation`` so the controller works in SI
        (``pneumatic_env.envs.observation.observation_to_si``)."""
        return observation_to_si(obs, self.context.observation_scales)

    def reference_ahead(self, obs: np.ndarray, steps) -> np.ndarray:
        """ref(k + steps) per row from the preview (steps clipped to the preview length)."""
        idx = OBS_REF + np.clip(np.asarray(steps, dtype=np.int64), 0, self.context.preview_steps)
        return obs[np.arange(obs.shape[0]), np.broadcast_to(idx, (obs.shape[0],))]

    # -- to implement ----------------------------------------------------------------------
    def _allocate(self, n: int) -> None:
        """Create the per-env state for ``n`` envs (all rows reset)."""

    def _reset_rows(self, rows: np.ndarray) -> None:
        """Reset the state of ``rows``."""

    def _act(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class ZeroController(Controller):
    """Zero coil current: the valve stays closed (the do-nothing floor of the benchmark)."""

    name = "zero"

    def _act(self, obs):
        return np.zeros(obs.shape[0])


@dataclass
class ControllerSpec:
    """How to build a controller for a variant: env options first, then ``build(context)``."""

    name: str
    env_options: dict
    build: Callable[[ControllerContext], Controller]
    source: str = ""
