"""The rollout and the update of ``agents/ppo.py``: env steps of the policy with the
trainer's reward (computed from ``info`` to match the benchmark's RMS metric, config
``reward``) scaled by a running std of the discounted return, a bootstrap on time-limit
truncation (the vector env truncates and resets in the same step; V of
``info["final_obs"]`` is added to the last reward), GAE, and clipped-PPO epochs with the
teacher's imitation term (``agents.teacher``)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn

from .learned import pure_current
from .ppo_config import PPOFastConfig
from .ppo_networks import Agent
from .ppo_setup import row_deadband_a
from .teacher import Teacher, TeacherConfig

__all__ = ["RolloutBuffer", "Rollouts", "advantages", "imitation_loss", "ppo_update"]


@dataclass
class RolloutBuffer:
    """One update's transitions, (T, N) arrays of T env steps of N envs."""

    obs: np.ndarray  # (T, N, inputs): normalised policy inputs
    act: np.ndarray  # sampled action (before the clip)
    logp: np.ndarray
    rew: np.ndarray  # scaled reward, plus gamma V(final obs) where an episode was truncated
    done: np.ndarray  # transition t ended its episode
    val: np.ndarray  # (T + 1, N): V, and V of the observation after the rollout
    teach: np.ndarray  # the teacher's action (0 without a teacher)
    plant: np.ndarray  # (T, N, privileged inputs): the critic's own (``PlantInputs``)

    @classmethod
    def zeros(cls, T: int, N: int, D: int, P: int = 0) -> RolloutBuffer:
        act, logp, rew, done = (np.zeros((T, N), np.float32) for _ in range(4))
        val, teach = np.zeros((T + 1, N), np.float32), np.zeros((T, N), np.float32)
        plant = np.zeros((T, N, P), np.float32)
        return cls(np.zeros((T, N, D), np.float32), act, logp, rew, done, val, teach, plant)


class Rollouts:
    """The env side of training: the policy's inputs and their normaliser, actions to
    currents, the reward and its running scale, the teacher (``agents.teacher``)."""

    def __init__(self, cfg: PPOFastConfig, env, index, obs_rms, ret_rms, plant=None):
        self.cfg, self.env, self.index = cfg, env, index
        self.plant = plant  # the critic's privileged inputs (PlantInputs), or None
        self.obs_rms, self.ret_rms = obs_rms, ret_rms
        self.scale, self.i_max = env.unwrapped.reference_scale, env.unwrapped.coil_current_max_a
        self.residual = cfg.mode == "residual"
        self.t_env_s = 0.0  # in env.step (a residual's classical base included)

    def start(self, seed: int, updates: int, rng, warm: bool) -> None:
        """Reset (staggered episode starts), warm the normaliser on zero actions (a fresh
        run), then start the teacher."""
        n, cfg = self.cfg.hyperparameters.num_envs, self.cfg
        options = (
            {"start_step": rng.integers(0, cfg.training.episode_steps, n)}
            if cfg.training.stagger
            else None
        )
        self.obs, _ = self.env.reset(seed=seed * 100_000 + updates, options=options)
        self.feat = self.obs[:, self.index]
        zeros = np.zeros(n)
        for _ in range(20 if warm else 0):  # the classical (or zero-current) features
            self.obs_rms.update(self.feat)
            self.obs, *_ = self.env.step(zeros[:, None])
            self.feat = self.obs[:, self.index]
        self.prev_u, self.ret_acc = np.zeros(n), np.zeros(n)
        self.deadband = row_deadband_a(self.env)
        teacher_cfg, pure = TeacherConfig.from_config(cfg), cfg.pure
        self.teacher: Teacher | None = None
        if teacher_cfg:
            self.teacher = Teacher(
                self.env, teacher_cfg, pure.action_scale_a, self.deadband, pure.deadband_smoothing
            )
            self.teacher.reset()
        # the classical controller: a residual's base (inside env.step) or the teacher
        self.base = getattr(self.env, "residual", None) or self.teacher
        self.base_t0_s = self.base.base_time_s if self.base else 0.0

    def base_time_s(self) -> float:
        """Time in the classical controller since :meth:`start`."""
        return (self.base.base_time_s - self.base_t0_s) if self.base else 0.0

    def normalise(self, x: np.ndarray) -> np.ndarray:
        rms, clip = self.obs_rms, self.cfg.hyperparameters.clip_obs
        return np.clip((x - rms.mean) / np.sqrt(rms.var + 1e-8), -clip, clip).astype(np.float32)

    def collect(self, agent: Agent, buf: RolloutBuffer) -> tuple[float, float]:
        """Fill ``buf``; (sum over steps of the mean squared error in scale units, of the
        mean squared gap between the policy's mean and the teacher's action)."""
        sq_err = sq_gap = 0.0
        for t in range(len(buf.act)):
            self.obs_rms.update(self.feat)
            x = self.normalise(self.feat)
            plant = self._plant()
            with torch.no_grad():
                xt = torch.from_numpy(x)
                d = agent.dist(xt)
                a = d.sample()
                logp, v = d.log_prob(a).sum(-1), agent.value(xt, plant)
            a_np = a.numpy()[:, 0].astype(np.float64)
            if self.teacher:
                buf.teach[t] = self.teacher.targets(self.obs)
                sq_gap += float(np.nanmean((d.mean.numpy()[:, 0] - buf.teach[t]) ** 2))
            a_clip = np.clip(a_np, -1.0, 1.0)
            trunc, info = self._step(a_clip)
            sq_err += float(np.mean((info["tracking_error"] / self.scale) ** 2))
            rs = self._scaled_reward(info, a_clip, trunc)
            self._bootstrap(agent, rs, trunc, info, plant)
            buf.obs[t], buf.act[t], buf.logp[t], buf.val[t] = x, a_np, logp.numpy(), v.numpy()
            buf.rew[t], buf.done[t] = rs, trunc
            if plant is not None:
                buf.plant[t] = plant.numpy()
        with torch.no_grad():
            x = torch.from_numpy(self.normalise(self.feat))
            buf.val[-1] = agent.value(x, self._plant()).numpy()
        return sq_err, sq_gap

    def _plant(self) -> torch.Tensor | None:
        """The critic's privileged inputs of each lane's current episode, or None."""
        return None if self.plant is None else torch.from_numpy(self.plant())

    def _step(self, a_clip: np.ndarray):
        pure = self.cfg.pure
        act = (
            a_clip
            if self.residual
            else pure_current(
                a_clip, pure.action_scale_a, self.deadband, pure.deadband_smoothing, self.i_max
            )
        )
        if self.teacher:
            self.teacher.applied(act)
        t0 = time.perf_counter()
        self.obs, _, _, trunc, info = self.env.step(act[:, None])
        self.t_env_s += time.perf_counter() - t0
        if self.teacher and trunc.any():
            self.teacher.reset(np.flatnonzero(trunc))
        self.feat = self.obs[:, self.index]
        return trunc, info

    def _scaled_reward(self, info, a_clip: np.ndarray, trunc: np.ndarray) -> np.ndarray:
        """The reward (config ``reward``) over a running std of the discounted return."""
        rw = self.cfg.reward
        e = info["tracking_error"] / (rw.error_unit_fraction * self.scale)
        u = info["coil_current_a"]
        rew = (
            -(e**2)
            - rw.l1_weight * np.abs(e)
            - rw.chatter_weight * ((u - self.prev_u) / rw.chatter_unit_a) ** 2
            - rw.effort_weight * (u / rw.effort_unit_a) ** 2
            - (rw.residual_weight * a_clip**2 if self.residual else 0.0)
        )
        self.prev_u = np.where(trunc, 0.0, u)
        self.ret_acc = self.ret_acc * self.cfg.hyperparameters.gamma + rew
        self.ret_rms.update(self.ret_acc)
        self.ret_acc[trunc] = 0.0
        return rew / np.sqrt(self.ret_rms.var + 1e-8)

    def _bootstrap(self, agent: Agent, rs: np.ndarray, trunc: np.ndarray, info, plant) -> None:
        """Add gamma V(final obs) to the reward of each episode truncated at this step
        (``plant``: the critic's inputs before the step, the ended episodes' plants)."""
        if not trunc.any():
            return
        rows = np.flatnonzero(trunc)
        final = np.stack([info["final_obs"][r] for r in rows])[:, self.index]
        with torch.no_grad():
            x = torch.from_numpy(self.normalise(final))
            value = agent.value(x, None if plant is None else plant[rows]).numpy()
        rs[rows] += self.cfg.hyperparameters.gamma * value


# --------------------------------------------------------------------------- PPO update


def advantages(buf: RolloutBuffer, gamma: float, lam: float) -> np.ndarray:
    """GAE; ``done[t]``: transition t ended its episode (its bootstrap is in the reward)."""
    T, N = buf.rew.shape
    adv = np.zeros((T, N), np.float32)
    last = np.zeros(N, np.float32)
    for t in reversed(range(T)):
        nd = 1.0 - buf.done[t]
        delta = buf.rew[t] + gamma * buf.val[t + 1] * nd - buf.val[t]
        last = delta + gamma * lam * nd * last
        adv[t] = last
    return adv


def imitation_loss(teacher: Teacher | None, teach: torch.Tensor, frac: float, T: int):
    """The teacher's imitation term at ``frac`` of the budget, as f(mean action,
    minibatch rows); None without a teacher or once its weight is 0. Rows without a
    teacher (a generalist's untuned variants) have no term."""
    w = teacher.config.weight_at(frac) if teacher else 0.0
    if teacher is None or w <= 0:
        return None
    unit, mask = teacher.config.unit, torch.from_numpy(np.tile(teacher.taught, T))
    if teacher.taught.all():
        return lambda mean, idx: w * (((mean - teach[idx]) / unit) ** 2).mean()

    def masked(mean, idx):
        gap, m = (mean - teach[idx]) / unit, mask[idx]
        sq = torch.where(m, gap, torch.zeros_like(gap)) ** 2
        return w * sq.sum() / m.sum().clamp(min=1)

    return masked


def ppo_update(agent: Agent, opt, buf: RolloutBuffer, adv, hp, imitation, plant_weight=0.0):
    """Epochs of clipped-PPO minibatch steps (stopped above ``target_kl``); (the
    minibatches' approximate KLs, the last value loss, the last plant-prediction mean
    square or None). ``plant_weight``: the weight of the actor's plant head's mean square
    error on the critic's plant inputs (an auxiliary loss)."""
    T, N, D = buf.obs.shape
    B = T * N
    fo, fa = torch.from_numpy(buf.obs.reshape(B, D)), torch.from_numpy(buf.act.reshape(B, 1))
    fp = torch.from_numpy(buf.plant.reshape(B, -1)) if buf.plant.shape[-1] else None
    flp, fadv = torch.from_numpy(buf.logp.reshape(-1)), torch.from_numpy(adv.reshape(-1))
    fret = torch.from_numpy((adv + buf.val[:T]).reshape(-1))
    n_mb = hp.minibatches
    mb = B // n_mb
    kls: list[float] = []
    plant_mse = None
    for _ in range(hp.epochs):
        perm = torch.randperm(B)
        for s in range(0, mb * n_mb, mb):
            idx = perm[s : s + mb]
            obs_mb = fo[idx]
            d, plant_pred = agent.dist_and_plant(obs_mb)
            log_ratio = d.log_prob(fa[idx]).sum(-1) - flp[idx]
            ratio = log_ratio.exp()
            with torch.no_grad():
                kls.append(((ratio - 1) - log_ratio).mean().item())
            A = fadv[idx]
            A = (A - A.mean()) / (A.std() + 1e-8)
            clip = hp.clip_range
            pg = torch.max(-A * ratio, -A * ratio.clamp(1 - clip, 1 + clip)).mean()
            plant_mb = None if fp is None else fp[idx]
            vl = 0.5 * ((agent.value(obs_mb, plant_mb) - fret[idx]) ** 2).mean()
            loss = pg + hp.vf_coef * vl - hp.ent_coef * d.entropy().sum(-1).mean()
            if imitation is not None:
                loss = loss + imitation(d.mean[:, 0], idx)
            if plant_pred is not None:
                plant_mse = ((plant_pred - plant_mb) ** 2).mean()
                loss = loss + plant_weight * plant_mse
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(agent.parameters(), hp.max_grad_norm)
            opt.step()
            with torch.no_grad():
                agent.log_std.clamp_(min=hp.log_std_min)
        if hp.target_kl and np.mean(kls[-n_mb:]) > hp.target_kl:
            break
    return kls, vl.item(), None if plant_mse is None else plant_mse.item()
