"""``pneumatic-env train --rig REPORT_DIR --out OUT``: a controller for the rig an
identification report describes (``agents.rig``).

Stages: the gains of PID and of the sliding mode (on the fitted and on the nominal model)
searched on the fitted rig and the suite there for the classical controllers, which
chooses the residual's base (``agents.rig_base``); the fast trainer (``agents.ppo``, the variant's
``configs/agents/ppo_fast-<variant>.yaml`` with that base and its gains) on the fitted rig
with the report's domain randomisation (``agents.rig.rig_randomization``); the final actor
written self-contained (``agents.learned.write_self_contained``: the fitted model, the
base controller's kind and gains and the model it runs on inside); the suite on the
fitted rig for it. Written to ``OUT``:

- ``controller.npz``: runs by file name (``pneumatic-env bench --controller
  OUT/controller.npz``, ``resolve_controller``) with no report or config;
- ``summary.md``: the suite's figures on the fitted rig of the new controller, PID and
  the sliding mode at their nominal tuning (the package's model of the rig and the
  benchmark's gains) and retuned for the fitted rig, and the base chosen and why;
- ``rig_training.json``: the same figures, the base, the retuned gains, the randomisation;
- ``training/``: the trainer's output (``actor.npz``, ``progress.csv``, ``train.json``).

The trainer's validation runs on the registered variant, not the fitted rig, so the final
actor is used (not ``actor_best.npz``). The fitted rig's sensors carry the recordings'
noise (``agents.rig``), so its suite shows how much a controller turns noise into valve
chatter (``rig_base.max_chatter_ratio`` x the sliding mode's at nominal tuning holds the
base's and the residual's). If the trained actor
does not cut its base's mean RMS error on the fitted rig by
``rig_base.min_residual_gain`` (2 %: the fitted rig is not the rig), or its chatter is
over that limit and its base's, or its air over ``rig_base.max_air_ratio`` x the same
sliding mode's and its base's, its residual is zeroed
(``agents.learned.zero_the_residual``): the file then runs the base bit for bit, and
``summary.md`` and ``rig_training.json`` (``base.residual_zeroed``) say so with the
trained actor's figures. With ``base="auto"`` the shipped learned controllers of the
variant are scored on the fitted rig too (``agents.rig_shipped``): the best of them
becomes ``controller.npz`` if it cuts the error of the file written so far there by
``rig_base.min_shipped_gain`` (10 %) within the chatter and air limits (``base.shipped`` says so;
the trained file is kept in ``training/controller_trained.npz``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym

from .base import ControllerContext
from .config import agent_config_path, load_agent_config
from .learned import write_self_contained, zero_the_residual
from .ppo import train
from .registry import classical_gains
from .rig import FittedRig, load_rig, rig_randomization
from .rig_base import (
    CHATTER_REFERENCE,
    candidate_base,
    chatter_limit,
    check_base,
    classical_and_base,
    reference_limit,
    retuned_gains,
)
from .rig_shipped import SHIPPED_SUFFIX, adopt_shipped, best_shipped, shipped_for
from .rig_summary import suite_summary, summary_markdown
from .suite import Suite, load_suite

__all__ = ["DEFAULT_MINUTES", "train_for_rig", "run"]

#: default wall-time budget of the training (min): the budget of the nine-rig evaluation
#: (docs/benchmark.md; 10 min gave the same ratio on its spool-friction rig, 0.97 and
#: 0.97), which leaves identify about 14 of the issue's 20 min on 2 cores
DEFAULT_MINUTES = 5.0


def _train_residual(
    rig: FittedRig,
    out: Path,
    randomization: dict,
    base: tuple[str, dict, dict | None],
    *,
    minutes: float | None,
    steps: float | None,
    seed: int,
    overrides: dict | None,
    log: Callable,
) -> tuple[str, dict] | None:
    """The fast trainer on the fitted rig with ``randomization``, a residual on ``base``
    (kind, gains, model parameters or None: the env's); returns the base (kind, gains) the
    actor was trained on (None for a pure actor)."""
    config = agent_config_path(f"ppo_fast-{rig.variant.lower()}")
    env_kwargs = {**rig.env_options, "domain_randomization": randomization}
    merged = {
        **{f"env_kwargs.{k}": v for k, v in env_kwargs.items()},
        # the validation of the registered variant: the rig's tube may have none
        "residual.variant": rig.variant,
        "residual.base": base[0],
        "residual.gains": dict(base[1]),
        "residual.base_model_params": base[2],
        "training.validation_variants": [rig.variant],
        **(overrides or {}),
    }
    log(f"[4/5] training ({minutes} min, {steps} steps at most) from {config.name}")
    training = train(
        config, rig.env_id, seed, out / "training", minutes, steps, overrides=merged, log=log
    )
    trained = training["config"].get("residual")
    if trained is None:
        return None
    kind = trained["base"]
    return kind, dict(trained.get("gains") or classical_gains(kind, rig.variant))


def _zero_if_it_loses(rig, path, figures, record, suite, log, rig_base: dict) -> list[dict]:
    """Zero the residual of ``path`` (``zero_the_residual``) if its figures on the fitted rig
    (``figures[0]``) do not cut its base's (``record``, from ``choose_base``) mean RMS
    error by ``rig_base["min_residual_gain"]``, or exceed ``chatter_limit`` and the base's
    chatter, or ``rig_base["max_air_ratio"]`` x the reference's air and the base's; then the
    file's figures anew and ``record["residual_zeroed"]`` with the trained ones. Returns
    the figures."""
    trained = figures[0]
    base_row = {f["controller"]: f for f in figures[1:]}[record["controller"]]
    base_rms = base_row["rms_error_pct"]
    max_chatter_ratio, min_gain = rig_base["max_chatter_ratio"], rig_base["min_residual_gain"]
    limit = max(chatter_limit(figures[1:], max_chatter_ratio), base_row["chatter_rms_a"])
    air_ratio = rig_base["max_air_ratio"]
    air = max(reference_limit(figures[1:], "air_mg", air_ratio), base_row["air_mg"])
    if trained["rms_error_pct"] > base_rms * (1.0 - min_gain):
        reason = (
            f"the trained residual ({trained['rms_error_pct']:.2f} %) did not cut its base's "
            f"error ({base_rms:.2f} %) by {100 * min_gain:g} % on the fitted rig "
            "(rig_base.min_residual_gain): the file runs the base"
        )
    elif trained["chatter_rms_a"] > limit:
        reason = (
            f"the trained residual's chatter ({trained['chatter_rms_a']:.4f} A) is over "
            f"{limit:.4f} A ({max_chatter_ratio} x {CHATTER_REFERENCE}'s, or its base's) "
            "on the fitted rig: the file runs the base"
        )
    elif trained["air_mg"] > air:
        reason = (
            f"the trained residual's air ({trained['air_mg']:.1f} mg) is over {air:.1f} mg "
            f"({air_ratio} x {CHATTER_REFERENCE}'s, or its base's) on the fitted rig: the "
            "file runs the base"
        )
    else:
        return figures
    log(f"      {reason}")
    record["residual_zeroed"] = {"reason": reason, "trained": figures[0]}
    zero_the_residual(path, reason)
    return suite_summary(rig, [str(path)], suite) + figures[1:]


def _shipped_figures(rig: FittedRig, suite: Suite, names: list[str]) -> list[dict]:
    """The suite's figures on the fitted rig of the shipped actors ``names`` that have one
    for the rig's variant (``shipped_for``), rows named ``<name> (shipped)``."""
    rows = suite_summary(rig, shipped_for(names, rig.variant), suite)
    return [{**f, "controller": f["controller"] + SHIPPED_SUFFIX} for f in rows]


def _adopt_if_better(rig, path, figures, shipped, record, context, suite, log, rig_base):
    """Write the best shipped actor (``best_shipped``) as ``path`` if it cuts the trained
    controller's error (``figures[0]``) on the fitted rig by ``rig_base["min_shipped_gain"]``
    within the chatter and air limits; then the file's figures anew and ``record["shipped"]``.
    Returns the figures."""
    limit = chatter_limit(figures[1:], rig_base["max_chatter_ratio"])
    air = reference_limit(figures[1:], "air_mg", rig_base["max_air_ratio"])
    best = best_shipped(figures[0], shipped, limit, rig_base["min_shipped_gain"], air)
    if best is None:
        return figures
    name = best["controller"].removesuffix(SHIPPED_SUFFIX)
    kept = adopt_shipped(name, rig.variant, context, path)
    reason = (
        f"The shipped {name} ({best['rms_error_pct']:.2f} %) beat the trained controller "
        f"({figures[0]['rms_error_pct']:.2f} %) on the fitted rig by more than "
        f"{100 * rig_base['min_shipped_gain']:g} % within the chatter and air limits, "
        f"so controller.npz is {name} with the fitted model (the trained one: {kept})"
    )
    log(f"      {reason}")
    record["shipped"] = {"adopted": name, "reason": reason, "trained": figures[0]}
    return suite_summary(rig, [str(path)], suite) + figures[1:]


def train_for_rig(
    report_dir: str | Path,
    out: str | Path,
    minutes: float | None = DEFAULT_MINUTES,
    steps: float | None = None,
    seed: int = 0,
    overrides: dict | None = None,
    tuning: dict | None = None,
    suite: Suite | None = None,
    command: str = "",
    log: Callable = print,
    base: str = "auto",
) -> dict:
    """Train a controller for the report's rig; writes ``OUT/controller.npz``,
    ``OUT/summary.md`` and ``OUT/rig_training.json``. ``overrides``: more ppo_fast config
    overrides; ``tuning``: the PID search (default ``configs/agents/tuning.yaml``);
    ``base``: the residual's base (``BASE_CHOICES``; ``choose_base``). Returns the summary
    figures, the controller's path and the base."""
    check_base(base)
    tuning = tuning or load_agent_config("tuning", raw=("references",))
    rig, out = load_rig(report_dir), Path(out)
    suite = suite or load_suite()
    log(f"[1/5] rig: {rig.cylinder}, tube {rig.params['tube_length_m']:g} m -> {rig.env_id}")
    randomization = rig_randomization(report_dir)
    log(f"[2/5] PID, sliding-mode gains searched ({len(randomization)} randomised params)")
    retuned = retuned_gains(rig, tuning)
    log(
        "[3/5] suite on the fitted rig: PID and sliding mode, nominal and retuned, each "
        "with its reference smoothing searched; the shipped learned controllers"
    )
    rig_base = tuning["rig_base"]
    classical, chosen, tried = classical_and_base(rig, retuned, suite, rig_base, base)
    log(f"      residual base: {chosen['controller']} ({chosen['reason']})")
    # a kind asked for (--base) asks for a residual on it: no shipped actor instead
    candidates = rig_base["shipped_candidates"] if base == "auto" else []
    shipped = _shipped_figures(rig, suite, candidates)
    held = _train_residual(
        rig,
        out,
        randomization,
        candidate_base(rig, chosen["candidate"], retuned, chosen["smoothing_steps"]),
        minutes=minutes,
        steps=steps,
        seed=seed,
        overrides=overrides,
        log=log,
    )
    probe = gym.make_vec(
        rig.env_id, num_envs=1, preview_steps=suite.preview_steps, **rig.env_options
    )
    context = ControllerContext.from_env(probe)
    probe.close()
    path = write_self_contained(
        out / "training" / "actor.npz",
        out / "controller.npz",
        context,
        held,
        name=f"rig-{rig.report_dir.name}",
        source=f"pneumatic-env train --rig {rig.report_dir}",
    )
    log(f"[5/5] suite on the fitted rig: {path.name}")
    figures = suite_summary(rig, [str(path)], suite) + classical
    gains = None if held is None else held[1]
    record = {**chosen, "gains": gains, "residual_zeroed": None, "shipped": None}
    if held is not None:
        figures = _zero_if_it_loses(rig, path, figures, record, suite, log, rig_base)
    figures = _adopt_if_better(rig, path, figures, shipped, record, context, suite, log, rig_base)
    figures += shipped
    figures[0]["controller"] = "controller.npz (train --rig)"
    (out / "summary.md").write_text(
        summary_markdown(rig, figures, record, command), encoding="utf-8"
    )
    written = {"figures": figures, "base": record, "retuned_gains": retuned}
    written |= {"reference_smoothing": tried, "randomization": randomization}
    (out / "rig_training.json").write_text(json.dumps(written, indent=2), encoding="utf-8")
    return {"figures": figures, "controller": str(path), "base": record}


def run(args) -> int:
    """``pneumatic-env train --rig REPORT_DIR [--out OUT] [--minutes M] [--steps N]
    [--base auto|pid|sliding_mode]``."""
    import shlex
    import sys

    out = Path(args.out or Path("runs") / f"rig-{Path(args.rig).name}")
    command = "pneumatic-env " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    minutes = args.minutes if args.minutes is not None else DEFAULT_MINUTES
    base = getattr(args, "base", None) or "auto"
    res = train_for_rig(
        args.rig, out, minutes, args.timesteps, args.seed, command=command, base=base
    )
    for f in res["figures"]:
        print(f"  {f['controller']}: mean RMS {f['rms_error_pct']:.2f} %")
    print(f"  residual base: {res['base']['controller']} ({res['base']['reason']})")
    if res["base"]["shipped"]:
        print(f"  {res['base']['shipped']['reason']}")
    print(f"wrote {res['controller']} and {out / 'summary.md'}")
    return 0
