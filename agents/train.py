"""``pneumatic-env train``: PPO or SAC on the native vector env (Stable-Baselines3), or the
fast PPO of ``agents/ppo.py`` (``--algo ppo_fast``: thousands of envs, delay-aware
features, residual policies; its docstring).

    pneumatic-env train --algo ppo --env pneumatic_env/ForceTrack-Numatics-2m-v0 \\
        --config configs/agents/ppo-numatics-2m.yaml [--timesteps N] [--seed S] [--out DIR]
    pneumatic-env train --algo ppo_fast --env pneumatic_env/ForceTrack-Numatics-2m-v0 \\
        [--config FILE] [--seed S] [--minutes M] [--out DIR] [--resume]
    pneumatic-env train --rig REPORT_DIR [--out OUT] [--minutes M] [--steps N] [--seed S] \\
        [--base auto|pid|sliding_mode]
        # a controller for the rig of an identification report (agents/rig_training.py)

Hyperparameters come from ``configs/agents/<algo>-<variant>.yaml`` (one file per algorithm and
variant, rl-zoo style; every number with unit and source). The env is ``gym.make_vec`` (our
native vector env) behind :class:`pneumatic_env.agents.sb3.SB3VecEnv`, with ``VecMonitor``
for episode statistics and optionally ``VecNormalize`` for the rewards (observations are
normalised by the env itself, ``normalize_observation=True``). Written to ``--out``:
TensorBoard and CSV logs, ``model.zip`` (SB3), ``model.npz`` (the actor for
``pneumatic_env.agents.policy``, no torch needed), ``train.json`` (settings, throughput,
evaluation) and ``learning_curve.png``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from pneumatic_env.ids import parse_env_id
from pneumatic_env.text_format import jsonable

from .config import ConfigError, agent_config_path, load_agent_config
from .policy import NumpyPolicy, export_policy

__all__ = ["train", "evaluate", "add_arguments", "run"]

ALGOS = ("ppo", "sac")  # Stable-Baselines3; "ppo_fast" is agents/ppo.py


def _variant_of(env_id: str) -> str:
    """``pneumatic_env/ForceTrack-Numatics-2m-v0`` -> ``numatics-2m`` (the config files' key)."""
    return parse_env_id(env_id).variant.lower()


def evaluate(
    act, env_id: str, seeds, episode_steps: int, action_repeat: int = 1, **env_kwargs
) -> np.ndarray:
    """Return of one episode per seed (env i reset with ``seeds[i]``) under ``act(obs) -> A``.

    Runs the native vector env with one env per seed, so every controller sees the same
    references; returns the undiscounted episode returns, shape (len(seeds),). ``act`` is
    asked every ``action_repeat`` steps and its current held in between.
    """
    import gymnasium as gym

    env = gym.make_vec(
        env_id, num_envs=len(seeds), max_episode_steps=int(episode_steps), **env_kwargs
    )
    obs, _ = env.reset(seed=[int(s) for s in seeds])
    total = np.zeros(len(seeds))
    a = np.zeros((len(seeds), 1))
    for k in range(int(episode_steps)):
        if k % action_repeat == 0:
            a = np.asarray(act(obs), dtype=np.float64).reshape(len(seeds), 1)
        obs, r, _, _, _ = env.step(a)
        total += r
    env.close()
    return total


def _learning_curve(out: Path, title: str) -> Path | None:
    import csv

    path = out / "progress.csv"
    if not path.is_file():
        return None
    xs, ys = [], []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            if row.get("rollout/ep_rew_mean") not in (None, ""):
                xs.append(float(row["time/total_timesteps"]))
                ys.append(float(row["rollout/ep_rew_mean"]))
    if not xs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(xs, ys, marker=".")
    ax.set_xlabel("env steps")
    ax.set_ylabel("mean episode return")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    png = out / "learning_curve.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png


def _sb3_config(algo: str, config: str | Path | dict) -> dict:
    """The SB3 config of ``algo`` (file or dict), its algo and keys checked."""
    if algo not in ALGOS:
        raise ValueError(f"algo = {algo!r} is not allowed: use one of {list(ALGOS)}")
    cfg = load_agent_config(config) if not isinstance(config, dict) else config
    if cfg.get("algo") != algo:
        raise ConfigError(
            f"config {config if not isinstance(config, dict) else '<dict>'}: "
            f"algo = {cfg.get('algo')!r}, but --algo {algo}"
        )
    for key in ("n_envs", "episode_steps", "total_timesteps", "hyperparameters"):
        if key not in cfg:
            raise ConfigError(f"config is missing {key!r}")
    return cfg


def _sb3_model(algo: str, cfg: dict, env_id: str, kwargs: dict, seed: int, out: Path, verbose):
    """(model, its wrapped vector env, the native env under it), logging to ``out``."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from .sb3 import make_sb3_vec_env

    repeat = int(cfg.get("action_repeat", 1))
    base = make_sb3_vec_env(
        env_id, int(cfg["n_envs"]), int(cfg["episode_steps"]), action_repeat=repeat, **kwargs
    )
    venv = VecMonitor(base)
    hp = dict(cfg["hyperparameters"])
    if cfg.get("normalize_reward", False):
        venv = VecNormalize(
            venv, norm_obs=False, norm_reward=True, gamma=float(hp.get("gamma", 0.99))
        )
    venv.seed(seed)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    model = cls(
        cfg.get("policy", "MlpPolicy"), venv, seed=seed, verbose=verbose, device="cpu", **hp
    )
    model.set_logger(configure(str(out), ["csv", "tensorboard"] + (["stdout"] if verbose else [])))
    return model, venv, base


def _export_and_evaluate(model, base, cfg: dict, env_id: str, kwargs: dict, out: Path, seeds):
    """Export the actor (``model.npz``); (its env settings, its returns on ``seeds``, the
    zero current's)."""

    repeat = int(cfg.get("action_repeat", 1))
    trained = base.venv.unwrapped
    policy_env = {
        "env_id": env_id,
        "preview_steps": trained.preview_steps,
        "normalize_observation": True,
        "action_scale_a": trained.coil_current_max_a,
    }
    export_policy(model, out / "model.npz", **policy_env, extra={"action_repeat": repeat})
    policy = NumpyPolicy(out / "model.npz")
    episode = int(cfg["episode_steps"])
    eval_kwargs = {k: v for k, v in kwargs.items() if k != "domain_randomization"}
    returns = evaluate(
        lambda o: policy(o), env_id, seeds, episode, action_repeat=repeat, **eval_kwargs
    )
    zero = evaluate(lambda o: np.zeros(len(o)), env_id, seeds, episode, **eval_kwargs)
    return policy_env, returns, zero


def train(
    algo: str,
    env_id: str,
    config: str | Path | dict,
    timesteps: int | None = None,
    seed: int = 0,
    out: str | Path = "runs/train",
    env_kwargs: dict | None = None,
    progress_bar: bool = True,
    eval_seeds=(9001, 9002, 9003, 9004),
    command: str = "",
    verbose: int = 0,
    torch_threads: int | None = 1,
) -> dict:
    """Train, save and evaluate; returns the summary written to ``train.json``.

    ``torch_threads=1`` (default): the networks are small, and one torch thread leaves the
    other core to the env and avoids oversubscription on a shared machine.
    """
    from stable_baselines3.common.utils import set_random_seed

    cfg = _sb3_config(algo, config)
    kwargs = {**(cfg.get("env_kwargs") or {}), **(env_kwargs or {})}
    if not kwargs.get("normalize_observation", False):
        raise ConfigError(
            "env_kwargs.normalize_observation must be true for learning agents "
            "(the exported policy records it; observations span 1e5 Pa and 1 N)"
        )
    timesteps = int(timesteps if timesteps is not None else cfg["total_timesteps"])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if torch_threads:
        import torch

        torch.set_num_threads(int(torch_threads))
    set_random_seed(seed)
    model, venv, base = _sb3_model(algo, cfg, env_id, kwargs, seed, out, verbose)
    t0 = time.perf_counter()
    model.learn(total_timesteps=timesteps, progress_bar=progress_bar)
    wall = time.perf_counter() - t0
    model.logger.close()  # flushes and closes progress.csv and the TensorBoard writer
    model.save(out / "model.zip")
    policy_env, returns, zero = _export_and_evaluate(
        model, base, cfg, env_id, kwargs, out, eval_seeds
    )
    summary = {
        "algo": algo,
        "env_id": env_id,
        "config": str(config) if not isinstance(config, dict) else "<dict>",
        "seed": seed,
        "timesteps": int(model.num_timesteps),
        "command": command,
        "n_envs": int(cfg["n_envs"]),
        "episode_steps": int(cfg["episode_steps"]),
        "env_kwargs": jsonable(kwargs),
        "wall_s": wall,
        "env_time_s": base.env_time_s,
        "env_share": base.env_time_s / wall,
        "action_repeat": int(cfg.get("action_repeat", 1)),
        "env_steps": int(base.env_steps),
        "env_steps_per_s": base.env_steps / wall,
        "env_only_steps_per_s": base.env_steps / base.env_time_s if base.env_time_s else None,
        "eval_seeds": list(eval_seeds),
        "eval_return_mean": float(returns.mean()),
        "eval_return_zero_current": float(zero.mean()),
        "policy_env": policy_env,
    }
    (out / "train.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    _learning_curve(out, f"{algo} on {env_id} (seed {seed})")
    venv.close()
    return summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rig",
        metavar="REPORT_DIR",
        help="train a controller for the fitted rig of `pneumatic-env identify --report "
        "REPORT_DIR` (writes OUT/controller.npz and OUT/summary.md; no --algo or --env)",
    )
    parser.add_argument(
        "--base",
        choices=("auto", "sliding_mode", "pid"),  # rig_base.BASE_CHOICES (a test checks)
        help="with --rig: the residual's base controller (default auto: of PID nominal and "
        "retuned and the sliding mode on the nominal and the fitted model, the lowest mean "
        "RMS error on the fitted rig; a kind: the better of its two)",
    )
    parser.add_argument("--algo", choices=ALGOS + ("ppo_fast",), help="required without --rig")
    parser.add_argument(
        "--env", help="env id, e.g. pneumatic_env/ForceTrack-Numatics-2m-v0 (without --rig)"
    )
    parser.add_argument(
        "--config", help="hyperparameter YAML (default configs/agents/<algo>-<variant>.yaml)"
    )
    parser.add_argument(
        "--timesteps",
        "--steps",
        type=int,
        help="env steps (default: the config's; ppo_fast: a cap besides --minutes)",
    )
    parser.add_argument(
        "--minutes",
        type=float,
        help="ppo_fast: wall-time budget of the training (default: the config's training.minutes)",
    )
    parser.add_argument(
        "--resume", action="store_true", help="ppo_fast: continue from OUT/checkpoint.pt"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="output directory (default runs/<algo>-<variant>-s<seed>)")
    parser.add_argument(
        "--env-kwargs",
        default="{}",
        help="JSON merged into the config's "
        'env_kwargs, e.g. \'{"domain_randomization": '
        '{"supply_pressure_pa": 0.1}}\'',
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import pneumatic_env  # noqa: F401  (registers the ids)

    if args.rig:
        from .rig_training import run as run_rig  # imports torch: only when it runs

        return run_rig(args)
    if args.base:
        raise SystemExit("pneumatic-env train: --base goes with --rig REPORT_DIR")
    if not args.algo or not args.env:
        raise SystemExit("pneumatic-env train: give --algo and --env (or --rig REPORT_DIR)")
    if args.env not in gym.registry:
        raise SystemExit(
            f"--env {args.env!r} is not registered: use one of {pneumatic_env.registered_ids()}"
        )
    if args.algo == "ppo_fast":
        from .ppo import run_fast  # imports torch: only when ppo_fast runs

        return run_fast(args)
    variant = _variant_of(args.env)
    config = args.config or agent_config_path(f"{args.algo}-{variant}")
    if not Path(config).is_file():
        raise SystemExit(
            f"no config {config}: write configs/agents/{args.algo}-{variant}.yaml or pass --config"
        )
    try:
        extra = json.loads(args.env_kwargs)
    except json.JSONDecodeError as exc:
        raise SystemExit(f"--env-kwargs is not valid JSON: {exc}") from None
    if not isinstance(extra, dict):
        raise SystemExit(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r}")
    out = args.out or f"runs/{args.algo}-{variant}-s{args.seed}"
    command = "pneumatic-env " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    s = train(
        args.algo,
        args.env,
        config,
        args.timesteps,
        args.seed,
        out,
        extra,
        progress_bar=not args.no_progress,
        command=command,
    )
    print(
        f"{s['timesteps']} steps in {s['wall_s']:.1f} s ({s['env_steps_per_s']:.0f} env steps/s, "
        f"{100 * s['env_share']:.0f} % of wall time in the env); eval return "
        f"{s['eval_return_mean']:.1f} (zero current {s['eval_return_zero_current']:.1f}); "
        f"wrote {out}"
    )
    return 0
