"""``pneumatic-env train --algo ppo_fast``: lean PPO over the native vector env (CleanRL style).

    pneumatic-env train --algo ppo_fast --env pneumatic_env/ForceTrack-Numatics-2m-v0 \\
        [--config configs/agents/ppo_fast-numatics-2m.yaml] [--seed S] [--minutes M] \\
        [--out DIR] [--resume]

One file, in the spirit of CleanRL's ``ppo_continuous_action.py``: thousands of envs
advanced in one jitted call (``gym.make_vec`` with the ``envs.features`` options), short
rollouts, a few large minibatches, GAE, and a bootstrap on time-limit truncation (the
vector env truncates and resets in the same step; V of ``info["final_obs"]`` is added to
the last reward). Residual mode trains a correction on a classical controller through
``agents.residual.ResidualVectorWrapper``; pure mode sets the current directly, taught in
its first updates by a classical controller if ``pure.teacher`` names one
(``agents.teacher``). The run ends at ``training.minutes`` or ``training.total_steps``,
whichever comes first, and the schedules follow the one nearer its end. The
policy reads the columns ``policy_inputs`` of the observation (running mean/std
normalised); rewards are scaled by a running std of the discounted return. The reward is
the trainer's, computed from ``info`` to match the benchmark's RMS metric (config
``reward``). Hyperparameters: ``configs/agents/ppo_fast-<variant>.yaml``.

Written to ``--out``: ``actor.npz`` (final) and ``actor_best.npz`` (best validation), numpy
actors for ``agents.learned`` (``pneumatic-env bench --controller DIR/actor.npz``);
``progress.csv`` (one row per update: wall time, env steps, steps/s, shares of time,
training RMS, validation RMS at evaluations), ``learning_curve.png``, ``train.json``
(config, throughput next to the env-only rate, curve) and ``checkpoint.pt`` every
``checkpoint_every`` updates (``--resume`` continues from it).
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

from .actor_validation import validate_actor
from .config import agent_config_path
from .generalist import MixtureVectorEnv
from .learned import FORMAT, pure_current
from .policy import actor_layers as _layers
from .ppo_setup import (
    action_scale_a,
    deadband_smoothing,
    load_config,
    make_training_env,
    references,
    row_deadband_a,
    select_columns,
)
from .residual import RESIDUAL_COLUMNS, env_variant
from .teacher import Teacher, TeacherConfig

__all__ = [
    "Agent",
    "export_actor",
    "train",
    "run_fast",
]

# --------------------------------------------------------------------------- networks


class RunningMeanStd:
    """Running mean and variance over batches (Chan et al.), as SB3's VecNormalize."""

    def __init__(self, shape=()):
        self.mean, self.var, self.count = np.zeros(shape), np.ones(shape), 1e-4

    def update(self, x):
        bm, bv, bc = x.mean(0), x.var(0), x.shape[0]
        d, tot = bm - self.mean, self.count + bc
        self.mean = self.mean + d * bc / tot
        self.var = (self.var * self.count + bv * bc + d**2 * self.count * bc / tot) / tot
        self.count = tot

    def state(self):
        return {"mean": self.mean, "var": self.var, "count": self.count}

    def load(self, s):
        self.mean, self.var, self.count = s["mean"], s["var"], s["count"]


class _NumpyTanhFunction(torch.autograd.Function):
    """tanh evaluated by NumPy, whose SIMD float32 tanh is about 3 x faster on one core
    than torch 2.13's on two (1M values: 0.43 ms against 1.35 ms); same backward as
    torch's (``tanh_backward``: g (1 - y^2))."""

    @staticmethod
    def forward(ctx, x):
        y = torch.from_numpy(np.tanh(x.detach().numpy()))
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad):
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


class NumpyTanh(nn.Tanh):
    """``nn.Tanh`` computed by :class:`_NumpyTanhFunction` (CPU tensors); exported as Tanh."""

    def forward(self, x):
        return _NumpyTanhFunction.apply(x)


def mlp(n_in: int, hidden, n_out: int, out_gain: float) -> nn.Sequential:
    layers, d = [], n_in
    for h in hidden:
        lin = nn.Linear(d, int(h))
        nn.init.orthogonal_(lin.weight, np.sqrt(2))
        nn.init.zeros_(lin.bias)
        layers += [lin, NumpyTanh()]
        d = int(h)
    out = nn.Linear(d, n_out)
    if out_gain > 0:
        nn.init.orthogonal_(out.weight, out_gain)
    else:  # zero output: a residual policy starts at the classical controller
        nn.init.zeros_(out.weight)
    nn.init.zeros_(out.bias)
    return nn.Sequential(*layers, out)


class Agent(nn.Module):
    """Gaussian actor (state-independent log std) and critic, separate MLPs."""

    def __init__(self, n_obs: int, hidden_pi, hidden_v, log_std_init: float, zero_init: bool):
        super().__init__()
        self.actor = mlp(n_obs, hidden_pi, 1, 0.0 if zero_init else 0.01)
        self.critic = mlp(n_obs, hidden_v, 1, 1.0)
        self.log_std = nn.Parameter(torch.full((1,), float(log_std_init)))

    def value(self, x):
        return self.critic(x).squeeze(-1)

    def dist(self, x):
        mu = self.actor(x)
        return torch.distributions.Normal(mu, self.log_std.exp().expand_as(mu))


def export_actor(
    agent: Agent,
    obs_rms: RunningMeanStd,
    cfg: dict,
    env_id: str,
    inputs: list[str],
    path: Path,
    name: str,
) -> Path:
    """The deterministic actor as an ``agents.learned`` ``.npz`` (numpy only at run time)."""
    from pneumatic_env.ids import parse_env_id

    layers = _layers(list(agent.actor))
    env_options = dict(cfg["env_kwargs"])
    meta = {
        "format": FORMAT,
        "algo": "ppo_fast",
        "name": name,
        "env_id": env_id,
        "variant": parse_env_id(env_id).variant,
        "output": "clip",
        "clip_obs": float(cfg["hyperparameters"]["clip_obs"]),
        "activations": [a for _, _, a in layers],
        "obs_dim": len(inputs),
        "inputs": list(inputs),
        "env_options": env_options,
        "preview_steps": int(env_options["preview_steps"]),
        "normalize_observation": bool(env_options["normalize_observation"]),
        "residual": dict(cfg["residual"]) if cfg["mode"] == "residual" else None,
        "action_scale_a": action_scale_a(cfg),
        "deadband_smoothing": deadband_smoothing(cfg),
        "variants": cfg.get("variants"),  # a generalist's training variants (else None)
    }
    arrays = {}
    for i, (w, b, _) in enumerate(layers):
        arrays[f"w{i}"], arrays[f"b{i}"] = w, b
    np.savez(
        path,
        meta=np.array(json.dumps(meta)),
        obs_mean=obs_rms.mean.astype(np.float64),
        obs_std=np.sqrt(obs_rms.var + 1e-8),
        **arrays,
    )
    return path


# --------------------------------------------------------------------------- training


def _env_only_rate(env, n_steps: int = 30) -> float:
    """Env steps/s of the bare vector env of ``env`` (same options), zero current."""
    top = env.unwrapped
    raws = [e.unwrapped for e in (top.envs if isinstance(top, MixtureVectorEnv) else [env])]
    actions = [np.zeros((raw.num_envs, 1)) for raw in raws]
    for raw, action in zip(raws, actions):
        raw.reset(seed=0)
        raw.step(action)  # warm: the first call loads the jitted step
    t0 = time.perf_counter()
    for _ in range(n_steps):
        for raw, action in zip(raws, actions):
            raw.step(action)
    return sum(raw.num_envs for raw in raws) * n_steps / (time.perf_counter() - t0)


PROGRESS_COLUMNS = (
    "update",
    "wall_s",
    "steps",
    "steps_per_s",
    "env_share",
    "base_share",
    "update_share",
    "train_rms_pct",
    "log_std",
    "approx_kl",
    "value_loss",
    "val_rms_pct",
    "val_chatter_a",
    "teacher_gap",  # RMS of (policy mean - teacher's action) over the rollout; "" without one
)


def train(
    config,
    env_id: str | None = None,
    seed: int = 0,
    out: str | Path = "runs/ppo_fast",
    minutes: float | None = None,
    total_steps: float | None = None,
    resume: bool = False,
    overrides: dict | None = None,
    on_eval=None,
    command: str = "",
    log=print,
) -> dict:
    """Train with the ppo_fast config (path or dict); returns the ``train.json`` summary.

    ``on_eval(record)`` is called after each validation (the tuner reports and prunes
    there; an exception it raises ends the run after the checkpoint).
    """
    cfg = load_config(config, overrides)
    env_id = env_id or cfg["env"]
    hp, tr, rw = cfg["hyperparameters"], cfg["training"], cfg["reward"]
    budget_s = 60.0 * float(minutes if minutes is not None else tr["minutes"])
    if total_steps is None:  # the config's step budget, if it has one
        total_steps = tr.get("total_steps")
    total_steps = float(total_steps) if total_steps is not None else float("inf")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(int(tr["torch_threads"]))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    residual = cfg["mode"] == "residual"
    env = make_training_env(cfg, env_id, seed)
    raw = env.unwrapped
    columns = getattr(raw, "columns", None) or (
        raw.observation_columns + (list(RESIDUAL_COLUMNS) if residual else [])
    )
    inputs = select_columns(columns, cfg["policy_inputs"])
    index = np.array([columns.index(c) for c in inputs])
    _, validation = references(cfg)
    variants = tr.get("validation_variants") or (
        raw.variants if isinstance(raw, MixtureVectorEnv) else [env_variant(env)]
    )
    N, T, D = int(hp["num_envs"]), int(hp["rollout_steps"]), len(inputs)
    scale, i_max = raw.reference_scale, raw.coil_current_max_a
    env_only = _env_only_rate(env)
    agent = Agent(D, hp["hidden_pi"], hp["hidden_v"], hp["log_std_init"], zero_init=residual)
    opt = torch.optim.Adam(agent.parameters(), lr=float(hp["learning_rate"]), eps=1e-5)
    obs_rms, ret_rms = RunningMeanStd(D), RunningMeanStd()
    state = {"steps": 0, "updates": 0, "wall_s": 0.0, "best": None, "curve": []}
    ckpt = out / "checkpoint.pt"
    if resume:
        if not ckpt.is_file():
            raise FileNotFoundError(f"--resume: no checkpoint at {ckpt}")
        saved = torch.load(ckpt, weights_only=False)
        agent.load_state_dict(saved["agent"])
        opt.load_state_dict(saved["optimizer"])
        obs_rms.load(saved["obs_rms"])
        ret_rms.load(saved["ret_rms"])
        state = saved["state"]
        torch.set_rng_state(saved["torch_rng"])
        rng = np.random.default_rng(seed + 7919 * state["updates"])
    gamma, lam, clip_obs = float(hp["gamma"]), float(hp["gae_lambda"]), float(hp["clip_obs"])

    def norm(x):
        return np.clip(
            (x - obs_rms.mean) / np.sqrt(obs_rms.var + 1e-8), -clip_obs, clip_obs
        ).astype(np.float32)

    episode = int(tr["episode_steps"])
    options = {"start_step": rng.integers(0, episode, N)} if tr["stagger"] else None
    obs, _ = env.reset(seed=seed * 100_000 + state["updates"], options=options)
    feat = obs[:, index]
    zeros = np.zeros(N)
    if not resume:  # warm the normaliser on the classical (or zero-current) features
        for _ in range(20):
            obs_rms.update(feat)
            obs, *_ = env.step(zeros[:, None])
            feat = obs[:, index]
    prev_u, ret_acc = np.zeros(N), np.zeros(N)
    b_obs = np.zeros((T, N, D), np.float32)
    b_act, b_logp, b_rew, b_done = (np.zeros((T, N), np.float32) for _ in range(4))
    b_val = np.zeros((T + 1, N), np.float32)
    e_unit, c_unit, u_unit = (
        float(rw["error_unit_fraction"]) * scale,
        float(rw["chatter_unit_a"]),
        float(rw["effort_unit_a"]),
    )
    action_scale, smoothing = action_scale_a(cfg), deadband_smoothing(cfg)
    deadband = row_deadband_a(env)
    teacher_cfg = TeacherConfig.from_config(cfg)
    teacher = Teacher(env, teacher_cfg, action_scale, deadband, smoothing) if teacher_cfg else None
    # the classical controller's time (a residual's base, inside env.step, or a pure
    # policy's teacher, outside it)
    base = getattr(env, "residual", None) or teacher
    if teacher:
        teacher.reset()
    b_teach = np.zeros((T, N), np.float32)
    t_env = t_upd = 0.0
    base_t0 = base.base_time_s if base else 0.0
    progress_path = out / "progress.csv"
    new_file = not (resume and progress_path.is_file())
    columns_written = PROGRESS_COLUMNS
    if not new_file:  # a resumed run keeps its file's columns (older runs have fewer)
        with open(progress_path, newline="", encoding="utf-8") as f:
            columns_written = tuple(next(csv.reader(f), PROGRESS_COLUMNS))
    progress = open(progress_path, "a" if not new_file else "w", newline="", encoding="utf-8")
    writer = csv.DictWriter(progress, fieldnames=columns_written, extrasaction="ignore")
    if new_file:
        writer.writeheader()
    t_start, wall0 = time.perf_counter(), state["wall_s"]
    last_eval, last_eval_steps = wall0, state["steps"]
    eval_every_steps = float(tr.get("eval_every_steps") or 0.0)  # 0: by wall time only
    eval_time = 0.0

    def wall():
        return wall0 + time.perf_counter() - t_start - eval_time

    lr0, lr_end = float(hp["learning_rate"]), float(hp["learning_rate_final_fraction"])
    try:
        while state["steps"] < total_steps and wall() < budget_s:
            # progress through the budget that binds first (wall time or env steps)
            frac = min(max(wall() / budget_s, state["steps"] / total_steps), 1.0)
            for g in opt.param_groups:
                g["lr"] = lr0 * (1.0 - (1.0 - lr_end) * frac)
            sq_err = sq_gap = 0.0
            for t in range(T):
                obs_rms.update(feat)
                x = norm(feat)
                with torch.no_grad():
                    xt = torch.from_numpy(x)
                    d = agent.dist(xt)
                    a = d.sample()
                    logp, v = d.log_prob(a).sum(-1), agent.value(xt)
                a_np = a.numpy()[:, 0].astype(np.float64)
                if teacher:
                    b_teach[t] = teacher.targets(obs)
                    sq_gap += float(np.nanmean((d.mean.numpy()[:, 0] - b_teach[t]) ** 2))
                a_clip = np.clip(a_np, -1.0, 1.0)
                act = (
                    a_clip
                    if residual
                    else pure_current(a_clip, action_scale, deadband, smoothing, i_max)
                )
                if teacher:
                    teacher.applied(act)
                t0 = time.perf_counter()
                obs, _, _, trunc, info = env.step(act[:, None])
                t_env += time.perf_counter() - t0
                if teacher and trunc.any():
                    teacher.reset(np.flatnonzero(trunc))
                feat = obs[:, index]
                e = info["tracking_error"] / e_unit
                u = info["coil_current_a"]
                rew = (
                    -(e**2)
                    - float(rw["l1_weight"]) * np.abs(e)
                    - float(rw["chatter_weight"]) * ((u - prev_u) / c_unit) ** 2
                    - float(rw["effort_weight"]) * (u / u_unit) ** 2
                    - (float(rw["residual_weight"]) * a_clip**2 if residual else 0.0)
                )
                prev_u = np.where(trunc, 0.0, u)
                sq_err += float(np.mean((info["tracking_error"] / scale) ** 2))
                ret_acc = ret_acc * gamma + rew
                ret_rms.update(ret_acc)
                ret_acc[trunc] = 0.0
                rs = rew / np.sqrt(ret_rms.var + 1e-8)
                if trunc.any():  # bootstrap the truncated episodes from their final obs
                    rows = np.flatnonzero(trunc)
                    final = np.stack([info["final_obs"][r] for r in rows])[:, index]
                    with torch.no_grad():
                        rs[rows] += gamma * agent.value(torch.from_numpy(norm(final))).numpy()
                b_obs[t], b_act[t], b_logp[t], b_val[t] = x, a_np, logp.numpy(), v.numpy()
                b_rew[t], b_done[t] = rs, trunc
            with torch.no_grad():
                b_val[T] = agent.value(torch.from_numpy(norm(feat))).numpy()
            tu = time.perf_counter()
            # GAE; done[t]: transition t ended its episode (its bootstrap is in the reward)
            adv = np.zeros((T, N), np.float32)
            last = np.zeros(N, np.float32)
            for t in reversed(range(T)):
                nd = 1.0 - b_done[t]
                delta = b_rew[t] + gamma * b_val[t + 1] * nd - b_val[t]
                last = delta + gamma * lam * nd * last
                adv[t] = last
            B = T * N
            fo = torch.from_numpy(b_obs.reshape(B, D))
            fa = torch.from_numpy(b_act.reshape(B, 1))
            flp, fadv = torch.from_numpy(b_logp.reshape(-1)), torch.from_numpy(adv.reshape(-1))
            fret = torch.from_numpy((adv + b_val[:T]).reshape(-1))
            fteach = torch.from_numpy(b_teach.reshape(-1))
            # rows without a teacher (a generalist's untuned variants): no imitation term
            fmask = torch.from_numpy(np.tile(teacher.taught, T)) if teacher else None
            all_taught = teacher is None or bool(teacher.taught.all())
            w_teach = teacher.config.weight_at(frac) if teacher else 0.0
            n_mb = int(hp["minibatches"])
            mb = B // n_mb
            kls = []
            for _ in range(int(hp["epochs"])):
                perm = torch.randperm(B)
                for s in range(0, mb * n_mb, mb):
                    idx = perm[s : s + mb]
                    obs_mb = fo[idx]
                    d = agent.dist(obs_mb)
                    lp = d.log_prob(fa[idx]).sum(-1)
                    log_ratio = lp - flp[idx]
                    ratio = log_ratio.exp()
                    with torch.no_grad():
                        kls.append(((ratio - 1) - log_ratio).mean().item())
                    A = fadv[idx]
                    A = (A - A.mean()) / (A.std() + 1e-8)
                    clip = float(hp["clip_range"])
                    pg = torch.max(-A * ratio, -A * ratio.clamp(1 - clip, 1 + clip)).mean()
                    vl = 0.5 * ((agent.value(obs_mb) - fret[idx]) ** 2).mean()
                    loss = (
                        pg
                        + float(hp["vf_coef"]) * vl
                        - float(hp["ent_coef"]) * d.entropy().sum(-1).mean()
                    )
                    if w_teach > 0:  # imitation of the teacher (agents.teacher)
                        gap = (d.mean[:, 0] - fteach[idx]) / teacher.config.unit
                        if all_taught:
                            loss = loss + w_teach * (gap**2).mean()
                        else:
                            m = fmask[idx]
                            sq = torch.where(m, gap, torch.zeros_like(gap)) ** 2
                            loss = loss + w_teach * sq.sum() / m.sum().clamp(min=1)
                    opt.zero_grad()
                    loss.backward()
                    nn.utils.clip_grad_norm_(agent.parameters(), float(hp["max_grad_norm"]))
                    opt.step()
                    with torch.no_grad():
                        agent.log_std.clamp_(min=float(hp["log_std_min"]))
                if hp["target_kl"] and np.mean(kls[-n_mb:]) > float(hp["target_kl"]):
                    break
            t_upd += time.perf_counter() - tu
            state["steps"] += B
            state["updates"] += 1
            w = wall()
            span = max(w - wall0, 1e-9)
            base_s = (base.base_time_s - base_t0) if base else 0.0
            row = {
                "update": state["updates"],
                "wall_s": round(w, 3),
                "steps": state["steps"],
                "steps_per_s": round(state["steps"] / max(w, 1e-9)),
                "env_share": round((t_env - base_s * residual) / span, 4),
                "base_share": round(base_s / span, 4),
                "update_share": round(t_upd / span, 4),
                "train_rms_pct": round(100 * np.sqrt(sq_err / T), 4),
                "log_std": round(agent.log_std.item(), 4),
                "approx_kl": round(np.mean(kls), 5),
                "value_loss": round(vl.item(), 5),
                "val_rms_pct": "",
                "val_chatter_a": "",
                "teacher_gap": round(np.sqrt(sq_gap / T), 5) if teacher else "",
            }
            done = w >= budget_s or state["steps"] >= total_steps
            due_by_steps = eval_every_steps > 0 and (
                state["steps"] - last_eval_steps >= eval_every_steps
            )
            if w - last_eval >= float(tr["eval_every_s"]) or due_by_steps or done:
                te = time.perf_counter()
                path = export_actor(
                    agent, obs_rms, cfg, env_id, inputs, out / "actor_tmp.npz", out.name
                )
                vals = [
                    validate_actor(path, v, validation, int(tr["validation_steps"]))
                    for v in variants
                ]
                val = {k: float(np.mean([v[k] for v in vals])) for k in vals[0]}
                row.update({k: round(v, 5) for k, v in val.items()})
                record = {
                    "wall_s": w,
                    "steps": state["steps"],
                    **val,
                    "train_rms_pct": row["train_rms_pct"],
                }
                state["curve"].append(record)
                log(
                    f"  eval at {w:.0f} s, {state['steps'] / 1e6:.2f}M steps: "
                    f"val RMS {val['val_rms_pct']:.3f} %",
                    flush=True,
                )
                if state["best"] is None or val["val_rms_pct"] < state["best"]["val_rms_pct"]:
                    state["best"] = record
                    path.replace(out / "actor_best.npz")
                eval_time += time.perf_counter() - te
                last_eval, last_eval_steps = wall(), state["steps"]
            writer.writerow(row)
            if row["val_rms_pct"] != "" and on_eval is not None:
                progress.flush()
                on_eval(state["curve"][-1])
            if state["updates"] % 10 == 0:
                progress.flush()
                log(
                    f"upd {state['updates']} {state['steps'] / 1e6:.1f}M steps "
                    f"{state['steps'] / max(w, 1e-9):.0f} steps/s (env alone {env_only:.0f}) "
                    f"train RMS {100 * np.sqrt(sq_err / T):.2f} % log_std "
                    f"{agent.log_std.item():.2f}"
                    + (f" teacher gap {row['teacher_gap']:.3f}" if teacher else ""),
                    flush=True,
                )
            if state["updates"] % int(tr["checkpoint_every"]) == 0:
                _checkpoint(ckpt, agent, opt, obs_rms, ret_rms, state, w)
    finally:
        progress.close()
        state["wall_s"] = wall()
        _checkpoint(ckpt, agent, opt, obs_rms, ret_rms, state, state["wall_s"])
        (out / "actor_tmp.npz").unlink(missing_ok=True)
    export_actor(agent, obs_rms, cfg, env_id, inputs, out / "actor.npz", out.name)
    w = state["wall_s"]
    span = max(w - wall0, 1e-9)
    base_s = (base.base_time_s - base_t0) if base else 0.0
    summary = {
        "algo": "ppo_fast",
        "env_id": env_id,
        "seed": seed,
        "command": command,
        "config": cfg,
        "steps": state["steps"],
        "updates": state["updates"],
        "wall_s": w,
        "steps_per_s": state["steps"] / max(w, 1e-9),
        "env_only_steps_per_s": env_only,
        "env_share": (t_env - base_s * residual) / span,
        "base_share": base_s / span,
        "update_share": t_upd / span,
        "inputs": inputs,
        "curve": state["curve"],
        "best": state["best"],
    }
    (out / "train.json").write_text(json.dumps(summary, indent=2, default=_plain), encoding="utf-8")
    _learning_curve(out, f"ppo_fast on {env_id} (seed {seed})")
    env.close()
    return summary


def _plain(x):
    return x.item() if hasattr(x, "item") else str(x)


def _checkpoint(path, agent, opt, obs_rms, ret_rms, state, wall_s):
    state = {**state, "wall_s": wall_s}
    torch.save(
        {
            "agent": agent.state_dict(),
            "optimizer": opt.state_dict(),
            "obs_rms": obs_rms.state(),
            "ret_rms": ret_rms.state(),
            "state": state,
            "torch_rng": torch.get_rng_state(),
        },
        path,
    )


def _learning_curve(out: Path, title: str) -> Path | None:
    rows = list(csv.DictReader(open(out / "progress.csv", newline="", encoding="utf-8")))
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    val = [r for r in rows if r["val_rms_pct"] != ""]
    for ax, key, label in ((axes[0], "wall_s", "wall time (s)"), (axes[1], "steps", "env steps")):
        ax.plot(
            [float(r[key]) for r in rows],
            [float(r["train_rms_pct"]) for r in rows],
            lw=0.8,
            label="training RMS (stochastic)",
        )
        ax.plot(
            [float(r[key]) for r in val],
            [float(r["val_rms_pct"]) for r in val],
            marker="o",
            label="validation RMS",
        )
        ax.set_xlabel(label)
    axes[0].set_ylabel("RMS error (% of scale)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    png = out / "learning_curve.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png


def run_fast(args) -> int:
    """The ``pneumatic-env train --algo ppo_fast`` command (arguments of agents.train)."""
    import shlex
    import sys

    from pneumatic_env.ids import parse_env_id

    variant = parse_env_id(args.env).variant.lower()
    config = args.config or agent_config_path(f"ppo_fast-{variant}")
    if not Path(config).is_file():
        raise SystemExit(
            f"no config {config}: write configs/agents/ppo_fast-{variant}.yaml or pass --config"
        )
    out = args.out or f"runs/ppo_fast-{variant}-s{args.seed}"
    command = "pneumatic-env " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    s = train(
        config, args.env, args.seed, out, args.minutes, args.timesteps, args.resume, command=command
    )
    best = s["best"] or {}
    print(
        f"{s['steps']} steps in {s['wall_s']:.0f} s: {s['steps_per_s']:.0f} env steps/s "
        f"(env alone {s['env_only_steps_per_s']:.0f} steps/s; shares: env "
        f"{100 * s['env_share']:.0f} %, classical base {100 * s['base_share']:.0f} %, "
        f"updates {100 * s['update_share']:.0f} %); best validation RMS "
        f"{best.get('val_rms_pct', float('nan')):.3f} %; wrote {out}"
    )
    return 0
