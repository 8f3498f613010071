"""``pneumatic-env train --rig REPORT_DIR --out OUT``: a controller for the rig an
identification report describes (``agents.rig``).

Stages: the gains of PID and of the sliding mode (on the fitted and on the nominal model)
searched on the fitted rig (``retuned_gains``: ``agents.tune_pid.grid_search``); the suite
on the fitted rig for the classical controllers, which chooses the residual's base
(``base="auto"``: the one of ``BASE_CANDIDATES`` with the lowest mean RMS error there:
PID nominal or retuned, the sliding mode on the nominal or the fitted model, at the
benchmark's gains or retuned, each also with its reference smoothed; a long tube's waves
and heat transfer can leave the sliding mode well behind PID, a fit that trades one
parameter for another can leave the sliding mode on the fitted model behind the nominal
one, and spool friction favours other sliding-mode gains than the benchmark's); the fast
trainer (``agents.ppo``, the variant's
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
chatter: a base candidate whose chatter is over ``rig_base.max_chatter_ratio`` x the
sliding mode's at nominal tuning is not chosen (unless all are). If the trained actor
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

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym

from .base import ControllerContext, ControllerSpec
from .config import agent_config_path, load_agent_config
from .learned import write_self_contained, zero_the_residual
from .ppo import train
from .registry import classical_gains
from .residual import BASE_CLASSES, BASE_CONTROLLERS
from .rig import FittedRig, load_rig, rig_randomization
from .rig_shipped import SHIPPED_SUFFIX, adopt_shipped, best_shipped, shipped_for
from .rig_summary import suite_summary, summary_markdown
from .suite import Suite, load_suite
from .tune_pid import grid_search

__all__ = [
    "DEFAULT_MINUTES",
    "BASE_CHOICES",
    "BASE_CANDIDATES",
    "RETUNED",
    "retuned_gains",
    "train_for_rig",
    "choose_base",
    "chatter_limit",
    "reference_limit",
    "CHATTER_REFERENCE",
    "candidate_base",
    "rig_controllers",
    "suite_summary",
    "run",
]

#: default wall-time budget of the training (min): the budget of the nine-rig evaluation
#: (docs/benchmark.md; 10 min gave the same ratio on its spool-friction rig, 0.97 and
#: 0.97), which leaves identify about 14 of the issue's 20 min on 2 cores
DEFAULT_MINUTES = 5.0

#: the residual's possible bases, the classical controllers of ``rig_controllers``: name ->
#: (kind, the model it runs on: the fitted rig's or the package's nominal one). Those in
#: ``RETUNED`` have the gains searched on the fitted rig (``retuned_gains``), the others
#: the benchmark's gains of the variant. The first wins a tie (the trainer configs' own
#: base).
BASE_CANDIDATES = {
    "sliding_mode (fitted model)": ("sliding_mode", "fitted"),
    "sliding_mode (nominal model)": ("sliding_mode", "nominal"),
    "pid (retuned on the fitted rig)": ("pid", "fitted"),
    "pid (nominal)": ("pid", "nominal"),
    "sliding_mode (fitted model, retuned on the fitted rig)": ("sliding_mode", "fitted"),
    "sliding_mode (nominal model, retuned on the fitted rig)": ("sliding_mode", "nominal"),
}
#: the candidates whose gains are searched on the fitted rig (PID has no model: "fitted")
RETUNED = tuple(name for name in BASE_CANDIDATES if "retuned on the fitted rig" in name)
#: the chatter a controller for the rig is held to is a multiple of this one's
#: (``rig_base.max_chatter_ratio``, issue 35 target 1: the sliding mode at nominal tuning)
CHATTER_REFERENCE = "sliding_mode (nominal model)"
#: ``train_for_rig(base=...)``, ``--base``: a kind (its better candidate) or "auto" (the best)
BASE_CHOICES = ("auto", *BASE_CONTROLLERS)


def smoothed_name(name: str, steps: int) -> str:
    """The row of the base candidate ``name`` tracking its reference smoothed over +-steps."""
    return f"{name}, reference smoothed +-{steps}"


def _named_candidates(smoothing: dict[str, int] | None = None) -> dict[str, tuple[str, int]]:
    """Row name -> (``BASE_CANDIDATES`` name, reference smoothing W): the candidates
    as they are, and each one given in ``smoothing`` with its W."""
    out = {name: (name, 0) for name in BASE_CANDIDATES}
    out.update({smoothed_name(n, w): (n, w) for n, w in (smoothing or {}).items()})
    return out


def _model_params(rig: FittedRig, model: str) -> dict | None:
    """The parameters of a candidate's model: the nominal one's, or None (the env's, i.e.
    the fitted rig's)."""
    return rig.nominal_parameters() if model == "nominal" else None


def retuned_gains(rig: FittedRig, tuning: dict | None = None) -> dict[str, dict]:
    """{candidate of ``RETUNED``: its gains}: the tuning grid of its kind
    (``configs/agents/tuning.yaml``) best on the fitted rig with exact sensors
    (``FittedRig.noiseless_env_options``) with the controller on the candidate's model,
    with the grid's fixed values."""
    tuning = tuning or load_agent_config("tuning", raw=("references",))
    out = {}
    for name in RETUNED:
        kind, model = BASE_CANDIDATES[name]
        res = grid_search(
            kind,
            rig.variant,
            tuning,
            rig.noiseless_env_options,
            base_params=_model_params(rig, model),
        )
        best = zip(res["names"], res["combos"][res["best"]])
        out[name] = {**tuning[kind]["fixed"], **{n: float(v) for n, v in best}}
    return out


def _spec(name: str, kind: str, gains: dict, base_params: dict | None, preview: int):
    """A classical controller with ``gains``; on the model ``base_params`` if given (else
    the env's, i.e. the fitted rig's)."""

    def build(ctx: ControllerContext):
        if base_params is not None:
            ctx = dataclasses.replace(ctx, base_params=dict(base_params))
        return BASE_CLASSES[kind](ctx, **gains)

    return ControllerSpec(name, {"preview_steps": preview, "normalize_observation": False}, build)


def candidate_base(
    rig: FittedRig, name: str, retuned: dict[str, dict], smoothing_steps: int = 0
) -> tuple[str, dict, dict | None]:
    """(kind, gains, model parameters or None for the fitted rig's) of the base ``name``
    (``BASE_CANDIDATES``; the gains of one in ``RETUNED`` from ``retuned``, of
    ``retuned_gains``), tracking its reference smoothed over +-``smoothing_steps``
    (``Controller.smoothed_reference``) if > 0."""
    kind, model = BASE_CANDIDATES[name]
    gains = dict(retuned[name]) if name in RETUNED else classical_gains(kind, rig.variant)
    if smoothing_steps:
        gains["reference_smoothing_steps"] = int(smoothing_steps)
    return kind, gains, _model_params(rig, model)


def rig_controllers(rig: FittedRig, retuned: dict[str, dict], suite: Suite) -> list[ControllerSpec]:
    """PID and the sliding mode at nominal tuning (the benchmark's gains of the variant)
    and retuned for the fitted rig (``retuned``), on the package's model of the rig or the
    fitted one: ``BASE_CANDIDATES``."""
    return [
        _spec(name, *candidate_base(rig, name, retuned), suite.preview_steps)
        for name in BASE_CANDIDATES
    ]


def _smoothed_figures(rig, retuned, suite, grids: dict[str, list[int]], by_w: dict) -> None:
    """The suite's figures on the fitted rig of each candidate of ``grids`` at each of its
    W, into ``by_w[candidate][W]``."""
    specs = [
        _spec(f"{n}|{w}", *candidate_base(rig, n, retuned, w), suite.preview_steps)
        for n, grid in grids.items()
        for w in grid
    ]
    for f in suite_summary(rig, specs, suite) if specs else []:
        name, w = f["controller"].rsplit("|", 1)
        by_w[name][int(w)] = f


def _lowest_error(figures: dict[int, dict]) -> int:
    return min(figures, key=lambda w: (figures[w]["rms_error_pct"], w))


def search_smoothing(
    rig: FittedRig,
    retuned: dict[str, dict],
    classical: list[dict],
    suite: Suite,
    grid,
    air_grid=(),
    air_limit_mg: float = math.inf,
) -> tuple[dict[str, int], list[dict], dict[str, dict[int, float]]]:
    """The reference smoothing W of each base candidate searched on the fitted rig's suite:
    every W of ``grid`` beside the candidate's own figure (W = 0, ``classical``). A
    candidate whose best W uses more air than ``air_limit_mg`` tries the W of ``air_grid``
    too and takes the best W within the limit, if one is (a smoother reference asks for
    less air). Returns {candidate: its W, where not 0}, their figures (rows named
    ``smoothed_name``) and {candidate: {W: mean RMS error %}} of every W tried."""
    by_w: dict[str, dict[int, dict]] = {f["controller"]: {0: f} for f in classical}
    grid = sorted({int(w) for w in grid if int(w) > 0})
    _smoothed_figures(rig, retuned, suite, dict.fromkeys(BASE_CANDIDATES, grid), by_w)
    best = {n: _lowest_error(by_w[n]) for n in BASE_CANDIDATES}
    over = [n for n, w in best.items() if by_w[n][w]["air_mg"] > air_limit_mg]
    extra = sorted({int(w) for w in air_grid} - set(grid) - {0})
    _smoothed_figures(rig, retuned, suite, dict.fromkeys(over, extra), by_w)
    for n in over:
        within = {w: f for w, f in by_w[n].items() if f["air_mg"] <= air_limit_mg}
        best[n] = _lowest_error(within) if within else best[n]
    rows = [{**by_w[n][w], "controller": smoothed_name(n, w)} for n, w in best.items() if w]
    tried = {n: {w: by_w[n][w]["rms_error_pct"] for w in sorted(by_w[n])} for n in best}
    return {n: w for n, w in best.items() if w}, rows, tried


def _classical_and_base(rig: FittedRig, retuned: dict, suite: Suite, rig_base: dict, base: str):
    """Stage 3: the base candidates' figures on the fitted rig, each also with its best
    reference smoothing (``search_smoothing``: ``rig_base.reference_smoothing_steps``, and
    ``air_smoothing_steps`` within ``max_air_ratio``), and the base chosen among them
    (``choose_base`` with ``rig_base.max_chatter_ratio``). Returns (figures, the choice,
    every smoothing tried)."""
    classical = suite_summary(rig, rig_controllers(rig, retuned, suite), suite)
    smoothing, smoothed, tried = search_smoothing(
        rig,
        retuned,
        classical,
        suite,
        rig_base["reference_smoothing_steps"],
        rig_base["air_smoothing_steps"],
        reference_limit(classical, "air_mg", rig_base["max_air_ratio"]),
    )
    classical += smoothed
    chosen = choose_base(classical, base, smoothing, rig_base["max_chatter_ratio"])
    return classical, chosen, tried


def _check_base(base: str) -> None:
    if base not in BASE_CHOICES:
        raise ValueError(f"base = {base!r} is not allowed: use one of {list(BASE_CHOICES)}")


def reference_limit(figures: list[dict], key: str, max_ratio: float | None) -> float:
    """The figure ``key`` a controller for the rig may have: ``max_ratio`` x that of
    ``CHATTER_REFERENCE`` in ``figures`` (None: no limit)."""
    if max_ratio is None:
        return math.inf
    return float(max_ratio) * {f["controller"]: f[key] for f in figures}[CHATTER_REFERENCE]


def chatter_limit(figures: list[dict], max_ratio: float | None) -> float:
    """The chatter (A) a controller for the rig may have: ``max_ratio`` x that of
    ``CHATTER_REFERENCE`` in ``figures`` (``rig_base.max_chatter_ratio``; None: no
    limit)."""
    return reference_limit(figures, "chatter_rms_a", max_ratio)


def choose_base(
    classical: list[dict],
    base: str = "auto",
    smoothing: dict[str, int] | None = None,
    max_chatter_ratio: float | None = None,
) -> dict:
    """The residual's base from the classical controllers' figures on the fitted rig
    (``suite_summary`` of ``rig_controllers``; the rows of ``smoothing``, from
    ``search_smoothing``, too): the candidate with the lowest mean RMS error, among all
    (``"auto"``) or those of the kind ``base``, whose chatter is within
    ``chatter_limit`` (all of them if none is). Returns ``{"controller": name, "kind",
    "model", "smoothing_steps", "reason", "rms_error_pct": {name: %}}``."""
    _check_base(base)
    named = _named_candidates(smoothing)
    by_name = {f["controller"]: f for f in classical}
    rms = {name: by_name[name]["rms_error_pct"] for name in named}
    kind_ok = [n for n in rms if base == "auto" or BASE_CANDIDATES[named[n][0]][0] == base]
    limit = chatter_limit(classical, max_chatter_ratio)
    quiet = [n for n in kind_ok if by_name[n]["chatter_rms_a"] <= limit]
    name = min(quiet or kind_ok, key=lambda n: rms[n])
    listed = ", ".join(f"{n} {v:.2f} %" for n, v in rms.items())
    reason = (
        f"auto: the lowest mean RMS error on the fitted rig ({listed})"
        if base == "auto"
        else f"given (base={base}, the better of its kind; on the fitted rig: {listed})"
    )
    loud = [n for n in kind_ok if n not in quiet]
    if loud:
        reason += (
            f"; chatter over {limit:.4f} A ({max_chatter_ratio} x {CHATTER_REFERENCE}'s), "
            + ("so not chosen: " if quiet else "as every candidate's, so allowed: ")
            + ", ".join(loud)
        )
    kind, model = BASE_CANDIDATES[named[name][0]]
    return {
        "controller": name,
        "kind": kind,
        "model": model,
        "candidate": named[name][0],
        "smoothing_steps": named[name][1],
        "reason": reason,
        "rms_error_pct": rms,
    }


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
    _check_base(base)
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
    classical, chosen, tried = _classical_and_base(rig, retuned, suite, rig_base, base)
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
