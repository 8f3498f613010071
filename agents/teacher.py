"""A classical teacher for a pure policy's first updates (ppo_fast, ``pure.teacher``).

A pure policy learned from zero spends most of its budget finding what a sliding mode
already knows: hold the force on a slow reference without dithering around the valve's
dead band. With a teacher, PPO's loss gets an imitation term for the first part of the
budget: the squared distance between the policy's mean action and the action whose
current (``learned.pure_current``) equals the teacher's, on the states the policy itself
visits (so the labels are on the learner's distribution, as in DAgger, Ross et al. 2011).
Its weight falls linearly to zero, after which the policy-gradient term alone shapes the
policy, as in demo-augmented policy gradients (DAPG, Rajeswaran et al. 2018). The teacher
runs only in training; the exported actor is the network alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .generalist import MixtureVectorEnv
from .ppo_config import PPOFastConfig, PureSettings
from .registry import tuned_config_path
from .residual import ResidualConfig, env_variant
from .residual_env import residual_core as _residual_core

__all__ = ["TeacherConfig", "Teacher", "pure_action_for_current", "has_tuned_gains"]


@dataclass(frozen=True)
class TeacherConfig:
    """``pure.teacher*`` of a ppo_fast config."""

    name: str  # a classical controller (agents.residual.BASE_CONTROLLERS)
    weight: float  # imitation loss weight at the start
    unit: float  # action difference that costs ``weight`` (action units)
    fraction: float  # share of the budget (wall time or steps) over which the weight falls to 0

    @classmethod
    def from_config(cls, cfg: PPOFastConfig | Mapping) -> TeacherConfig | None:
        """The teacher of a config (or a tree with ``mode`` and ``pure``); None without."""
        if isinstance(cfg, Mapping):
            mode, pure = cfg.get("mode"), PureSettings.from_tree(cfg.get("pure") or {}, "pure")
        else:
            mode, pure = cfg.mode, cfg.pure
        if mode != "pure" or not pure.teacher:
            return None
        out = cls(pure.teacher, pure.teacher_weight, pure.teacher_unit, pure.teacher_fraction)
        for name in ("weight", "unit"):
            value = getattr(out, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(
                    f"pure.teacher_{name} = {value!r} is not allowed: must be a finite number > 0"
                )
        if not (0.0 < out.fraction <= 1.0):
            raise ValueError(
                f"pure.teacher_fraction = {out.fraction!r} is not allowed: must be in (0, 1]"
            )
        return out

    def weight_at(self, budget_fraction: float) -> float:
        """The imitation weight after ``budget_fraction`` of the budget (linear to 0)."""
        return self.weight * max(0.0, 1.0 - budget_fraction / self.fraction)


def _action_table(action_scale_a: float, deadband_a: float, smoothing: float):
    """(currents, actions) of ``learned.pure_current`` over [-1, 1], without the clip."""
    a = np.linspace(-1.0, 1.0, 4001)
    u = action_scale_a * a
    if smoothing > 0:
        u = u + deadband_a * np.tanh(a / smoothing)
    return u, a


def pure_action_for_current(
    current_a, action_scale_a: float, deadband_a: float, smoothing: float
) -> np.ndarray:
    """The action in [-1, 1] whose ``learned.pure_current`` is ``current_a`` (the map is
    increasing; currents beyond the action range go to its ends)."""
    u, a = _action_table(action_scale_a, deadband_a, smoothing)
    return np.interp(np.asarray(current_a, dtype=np.float64), u, a)


def has_tuned_gains(name: str, variant: str) -> bool:
    """Whether ``configs/agents/<name>-<variant>.yaml`` holds the benchmark's gains."""
    return tuned_config_path(name, variant).is_file()


class Teacher:
    """The teacher's action targets on a vector env's batch, step by step.

    ``targets(obs)`` before the step (the env's observation rows), ``applied(u)`` with the
    current the policy chose (the teacher's predictor of the commands in the tube must
    know them), ``reset(rows)`` for rows that start a new episode.

    On a mixture of variants (a generalist, ``agents.generalist.MixtureVectorEnv``) each
    variant with tuned gains (``configs/agents/<name>-<variant>.yaml``) gets its own
    teacher; the rows of the others have no target (NaN; ``taught`` is False there) and
    learn from the policy gradient alone."""

    def __init__(self, env, config: TeacherConfig, action_scale_a, deadband_a, smoothing):
        top = env.unwrapped
        mixture = isinstance(top, MixtureVectorEnv)
        subs, bounds = (top.envs, top.bounds) if mixture else ([env], (0, env.num_envs))
        deadbands = np.broadcast_to(np.asarray(deadband_a, dtype=np.float64), (bounds[-1],))
        self.config = config
        self.num_envs = int(bounds[-1])
        self.parts = []  # (rows, core, the action map's table (u, a)), built once per run
        for k, sub in enumerate(subs):
            if mixture and not has_tuned_gains(config.name, env_variant(sub)):
                continue
            rows = slice(int(bounds[k]), int(bounds[k + 1]))
            core = _residual_core(sub, config.name, ResidualConfig(base=config.name))
            table = _action_table(float(action_scale_a), float(deadbands[rows.start]), smoothing)
            self.parts.append((rows, core, table))
        if not self.parts:
            raise ValueError(
                f"pure.teacher = {config.name!r} is not allowed here: no variant of the "
                f"mixture has tuned gains (configs/agents/{config.name}-<variant>.yaml)"
            )
        self.taught = np.zeros(self.num_envs, dtype=bool)
        for rows, _, _ in self.parts:
            self.taught[rows] = True

    @property
    def base_time_s(self) -> float:
        """The teachers' summed time (s)."""
        return float(sum(core.base_time_s for _, core, _ in self.parts))

    def targets(self, obs) -> np.ndarray:
        out = np.full(self.num_envs, np.nan, dtype=np.float32)
        for rows, core, (u, a) in self.parts:
            core.observe(obs[rows])
            out[rows] = np.interp(core.u_base, u, a)
        return out

    def applied(self, current) -> None:
        for rows, core, _ in self.parts:
            core.follow(current[rows])

    def reset(self, rows=None) -> None:
        for part_rows, core, _ in self.parts:
            if rows is None:
                core.reset()
                continue
            mine = np.asarray(rows)
            mine = mine[(mine >= part_rows.start) & (mine < part_rows.stop)] - part_rows.start
            if mine.size:
                core.reset(mine)
