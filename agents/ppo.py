"""``pneumatic-env train --algo ppo_fast``: lean PPO over the native vector env (CleanRL style).

    pneumatic-env train --algo ppo_fast --env pneumatic_env/ForceTrack-Numatics-2m-v0 \\
        [--config configs/agents/ppo_fast-numatics-2m.yaml] [--seed S] [--minutes M] \\
        [--out DIR] [--resume]

In the shape of CleanRL's ``ppo_continuous_action.py``: a typed config
(``agents.ppo_config.PPOFastConfig``) and a loop that reads top to bottom as rollout,
advantages, update, validate, log (``agents.ppo_rollout``). Thousands of envs advance in
one jitted call (``gym.make_vec`` with the ``envs.features`` options), short rollouts, a
few large minibatches, GAE, and a bootstrap on time-limit truncation. Residual mode
trains a correction on a classical controller through
``agents.residual.ResidualVectorWrapper``; pure mode sets the current directly, taught in
its first updates by a classical controller if ``pure.teacher`` names one
(``agents.teacher``). The run ends at ``training.minutes`` or ``training.total_steps``,
whichever comes first, and the schedules follow the one nearer its end. The policy reads
the columns ``policy_inputs`` of the observation (running mean/std normalised); rewards
are scaled by a running std of the discounted return (``agents.ppo_rollout``).
Hyperparameters: ``configs/agents/ppo_fast-<variant>.yaml``.

Written to ``--out``: ``actor.npz`` (final) and ``actor_best.npz`` (best validation), numpy
actors for ``agents.learned`` (``pneumatic-env bench --controller DIR/actor.npz``);
``progress.csv`` (one row per update: wall time, env steps, steps/s, shares of time,
training RMS, validation RMS at evaluations), ``learning_curve.png``, ``train.json``
(config, throughput next to the env-only rate, curve) and ``checkpoint.pt`` every
``checkpoint_every`` updates (``--resume`` continues from it). A residual config that
lists ``training.residual_gains`` has its best actor's correction bound chosen at the end
(``agents.residual_gain``): ``actor_best.npz`` is then the chosen gain's and
``actor_best_unscaled.npz`` the actor as trained.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import torch

from .actor_validation import validate_on_draws
from .config import agent_config_path
from .generalist import MixtureVectorEnv
from .learned import FORMAT
from .policy import actor_layers
from .ppo_config import PPOFastConfig, drawn_plants, load_config
from .ppo_networks import Agent, RunningMeanStd
from .ppo_rollout import RolloutBuffer, Rollouts, advantages, imitation_loss, ppo_update
from .ppo_setup import PlantInputs, make_training_env, references, select_columns
from .residual import RESIDUAL_COLUMNS, env_variant
from .residual_gain import apply_residual_gain

__all__ = [
    "export_actor",
    "train",
    "run_fast",
]


def export_actor(
    agent: Agent,
    obs_rms: RunningMeanStd,
    cfg: PPOFastConfig,
    env_id: str,
    inputs: list[str],
    path: Path,
    name: str,
) -> Path:
    """The deterministic actor as an ``agents.learned`` ``.npz`` (numpy only at run time)."""
    from pneumatic_env.ids import parse_env_id

    layers = actor_layers(list(agent.actor))
    env_options = dict(cfg.env_kwargs)
    meta = {
        "format": FORMAT,
        "algo": "ppo_fast",
        "name": name,
        "env_id": env_id,
        "variant": parse_env_id(env_id).variant,
        "output": "clip",
        "clip_obs": cfg.hyperparameters.clip_obs,
        "activations": [a for _, _, a in layers],
        "obs_dim": len(inputs),
        "inputs": list(inputs),
        "env_options": env_options,
        "preview_steps": int(env_options["preview_steps"]),
        "normalize_observation": bool(env_options["normalize_observation"]),
        "residual": dict(cfg.residual or {}) if cfg.mode == "residual" else None,
        "action_scale_a": cfg.pure.action_scale_a,
        "deadband_smoothing": cfg.pure.deadband_smoothing,
        # a generalist's training variants (else None)
        "variants": list(cfg.variants) if cfg.variants else None,
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


# --------------------------------------------------------------------------- training run


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


class Checkpoint:
    """``checkpoint.pt``: networks, optimiser, normalisers, counters and torch's RNG."""

    def __init__(self, path: Path, agent: Agent, opt, obs_rms, ret_rms):
        self.path, self.agent, self.opt = path, agent, opt
        self.obs_rms, self.ret_rms = obs_rms, ret_rms

    def save(self, state: dict, wall_s: float) -> None:
        torch.save(
            {
                "agent": self.agent.state_dict(),
                "optimizer": self.opt.state_dict(),
                "obs_rms": self.obs_rms.state(),
                "ret_rms": self.ret_rms.state(),
                "state": {**state, "wall_s": wall_s},
                "torch_rng": torch.get_rng_state(),
            },
            self.path,
        )

    def resume(self) -> dict:
        """Load the saved run into the networks etc.; its counters."""
        if not self.path.is_file():
            raise FileNotFoundError(f"--resume: no checkpoint at {self.path}")
        saved = torch.load(self.path, weights_only=False)
        self.agent.load_state_dict(saved["agent"])
        self.opt.load_state_dict(saved["optimizer"])
        self.obs_rms.load(saved["obs_rms"])
        self.ret_rms.load(saved["ret_rms"])
        torch.set_rng_state(saved["torch_rng"])
        return saved["state"]


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
    "plant_mse",  # the actor's plant head's last minibatch mean square; "" without one
)


class ProgressLog:
    """``progress.csv``, one row per update; a resumed run appends in its file's columns
    (older runs have fewer)."""

    def __init__(self, path: Path, resume: bool):
        new_file = not (resume and path.is_file())
        columns = PROGRESS_COLUMNS
        if not new_file:
            with open(path, newline="", encoding="utf-8") as f:
                columns = tuple(next(csv.reader(f), PROGRESS_COLUMNS))
        self.file = open(path, "w" if new_file else "a", newline="", encoding="utf-8")
        self.writer = csv.DictWriter(self.file, fieldnames=columns, extrasaction="ignore")
        if new_file:
            self.writer.writeheader()


class WallClock:
    """Training wall time (s): a resumed run's plus this run's, validations not counted."""

    def __init__(self, wall0_s: float):
        self.wall0_s, self.t_start, self.eval_s = wall0_s, time.perf_counter(), 0.0

    def __call__(self) -> float:
        return self.wall0_s + time.perf_counter() - self.t_start - self.eval_s


class TrainingRun:
    """A run's parts: env, networks, rollouts, counters (``state``: steps, updates,
    wall_s, best, curve), clocks, checkpoint and progress file."""

    def __init__(self, cfg: PPOFastConfig, env_id: str, seed: int, out: Path, budget, resume):
        hp, tr = cfg.hyperparameters, cfg.training
        minutes, total_steps = budget
        self.cfg, self.env_id, self.seed, self.out = cfg, env_id, seed, out
        self.budget_s = 60.0 * float(minutes if minutes is not None else tr.minutes)
        if total_steps is None:  # the config's step budget, if it has one
            total_steps = tr.total_steps
        self.total_steps = float(total_steps) if total_steps is not None else float("inf")
        out.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(tr.torch_threads)
        torch.manual_seed(seed)
        rng = np.random.default_rng(seed)
        self.env = env = make_training_env(cfg, env_id, seed)
        raw = env.unwrapped
        columns = getattr(raw, "columns", None) or (
            raw.observation_columns + (list(RESIDUAL_COLUMNS) if cfg.mode == "residual" else [])
        )
        self.inputs = select_columns(columns, list(cfg.policy_inputs))
        _, self.validation = references(cfg)
        self.variants = tr.validation_variants or (
            raw.variants if isinstance(raw, MixtureVectorEnv) else [env_variant(env)]
        )
        self.env_only = _env_only_rate(env)
        D = len(self.inputs)
        plant = PlantInputs(env, tr.critic_plant_inputs) if tr.critic_plant_inputs else None
        n_plant = len(plant) if plant else 0
        self.agent = Agent(
            D,
            hp.hidden_pi,
            hp.hidden_v,
            hp.log_std_init,
            zero_init=cfg.mode == "residual",
            n_privileged=n_plant,
            plant_head=tr.actor_plant_prediction > 0,
        )
        self.opt = torch.optim.Adam(self.agent.parameters(), lr=hp.learning_rate, eps=1e-5)
        self.obs_rms, ret_rms = RunningMeanStd(D), RunningMeanStd()
        self.checkpoint = Checkpoint(
            out / "checkpoint.pt", self.agent, self.opt, self.obs_rms, ret_rms
        )
        self.state = {"steps": 0, "updates": 0, "wall_s": 0.0, "best": None, "curve": []}
        if resume:
            self.state = self.checkpoint.resume()
            rng = np.random.default_rng(seed + 7919 * self.state["updates"])
        index = np.array([columns.index(c) for c in self.inputs])
        self.rollouts = Rollouts(cfg, env, index, self.obs_rms, ret_rms, plant)
        self.rollouts.start(seed, self.state["updates"], rng, warm=not resume)
        self.buf = RolloutBuffer.zeros(hp.rollout_steps, hp.num_envs, D, n_plant)
        self.progress = ProgressLog(out / "progress.csv", resume)
        self.wall = WallClock(self.state["wall_s"])
        self.last_eval_s, self.last_eval_steps = self.wall.wall0_s, self.state["steps"]
        self.t_update_s = 0.0

    def budget_fraction(self) -> float:
        """Progress through the budget that binds first (wall time or env steps)."""
        return min(max(self.wall() / self.budget_s, self.state["steps"] / self.total_steps), 1.0)

    def anneal_learning_rate(self, frac: float) -> None:
        hp = self.cfg.hyperparameters
        for g in self.opt.param_groups:
            g["lr"] = hp.learning_rate * (1.0 - (1.0 - hp.learning_rate_final_fraction) * frac)

    def shares(self, wall_s: float) -> tuple[float, float, float]:
        """This run's shares of wall time in the env, the classical base, the updates."""
        span = max(wall_s - self.wall.wall0_s, 1e-9)
        base_s = self.rollouts.base_time_s()
        env_s = self.rollouts.t_env_s - base_s * (self.cfg.mode == "residual")
        return env_s / span, base_s / span, self.t_update_s / span

    def progress_row(
        self, w: float, sq_err: float, sq_gap: float, kls, value_loss, plant_mse=None
    ) -> dict:
        T, steps = len(self.buf.act), self.state["steps"]
        env_share, base_share, update_share = self.shares(w)
        return {
            "update": self.state["updates"],
            "wall_s": round(w, 3),
            "steps": steps,
            "steps_per_s": round(steps / max(w, 1e-9)),
            "env_share": round(env_share, 4),
            "base_share": round(base_share, 4),
            "update_share": round(update_share, 4),
            "train_rms_pct": round(100 * np.sqrt(sq_err / T), 4),
            "log_std": round(self.agent.log_std.item(), 4),
            "approx_kl": round(np.mean(kls), 5),
            "value_loss": round(value_loss, 5),
            "val_rms_pct": "",
            "val_chatter_a": "",
            "teacher_gap": round(np.sqrt(sq_gap / T), 5) if self.rollouts.teacher else "",
            "plant_mse": "" if plant_mse is None else round(plant_mse, 5),
        }

    def validation_due(self, w: float) -> bool:
        """Every ``eval_every_s`` of wall time or ``eval_every_steps``, and at the end."""
        tr, steps = self.cfg.training, self.state["steps"]
        done = w >= self.budget_s or steps >= self.total_steps
        by_steps = tr.eval_every_steps > 0 and steps - self.last_eval_steps >= tr.eval_every_steps
        return w - self.last_eval_s >= tr.eval_every_s or by_steps or done

    def export(self, path: Path) -> Path:
        """The actor as it is now (``export_actor``), named after the output directory."""
        return export_actor(
            self.agent, self.obs_rms, self.cfg, self.env_id, self.inputs, path, self.out.name
        )

    def validate(self, row: dict, w: float, log) -> None:
        """The actor on the validation references of each variant, on the nominal plant
        and on ``training.validation_draws`` plants per reference drawn from the config's
        randomisation (``agents.actor_validation.validate_on_draws``); the best is kept."""
        te, out, state = time.perf_counter(), self.out, self.state
        path = self.export(out / "actor_tmp.npz")
        steps = self.cfg.training.validation_steps
        draws, randomization = drawn_plants(self.cfg, "validation_draws")
        vals = [
            validate_on_draws(path, v, self.validation, steps, randomization, draws)
            for v in self.variants
        ]
        val = {k: float(np.mean([v[k] for v in vals])) for k in vals[0]}
        row.update({k: round(val[k], 5) for k in ("val_rms_pct", "val_chatter_a")})
        record = {"wall_s": w, "steps": state["steps"], **val}
        record["train_rms_pct"] = row["train_rms_pct"]
        state["curve"].append(record)
        log(
            f"  eval at {w:.0f} s, {state['steps'] / 1e6:.2f}M steps: "
            f"val RMS {val['val_rms_pct']:.3f} %",
            flush=True,
        )
        if state["best"] is None or val["val_rms_pct"] < state["best"]["val_rms_pct"]:
            state["best"] = record
            path.replace(out / "actor_best.npz")
            # a finished run resumed: the gain step (agents.residual_gain) starts afresh
            (out / "actor_best_unscaled.npz").unlink(missing_ok=True)
        self.wall.eval_s += time.perf_counter() - te
        self.last_eval_s, self.last_eval_steps = self.wall(), state["steps"]

    def write_row(self, row: dict, log, on_eval) -> None:
        """The row to ``progress.csv``; ``on_eval`` after a validation; a line every 10."""
        self.progress.writer.writerow(row)
        if row["val_rms_pct"] != "" and on_eval is not None:
            self.progress.file.flush()
            on_eval(self.state["curve"][-1])
        steps, w = self.state["steps"], row["wall_s"]
        if self.state["updates"] % 10 == 0:
            self.progress.file.flush()
            log(
                f"upd {self.state['updates']} {steps / 1e6:.1f}M steps "
                f"{steps / max(w, 1e-9):.0f} steps/s (env alone {self.env_only:.0f}) "
                f"train RMS {row['train_rms_pct']:.2f} % log_std {row['log_std']:.2f}"
                + (f" teacher gap {row['teacher_gap']:.3f}" if self.rollouts.teacher else ""),
                flush=True,
            )

    def close(self) -> None:
        """Close the progress file and checkpoint (also when the run is interrupted)."""
        self.progress.file.close()
        self.state["wall_s"] = self.wall()
        self.checkpoint.save(self.state, self.state["wall_s"])
        (self.out / "actor_tmp.npz").unlink(missing_ok=True)

    def summary(self, command: str, log=print) -> dict:
        """The final actor, the best actor's residual gain if the config lists gains
        (``agents.residual_gain``), ``train.json`` and the learning curve; the summary."""
        self.export(self.out / "actor.npz")
        w, state = self.state["wall_s"], self.state
        env_share, base_share, update_share = self.shares(w)
        summary = {
            "algo": "ppo_fast",
            "env_id": self.env_id,
            "seed": self.seed,
            "command": command,
            "config": self.cfg.to_tree(),
            "steps": state["steps"],
            "updates": state["updates"],
            "wall_s": w,
            "steps_per_s": state["steps"] / max(w, 1e-9),
            "env_only_steps_per_s": self.env_only,
            "env_share": env_share,
            "base_share": base_share,
            "update_share": update_share,
            "inputs": self.inputs,
            "curve": state["curve"],
            "best": state["best"],
        }
        if self.cfg.training.residual_gains and state["best"] is not None:
            summary["residual_gain"] = apply_residual_gain(self.out, self.cfg, log)
        text = json.dumps(summary, indent=2, default=_plain)
        (self.out / "train.json").write_text(text, encoding="utf-8")
        _learning_curve(self.out, f"ppo_fast on {self.env_id} (seed {self.seed})")
        self.env.close()
        return summary


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
    """Train with the ppo_fast config (path, tree or config); returns the ``train.json``
    summary. The run ends at ``minutes`` or ``total_steps`` (default: the config's).

    ``on_eval(record)`` is called after each validation (the tuner reports and prunes
    there; an exception it raises ends the run after the checkpoint).
    """
    cfg = load_config(config, overrides)
    hp, tr = cfg.hyperparameters, cfg.training
    run = TrainingRun(cfg, env_id or cfg.env, seed, Path(out), (minutes, total_steps), resume)
    buf, state, teach = run.buf, run.state, torch.from_numpy(run.buf.teach.reshape(-1))
    try:
        while state["steps"] < run.total_steps and run.wall() < run.budget_s:
            frac = run.budget_fraction()
            run.anneal_learning_rate(frac)
            sq_err, sq_gap = run.rollouts.collect(run.agent, buf)
            t0 = time.perf_counter()
            adv = advantages(buf, hp.gamma, hp.gae_lambda)
            imitation = imitation_loss(run.rollouts.teacher, teach, frac, len(buf.act))
            kls, value_loss, plant_mse = ppo_update(
                run.agent, run.opt, buf, adv, hp, imitation, tr.actor_plant_prediction
            )
            run.t_update_s += time.perf_counter() - t0
            state["steps"] += buf.act.size
            state["updates"] += 1
            w = run.wall()
            row = run.progress_row(w, sq_err, sq_gap, kls, value_loss, plant_mse)
            if run.validation_due(w):
                run.validate(row, w, log)
            run.write_row(row, log, on_eval)
            if state["updates"] % tr.checkpoint_every == 0:
                run.checkpoint.save(state, w)
    finally:
        run.close()
    return run.summary(command, log)


def _plain(x):
    return x.item() if hasattr(x, "item") else str(x)


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
