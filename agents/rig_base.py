"""The residual's base for ``train --rig`` (``agents.rig_training``), and the limits a
controller for the rig is held to on the fitted rig (``configs/agents/tuning.yaml:
rig_base``).

The candidates (``BASE_CANDIDATES``): PID nominal or retuned, the sliding mode on the
nominal or the fitted model, at the benchmark's gains or retuned on the fitted rig
(``retuned_gains``: ``agents.tune_pid.grid_search``), each also tracking its reference
smoothed (``search_smoothing``). A long tube's waves and heat transfer can leave the
sliding mode well behind PID, a fit that trades one parameter for another can leave the
sliding mode on the fitted model behind the nominal one, and spool friction favours other
sliding-mode gains than the benchmark's. Each candidate takes the smoothing with its
lowest mean RMS error on the fitted rig's suite; one over ``rig_base.max_air_ratio`` x the
air of the sliding mode at nominal tuning (``CHATTER_REFERENCE``) smooths its reference
further if that brings it within. With ``base="auto"`` the candidate with the lowest mean
RMS error there is chosen (``choose_base``), among those whose chatter is within
``rig_base.max_chatter_ratio`` x the same sliding mode's (all if none is).
"""

from __future__ import annotations

import dataclasses
import math

from .base import ControllerContext, ControllerSpec
from .config import load_agent_config
from .registry import classical_gains, classical_spec
from .residual import BASE_CONTROLLERS
from .rig import FittedRig
from .rig_summary import suite_summary
from .suite import Suite
from .tune_pid import grid_search

__all__ = [
    "BASE_CANDIDATES",
    "BASE_CHOICES",
    "CHATTER_REFERENCE",
    "RETUNED",
    "candidate_base",
    "chatter_limit",
    "check_base",
    "choose_base",
    "classical_and_base",
    "reference_limit",
    "retuned_gains",
    "rig_controllers",
    "search_smoothing",
    "smoothed_name",
]

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
    """Row name -> (``BASE_CANDIDATES`` name, reference smoothing W): each candidate once,
    at its W in ``smoothing`` (``search_smoothing``'s choice; else 0). The W search
    chooses within a candidate, air included: its other rows are not candidates."""
    smoothing = smoothing or {}
    steps = {name: int(smoothing.get(name, 0)) for name in BASE_CANDIDATES}
    return {(smoothed_name(n, w) if w else n): (n, w) for n, w in steps.items()}


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
    spec = classical_spec(kind, gains, preview, name)
    if base_params is None:
        return spec

    def build(ctx: ControllerContext):
        return spec.build(dataclasses.replace(ctx, base_params=dict(base_params)))

    return dataclasses.replace(spec, build=build)


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
) -> tuple[dict[str, int], list[dict], dict[str, dict[int, dict]]]:
    """The reference smoothing W of each base candidate searched on the fitted rig's suite:
    every W of ``grid`` beside the candidate's own figure (W = 0, ``classical``). A
    candidate whose best W uses more air than ``air_limit_mg`` tries the W of ``air_grid``
    too and takes the best W within the limit, if one is (a smoother reference asks for
    less air). Returns {candidate: its W, where not 0}, their figures (rows named
    ``smoothed_name``) and {candidate: {W: {"rms_error_pct", "air_mg"}}} of every W tried."""
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
    tried = {
        n: {w: {k: by_w[n][w][k] for k in ("rms_error_pct", "air_mg")} for w in sorted(by_w[n])}
        for n in best
    }
    return {n: w for n, w in best.items() if w}, rows, tried


def classical_and_base(rig: FittedRig, retuned: dict, suite: Suite, rig_base: dict, base: str):
    """Stage 3: the base candidates' figures on the fitted rig, each also with its best
    reference smoothing (``search_smoothing``: ``rig_base.reference_smoothing_steps``, and
    ``air_smoothing_steps`` within ``max_air_ratio``), and the base chosen among them
    (``choose_base`` with ``rig_base.max_chatter_ratio``). Returns (figures, the choice,
    every smoothing tried)."""
    classical = suite_summary(rig, rig_controllers(rig, retuned, suite), suite)
    reference_air = reference_limit(classical, "air_mg", 1.0)
    ratio = rig_base["max_air_ratio"]
    smoothing, smoothed, tried = search_smoothing(
        rig,
        retuned,
        classical,
        suite,
        rig_base["reference_smoothing_steps"],
        rig_base["air_smoothing_steps"],
        ratio * reference_air,
    )
    classical += smoothed
    chosen = choose_base(classical, base, smoothing, rig_base["max_chatter_ratio"])
    figures = tried[chosen["candidate"]]
    lowest = _lowest_error(figures)
    if lowest != chosen["smoothing_steps"]:  # its W was taken for air: say so
        chosen["reason"] += (
            f"; its reference smoothed +-{chosen['smoothing_steps']}, not +-{lowest} "
            f"({figures[lowest]['rms_error_pct']:.2f} %), whose air "
            f"({figures[lowest]['air_mg'] / reference_air:.2f} x {CHATTER_REFERENCE}'s) is "
            f"over the limit ({ratio} x)"
        )
    return classical, chosen, tried


def check_base(base: str) -> None:
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
    (``suite_summary`` of ``rig_controllers`` and the rows of ``search_smoothing``), each
    candidate at its W of ``smoothing``: the one with the lowest mean RMS error, among all
    (``"auto"``) or those of the kind ``base``, whose chatter is within
    ``chatter_limit`` (all of them if none is). Returns ``{"controller": name, "kind",
    "model", "smoothing_steps", "reason", "rms_error_pct": {name: %}}``."""
    check_base(base)
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
