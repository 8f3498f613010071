"""Residual control: a bounded learned correction on top of a classical controller.

The policy's action ``a`` in [-1, 1] is added to the classical controller's current,

    u = clip(u_b + correction_fraction * i_max * g * a, -i_max, i_max),

where ``u_b`` is the output of the benchmark's sliding mode or PID (per-variant gains from
``configs/agents/<name>-<variant>.yaml``) and ``g`` an optional gate in [0, 1] that shrinks
the bound on slow references (:func:`residual_gate`; off by default). Zero action is the
classical controller, bit for bit, so training starts at its performance (Johannink et
al., ICRA 2019; Silver et al., 2018). The observation gets two columns after the env's:
``base_current`` (u_b, A) and ``base_error`` (the controller's error estimate divided by
the reference scale: the sliding mode's predicted error ``f^(k+d) - r(k+lead)``, else
``y - r(k)``). The sliding mode is told the applied current (``applied``), so its
predictor knows the command in flight.

Three ways in, all with the same numbers:

* ``ResidualWrapper(gym.make(id, preview_steps=20), base="sliding_mode")``: a
  ``gym.Wrapper`` for any single-env algorithm (SB3: ``make_vec_env`` over it);
* ``ResidualVectorWrapper(gym.make_vec(id, num_envs=n, preview_steps=20))`` over the
  native vector env (the final observation of a truncated episode gets its columns too);
* registered ids: ``gym.make("pneumatic_env.agents.residual:pneumatic_env/ResidualForceTrack-
  Numatics-2m-v0", correction_fraction=0.15)`` and the same id with ``gym.make_vec``
  (the module prefix imports this module, which registers them); the residual keywords
  (:class:`ResidualConfig`) and the env's are given together.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass, fields

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import batch_space

from pneumatic_env import ids
from pneumatic_env.envs.observation import OBS_F, OBS_REF, observation_dim

from .base import Controller, ControllerContext

__all__ = [
    "ResidualConfig",
    "ResidualCore",
    "ResidualWrapper",
    "ResidualVectorWrapper",
    "residual_gate",
    "make_base_controller",
    "env_variant",
    "residual_env_id",
    "RESIDUAL_COLUMNS",
    "BASE_CONTROLLERS",
]

RESIDUAL_COLUMNS = ("base_current", "base_error")
BASE_CONTROLLERS = ("sliding_mode", "pid")


@dataclass(frozen=True)
class ResidualConfig:
    """How the correction is bounded and what it sits on."""

    base: str = "sliding_mode"  # one of BASE_CONTROLLERS
    correction_fraction: float = 0.15  # bound of the correction, fraction of i_max
    gate_floor: float = 1.0  # residual_gate's floor; >= 1: no gate
    gate_scale: float = 0.3  # reference span (fraction of the scale) that opens the gate
    gate_steps: int = 20  # preview steps the gate looks at
    consistent_predictor: bool = True  # tell the base controller the applied current
    variant: str | None = None  # whose gains (default: the env's cylinder and tube)

    def validate(self) -> None:
        if self.base not in BASE_CONTROLLERS:
            raise ValueError(
                f"base = {self.base!r} is not allowed: use one of {list(BASE_CONTROLLERS)}"
            )
        for name, low in (("correction_fraction", 0.0), ("gate_floor", 0.0)):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= low):
                raise ValueError(
                    f"{name} = {value!r} is not allowed: must be a finite number >= {low:g}"
                )
        if not (np.isfinite(self.gate_scale) and self.gate_scale > 0):
            raise ValueError(
                f"gate_scale = {self.gate_scale!r} is not allowed: must be a finite number > 0"
            )
        if int(self.gate_steps) != self.gate_steps or self.gate_steps < 0:
            raise ValueError(
                f"gate_steps = {self.gate_steps!r} is not allowed: must be an integer >= 0"
            )

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def split(cls, kwargs: dict) -> tuple[ResidualConfig, dict]:
        """(the residual keywords of ``kwargs`` as a config, the rest)."""
        names = {f.name for f in fields(cls)}
        config = cls(**{k: v for k, v in kwargs.items() if k in names})
        return config, {k: v for k, v in kwargs.items() if k not in names}


def residual_gate(
    obs_si: np.ndarray, scale: float, floor: float, span_scale: float, steps: int = 20
) -> np.ndarray:
    """Bound of the correction relative to its range, per row:
    ``clip(floor + (max - min of r(k..k+steps)) / (span_scale * scale), 0, 1)``; ones when
    ``floor >= 1``. Slow references (a 1 Hz sine moves 4 % of the scale in 20 ms) get a
    small bound, fast ones and coming steps the full one."""
    if floor >= 1.0:
        return np.ones(obs_si.shape[0])
    r = obs_si[:, OBS_REF : OBS_REF + steps + 1]
    span = (r.max(axis=1) - r.min(axis=1)) / scale
    return np.clip(floor + span / span_scale, 0.0, 1.0)


def env_variant(env) -> str:
    """``"Numatics-2m"``: the cylinder and tube of an env (any wrappers, single or vector)."""
    core = env.unwrapped.core
    return ids.variant_id(core.cylinder, core.base_params["tube_length_m"])


def make_base_controller(name: str, context: ControllerContext, variant: str) -> Controller:
    """The benchmark's ``name`` controller with the gains of ``variant``, for ``context``."""
    from .registry import resolve_controller

    if name not in BASE_CONTROLLERS:
        raise ValueError(f"base = {name!r} is not allowed: use one of {list(BASE_CONTROLLERS)}")
    return resolve_controller(name, variant, preview_steps=context.preview_steps).build(context)


class ResidualCore:
    """The batched residual logic of the wrappers and of a learned residual controller.

    Per step: ``observe(obs)`` (the env's observation; its base columns go to the
    controller) -> the two residual columns; ``current(action)`` -> u; ``applied(u)``
    after choosing it. ``reset(rows)`` on new episodes; ``peek(obs, rows)`` gives the
    columns of final observations without changing the state.
    """

    def __init__(self, base: Controller, config: ResidualConfig):
        config.validate()
        self.base, self.config = base, config
        ctx = base.context
        self.base_dim = observation_dim(ctx.preview_steps)
        self.scale = float(ctx.scale_n)
        self.bound_a = config.correction_fraction * ctx.i_max_a
        self.i_max = ctx.i_max_a
        self.base_time_s = 0.0
        self._obs: np.ndarray | None = None

    def reset(self, rows=None) -> None:
        self.base.reset(rows)

    @staticmethod
    def _plain_error(obs_si) -> np.ndarray:
        return obs_si[:, OBS_F] - obs_si[:, OBS_REF]

    def _columns(self, current, error) -> np.ndarray:
        return np.stack([current, np.asarray(error) / self.scale], axis=1).astype(np.float32)

    def observe(self, obs) -> np.ndarray:
        """Run the base controller on the base columns of ``obs`` (n rows); returns the
        residual columns (n, 2) float32."""
        t0 = time.perf_counter()
        self._obs = np.asarray(obs, dtype=np.float64)[:, : self.base_dim]
        self.u_base = self.base.act(self._obs)
        si = self.base.observation_si(self._obs)
        error = getattr(self.base, "last_error", None)
        if error is None or not hasattr(self.base, "peek"):
            error = self._plain_error(si)
        self.gate = residual_gate(
            si, self.scale, self.config.gate_floor, self.config.gate_scale, self.config.gate_steps
        )
        self.base_time_s += time.perf_counter() - t0
        return self._columns(self.u_base, error)

    def current(self, action) -> np.ndarray:
        """u = clip(u_b + bound g a) (A) for actions in [-1, 1] (clipped to it)."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        self._correction = self.bound_a * self.gate * a
        return np.clip(self.u_base + self._correction, -self.i_max, self.i_max)

    def applied(self, current) -> None:
        """Tell the base controller the current applied after the last ``observe`` (rows
        with a correction; where it is zero the controller's own command was applied)."""
        if self.config.consistent_predictor and hasattr(self.base, "applied"):
            t0 = time.perf_counter()
            self.base.applied(self._obs, current, np.flatnonzero(self._correction != 0.0))
            self.base_time_s += time.perf_counter() - t0

    def follow(self, current) -> None:
        """Tell the base controller the current another controller chose after the last
        ``observe`` (a pure policy it teaches, ``agents.teacher``)."""
        self._correction = np.asarray(current, dtype=np.float64) - self.u_base
        self.applied(current)

    def peek(self, obs, rows) -> np.ndarray:
        """Residual columns for final observations ``obs`` of ``rows`` (no state change)."""
        t0 = time.perf_counter()
        o = np.asarray(obs, dtype=np.float64)[:, : self.base_dim]
        if hasattr(self.base, "peek"):
            current, error = self.base.peek(o, rows)
        else:  # a copy of the controller acts on the batch with those rows replaced
            batch = self._obs.copy()
            batch[rows] = o
            current = copy.deepcopy(self.base).act(batch)[rows]
            error = self._plain_error(self.base.observation_si(o))
        self.base_time_s += time.perf_counter() - t0
        return self._columns(current, error)


def _residual_core(env, base, config: ResidualConfig) -> ResidualCore:
    ctx = ControllerContext.from_env(env)
    if isinstance(base, Controller):
        controller = base
    else:
        config = ResidualConfig(**{**config.as_dict(), "base": base})
        config.validate()
        controller = make_base_controller(base, ctx, config.variant or env_variant(env))
    return ResidualCore(controller, config)


def _box(dim: int) -> gym.spaces.Box:
    return gym.spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)


ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)


class ResidualWrapper(gym.Wrapper):
    """A single env with residual actions in [-1, 1] and the two residual columns.

    ``base``: ``"sliding_mode"`` or ``"pid"`` (the benchmark's gains for the env's variant
    or ``variant``) or a ``Controller``; the other keywords: :class:`ResidualConfig`.
    ``info["base_current_a"]``: the classical controller's current of the step.
    """

    def __init__(self, env: gym.Env, base: str | Controller = "sliding_mode", **config):
        super().__init__(env)
        self.residual = _residual_core(env, base, ResidualConfig(**config))
        self.action_space = ACTION_SPACE
        self.observation_space = _box(env.observation_space.shape[0] + len(RESIDUAL_COLUMNS))

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.residual.reset()
        return self._observe(obs), info

    def _observe(self, obs):
        return np.concatenate([obs, self.residual.observe(obs[None])[0]])

    def step(self, action):
        u = self.residual.current(action)
        self.residual.applied(u)
        obs, reward, terminated, truncated, info = self.env.step(u)
        info["base_current_a"] = float(self.residual.u_base[0])
        return self._observe(obs), reward, terminated, truncated, info


class ResidualVectorWrapper(gym.vector.VectorWrapper):
    """The native vector env with residual actions (``(num_envs, 1)`` in [-1, 1]) and the
    two residual columns; arguments as :class:`ResidualWrapper`. Needs same-step
    autoreset (``info["final_obs"]`` gets the columns of the final observations)."""

    def __init__(
        self, env: gym.vector.VectorEnv, base: str | Controller = "sliding_mode", **config
    ):
        super().__init__(env)
        self.residual = _residual_core(env, base, ResidualConfig(**config))
        self.single_action_space = ACTION_SPACE
        self.action_space = batch_space(ACTION_SPACE, env.num_envs)
        self.single_observation_space = _box(
            env.single_observation_space.shape[0] + len(RESIDUAL_COLUMNS)
        )
        self.observation_space = batch_space(self.single_observation_space, env.num_envs)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.residual.reset()
        return np.concatenate([obs, self.residual.observe(obs)], axis=1), info

    def step(self, actions):
        u = self.residual.current(actions)
        self.residual.applied(u)
        obs, reward, terminated, truncated, info = self.env.step(u[:, None])
        done = np.flatnonzero(np.logical_or(terminated, truncated))
        if done.size:
            final = info["final_obs"]
            cols = self.residual.peek(np.stack([final[i] for i in done]), done)
            final = final.copy()
            for j, i in enumerate(done):
                final[i] = np.concatenate([final[i], cols[j]])
            info["final_obs"] = final
            self.residual.reset(done)
        info["base_current_a"] = self.residual.u_base.copy()
        obs = np.concatenate([obs, self.residual.observe(obs)], axis=1)
        return obs, reward, terminated, truncated, info


# --------------------------------------------------------------------------- registered ids


def residual_env_id(env_id: str) -> str:
    """``pneumatic_env/ForceTrack-Numatics-2m-v0`` -> ``pneumatic_env/ResidualForceTrack-
    Numatics-2m-v0`` (registered when this module is imported)."""
    e = ids.parse_env_id(env_id)
    return f"{ids.ENV_NAMESPACE}/Residual{e.task}-{e.variant}-v{ids.ENV_VERSION}"


def _make_single(env_id: str, **kwargs) -> gym.Env:
    config, env_kwargs = ResidualConfig.split(kwargs)
    env_kwargs.pop("max_episode_steps", None)  # gym.make's TimeLimit wraps the outside
    return ResidualWrapper(gym.make(env_id, **env_kwargs).unwrapped, **config.as_dict())


def _make_vector(env_id: str, num_envs: int = 1, **kwargs) -> gym.vector.VectorEnv:
    config, env_kwargs = ResidualConfig.split(kwargs)
    return ResidualVectorWrapper(
        gym.make_vec(env_id, num_envs=num_envs, **env_kwargs), **config.as_dict()
    )


def _register() -> None:
    from .suite import suite_preview_steps

    preview = suite_preview_steps()
    for env_id in ids.registered_ids():
        if ids.parse_env_id(env_id).task != ids.FORCE_TRACK:
            continue
        rid = residual_env_id(env_id)
        if rid in gym.registry:
            continue
        gym.register(
            rid,
            entry_point=f"{__name__}:_make_single",
            vector_entry_point=f"{__name__}:_make_vector",
            max_episode_steps=ids.EPISODE_STEPS,
            kwargs={"env_id": env_id, "preview_steps": preview},
        )


_register()
