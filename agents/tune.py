"""``pneumatic-env tune``: hyperparameter search of the fast trainer (rl-zoo style).

    pneumatic-env tune --env pneumatic_env/ForceTrack-Numatics-2m-v0 \\
        [--space configs/agents/tune-ppo_fast.yaml] [--trials N] [--minutes-per-trial M] \\
        [--steps-per-trial S] [--storage sqlite:///runs/tune/study.db] [--study-name NAME] \\
        [--out DIR] [--ray-address ADDR]

Optuna's TPE sampler proposes the values of ``search_space`` (dotted paths into the
ppo_fast config); each trial trains ``agents/ppo.py`` for ``minutes_per_trial`` of wall
time, or for ``steps_per_trial`` env steps if given (then the minutes are only a cap), and
evaluates on the validation references after every budget slice; the median pruner stops
trials whose intermediate value is worse than the median of earlier trials at the same
slice. The objective is the validation mean RMS error (%) at the end of the trial, plus
``objective.chatter_pct_per_a`` times the validation chatter (A) if the file sets it.
``--storage`` (default ``sqlite:///<out>/study.db``) keeps the study: running the command
again with the same ``--study-name`` continues it until ``--trials`` trials are finished.
The best values are written to ``<out>/best.json`` and ``<out>/ppo_fast-tuned.yaml`` (the
base config with them, sources naming the study).

``--ray-address ADDR`` (``auto``, ``ray://host:10001`` or ``local`` for a local instance)
runs the trials on Ray Tune with the Optuna searcher (same space, TPE) and Ray's median
stopping rule; results and the restore point in ``<out>/ray``. Ray is the optional
``distributed`` extra and is imported only then.
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

from pneumatic_env.config_files import make_entry, read_yaml

from .config import ConfigError, agent_config_path, load_agent_config, write_agent_config
from .ppo_config import load_config

__all__ = [
    "load_space",
    "suggest",
    "objective",
    "score",
    "objective_name",
    "run_local",
    "run_ray",
    "write_best",
    "add_arguments",
    "run",
]

TYPES = ("float", "int", "categorical")
METRIC = "val_rms_pct"


def load_space(path: str | Path = "tune-ppo_fast") -> dict:
    """The tuning file with entries resolved; its search space checked. ``units`` maps each
    search-space key to its entry's unit (the tuned config's units)."""
    spec = load_agent_config(path)
    space = spec.get("search_space")
    if not isinstance(space, dict) or not space:
        raise ConfigError(f"{path}: missing the 'search_space' mapping")
    raw = read_yaml(agent_config_path(path)).get("search_space") or {}
    spec["units"] = {
        k: str(v.get("unit", "-")) if isinstance(v, dict) else "-" for k, v in raw.items()
    }
    for key, dim in space.items():
        where = f"{path}: search_space.{key}"
        if not isinstance(dim, dict) or dim.get("type") not in TYPES:
            raise ConfigError(
                f"{where} = {dim!r} is not allowed: a mapping with type in {list(TYPES)}"
            )
        if dim["type"] == "categorical":
            if not isinstance(dim.get("choices"), list) or not dim["choices"]:
                raise ConfigError(f"{where}: a categorical needs a non-empty 'choices' list")
        elif not (
            isinstance(dim.get("low"), (int, float))
            and isinstance(dim.get("high"), (int, float))
            and dim["low"] < dim["high"]
        ):
            raise ConfigError(
                f"{where}: low = {dim.get('low')!r}, high = {dim.get('high')!r} "
                "is not allowed: numbers with low < high"
            )
    return spec


def suggest(trial, space: dict) -> dict:
    """Config overrides {"section.name": value} drawn by an Optuna trial."""
    out = {}
    for key, dim in space.items():
        if dim["type"] == "float":
            out[key] = trial.suggest_float(
                key, dim["low"], dim["high"], log=bool(dim.get("log", False))
            )
        elif dim["type"] == "int":
            out[key] = trial.suggest_int(
                key, int(dim["low"]), int(dim["high"]), log=bool(dim.get("log", False))
            )
        else:
            out[key] = trial.suggest_categorical(key, dim["choices"])
    return out


def _chatter_weight(spec: dict) -> float:
    """``objective.chatter_pct_per_a`` of the tuning file (%/A; 0 if unset)."""
    return float((spec.get("objective") or {}).get("chatter_pct_per_a", 0.0))


def objective_name(spec: dict) -> str:
    """What :func:`score` measures, for messages and the tuned config's sources."""
    weight = _chatter_weight(spec)
    extra = f" + {weight:g} %/A x validation chatter" if weight else ""
    return f"validation RMS (%){extra}"


def score(spec: dict, record: dict) -> float:
    """The objective of one validation record: ``val_rms_pct`` plus, if the tuning file
    sets ``objective.chatter_pct_per_a``, that weight times ``val_chatter_a``."""
    return float(record[METRIC]) + _chatter_weight(spec) * float(record.get("val_chatter_a", 0.0))


def _train_trial(
    params: dict,
    spec: dict,
    env_id: str,
    seed: int,
    out: Path,
    minutes: float,
    report,
    steps: float | None = None,
) -> float:
    """Train one trial; ``report(value, slice)`` after each evaluation; the last value.

    With ``steps`` the trial ends after that many env steps and evaluates every
    ``steps / slices`` (``minutes`` is then only a cap), so a loaded machine does not
    change what a trial learns; else it runs ``minutes`` and evaluates by wall time."""
    from .ppo import train  # imports torch: only when a trial runs

    slices = int(spec["budget"]["slices"])
    if steps:
        overrides = {
            **params,
            "training.eval_every_s": 1.0e12,
            "training.eval_every_steps": float(steps) / slices,
        }
    else:
        overrides = {**params, "training.eval_every_s": 60.0 * minutes / slices}
    count = {"n": 0}

    def on_eval(record):
        count["n"] += 1
        report(score(spec, record), count["n"])

    s = train(
        agent_config_path(spec["base_config"]),
        env_id,
        seed,
        out,
        minutes,
        total_steps=steps,
        overrides=overrides,
        on_eval=on_eval,
        log=lambda *a, **k: None,
    )
    return score(spec, s["curve"][-1])


def objective(
    spec: dict, env_id: str, seed: int, out: Path, minutes: float, steps: float | None = None
):
    """The Optuna objective: train with the trial's values, report per slice, prune."""
    import optuna

    def run_trial(trial) -> float:
        params = suggest(trial, spec["search_space"])

        def report(value, step):
            # Optuna counts steps from 0 and prunes from step n_warmup_steps on, so slice 1
            # is step 0: n_warmup_steps = 1 keeps every trial's first evaluation
            trial.report(value, step - 1)
            if trial.should_prune():
                raise optuna.TrialPruned(f"slice {step}: {objective_name(spec)} = {value:.3f}")

        return _train_trial(
            params,
            spec,
            env_id,
            seed + trial.number,
            out / f"trial-{trial.number:03d}",
            minutes,
            report,
            steps,
        )

    return run_trial


def _study(spec: dict, storage: str, name: str, seed: int):
    import optuna

    sampler = optuna.samplers.TPESampler(
        n_startup_trials=int(spec["sampler"]["n_startup_trials"]), seed=seed
    )
    pruner = optuna.pruners.MedianPruner(
        n_startup_trials=int(spec["pruner"]["n_startup_trials"]),
        n_warmup_steps=int(spec["pruner"]["n_warmup_steps"]),
    )
    return optuna.create_study(
        storage=storage,
        study_name=name,
        direction="minimize",
        sampler=sampler,
        pruner=pruner,
        load_if_exists=True,
    )


def run_local(
    spec: dict,
    env_id: str,
    out: Path,
    trials: int,
    minutes: float,
    storage: str,
    name: str,
    seed: int = 0,
    steps: float | None = None,
):
    """Run (or continue) the study until ``trials`` trials are complete or pruned."""
    import optuna

    study = _study(spec, storage, name, seed)
    done = sum(
        t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
        for t in study.trials
    )
    if trials > done:
        study.optimize(
            objective(spec, env_id, seed, out, minutes, steps),
            n_trials=trials - done,
            catch=(),
        )
    return study


def _define_space(trial, search_space: dict) -> None:
    """Ray's OptunaSearch define-by-run space: the trial's suggestions (:func:`suggest`)."""
    suggest(trial, search_space)


def run_ray(
    spec: dict,
    env_id: str,
    out: Path,
    trials: int,
    minutes: float,
    address: str,
    name: str,
    seed: int = 0,
    steps: float | None = None,
) -> dict:
    """The trials on Ray Tune with the Optuna searcher; resumes ``<out>/ray/<name>``."""
    import optuna
    import ray
    from ray import tune
    from ray.tune.schedulers import MedianStoppingRule
    from ray.tune.search.optuna import OptunaSearch

    try:  # Ray >= 2.41
        from ray.tune import report as ray_report
    except ImportError:  # Ray 2.9-2.40
        from ray.train import report as ray_report
    run_config_cls = getattr(tune, "RunConfig", None)
    if run_config_cls is None:
        from ray.train import RunConfig as run_config_cls
    if not ray.is_initialized():
        ray.init(address=None if address == "local" else address)
    out = out.resolve()

    def trainable(params: dict) -> None:
        def report(value, step):
            ray_report({METRIC: value, "slice": step})

        _train_trial(
            params,
            spec,
            env_id,
            seed,
            out / "trials" / tune.get_context().get_trial_id(),
            minutes,
            report,
            steps,
        )

    searcher = OptunaSearch(
        # define-by-run; Ray pickles the searcher, so no local function here
        space=functools.partial(_define_space, search_space=spec["search_space"]),
        metric=METRIC,
        mode="min",
        sampler=optuna.samplers.TPESampler(
            n_startup_trials=int(spec["sampler"]["n_startup_trials"]), seed=seed
        ),
    )
    scheduler = MedianStoppingRule(
        time_attr="training_iteration",
        metric=METRIC,
        mode="min",
        grace_period=int(spec["pruner"]["n_warmup_steps"]) + 1,
        min_samples_required=int(spec["pruner"]["n_startup_trials"]),
    )
    resources = tune.with_resources(trainable, {"cpu": 2})
    path = out / "ray" / name
    if tune.Tuner.can_restore(str(path)):
        tuner = tune.Tuner.restore(str(path), trainable=resources, resume_errored=True)
    else:
        tuner = tune.Tuner(
            resources,
            tune_config=tune.TuneConfig(
                search_alg=searcher, scheduler=scheduler, num_samples=trials
            ),
            run_config=run_config_cls(name=name, storage_path=str(out / "ray")),
        )
    best = tuner.fit().get_best_result(metric=METRIC, mode="min")
    return {"value": float(best.metrics[METRIC]), "params": dict(best.config)}


def write_best(spec: dict, params: dict, value: float, out: Path, name: str) -> Path:
    """``best.json`` and ``ppo_fast-tuned.yaml``: the base config with the tuned values."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "best.json").write_text(json.dumps({"value": value, "params": params}, indent=2))
    tree = read_yaml(agent_config_path(spec["base_config"]))
    for key, value_ in params.items():
        *sections, leaf = key.split(".")
        node = tree
        for s in sections:
            node = node.setdefault(s, {})
        old = node.get(leaf)
        unit = (spec.get("units") or {}).get(key, "-")
        entry = dict(old) if isinstance(old, dict) and "value" in old else {"unit": unit}
        entry["value"] = value_
        entry["source"] = (
            f"tuned: pneumatic-env tune, study {name!r} ({objective_name(spec)} {value:.3f})"
        )
        node[leaf] = make_entry(entry["value"], entry["unit"], entry["source"])
    path = out / "ppo_fast-tuned.yaml"
    write_agent_config(
        path,
        tree,
        header=f"ppo_fast config tuned by pneumatic-env tune "
        f"(study {name}); base: {spec['base_config']}",
    )
    return path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default=None, help="env id (default: the base config's)")
    parser.add_argument(
        "--space",
        default="tune-ppo_fast",
        help="tuning file (default configs/agents/tune-ppo_fast.yaml)",
    )
    parser.add_argument("--trials", type=int, help="trials to finish (default: the file's)")
    parser.add_argument(
        "--minutes-per-trial", type=float, help="wall time per trial (a cap with steps)"
    )
    parser.add_argument(
        "--steps-per-trial",
        type=float,
        help="env steps per trial (default: the file's budget.steps_per_trial, if any)",
    )
    parser.add_argument("--storage", help="Optuna storage URL (default sqlite:///OUT/study.db)")
    parser.add_argument("--study-name", default="ppo_fast", help="study to create or continue")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/tune", help="output directory")
    parser.add_argument(
        "--ray-address",
        help="run the trials on Ray Tune at this address "
        "('local' starts one here); needs the 'distributed' extra",
    )


def run(args: argparse.Namespace) -> int:
    spec = load_space(args.space)
    env_id = args.env or load_config(agent_config_path(spec["base_config"])).env
    trials = int(args.trials if args.trials is not None else spec["budget"]["trials"])
    minutes = float(args.minutes_per_trial or spec["budget"]["minutes_per_trial"])
    steps = args.steps_per_trial or spec["budget"].get("steps_per_trial")
    if steps is not None and not float(steps) > 0:
        raise SystemExit(
            f"--steps-per-trial (budget.steps_per_trial) = {steps!r} is not allowed: "
            "must be a number > 0"
        )
    steps = float(steps) if steps is not None else None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.ray_address:
        try:
            best = run_ray(
                spec,
                env_id,
                out,
                trials,
                minutes,
                args.ray_address,
                args.study_name,
                args.seed,
                steps,
            )
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] != "ray":
                raise
            raise SystemExit(
                "--ray-address needs Ray: pip install 'pneumatic_env[distributed]'"
            ) from None
        value, params = best["value"], best["params"]
    else:
        storage = args.storage or f"sqlite:///{(out / 'study.db').resolve()}"
        study = run_local(
            spec, env_id, out, trials, minutes, storage, args.study_name, args.seed, steps
        )
        import optuna

        if not any(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials):
            raise SystemExit(
                f"study {args.study_name!r}: no trial completed (all pruned or "
                "failed); raise --trials or --minutes-per-trial"
            )
        value, params = study.best_value, study.best_params
    path = write_best(spec, params, value, out, args.study_name)
    print(f"best {objective_name(spec)} {value:.3f} with {params}; wrote {path}")
    return 0
