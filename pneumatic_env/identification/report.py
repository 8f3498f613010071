"""Report of a diagnosis: ``report.md``, PNG plots, ``diagnosis.json``, fitted parameter sets.

Files written into the report directory (nothing else is touched; the input recordings
are only read):

- ``diagnosis.json``: keys ``baseline_nrmse`` (per channel, held-out), ``candidates``
  (ranked, with fitted parameters, held-out NRMSE and score), ``selected`` (effect names,
  ``[]`` for none), ``after_nrmse`` (per channel, held-out), and more (see
  :meth:`Diagnosis.to_json`);
- ``fitted_base.yaml`` and ``fitted_final.yaml``: kernel parameters of the calibrated
  base model and of the model with the selected effects, loadable with
  ``load_parameters(params=...)`` and ``gym.make(id, params=...)``;
- ``fit_<recording>.png`` (measured vs model before/after) and ``residuals_<recording>.png``;
- ``report.md``: the summary.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

from pneumatic_env.text_format import jsonable, number_text

from .diagnose import Diagnosis
from .stage_costs import stage_cost_lines

__all__ = ["REPORT_FILES", "diagnosis_json", "write_report"]

REPORT_FILES = ("report.md", "diagnosis.json", "fitted_base.yaml", "fitted_final.yaml")
_UNITS = {"p1": "Pa", "p2": "Pa", "f": "N", "x": "m", "v": "m/s", "x_s": "m"}


def _fmt(x, digits: int = 4) -> str:
    return number_text(x, digits)  # None: "-"


def _check_outputs(out_dir: Path, inputs: Sequence[Path], names: Sequence[str]) -> None:
    inputs_resolved = {Path(p).resolve() for p in inputs}
    for name in names:
        target = (out_dir / name).resolve()
        if target in inputs_resolved:
            raise ValueError(
                f"report file {target} would overwrite an input recording; "
                "choose another report directory"
            )


def _plots(diag: Diagnosis, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    split_t = None
    for k, ds in enumerate(diag.datasets):
        t = ds.recording.t
        split_t = None
        if diag.holdout.get("mode") == "time" or ds.name in diag.holdout.get("time_split", ()):
            split_t = t[int(round(diag.holdout["train_fraction"] * ds.n_samples))]
        before, after = diag.predictions["before"][k], diag.predictions["after"][k]
        n = len(ds.channels)
        fig, axes = plt.subplots(n + 1, 1, figsize=(10, 2.2 * (n + 1)), sharex=True)
        axes[0].plot(t, ds.recording.i_c, color="k", lw=0.8)
        axes[0].set_ylabel("i_c [A]")
        for ax, c in zip(axes[1:], ds.channels):
            ax.plot(t, ds.measured(c), color="0.6", lw=0.8, label="recorded")
            ax.plot(t, before[c], color="C0", lw=0.9, label="model before (calibrated base)")
            ax.plot(
                t,
                after[c],
                color="C3",
                lw=0.9,
                ls="--",
                label="model after (" + (", ".join(diag.selected) or "no effect") + ")",
            )
            ax.set_ylabel(f"{c} [{_UNITS.get(c, '')}]")
        for ax in axes:
            if split_t is not None:
                ax.axvline(split_t, color="k", ls=":", lw=0.8)
        axes[1].legend(loc="upper right", fontsize=7)
        axes[-1].set_xlabel("t [s]" + ("  (dotted: start of the held-out part)" if split_t else ""))
        fig.suptitle(f"{ds.name}: recorded vs model")
        fig.tight_layout()
        name = f"fit_{ds.name}.png"
        fig.savefig(out_dir / name, dpi=90)
        plt.close(fig)
        written.append(name)

        fig, axes = plt.subplots(n, 1, figsize=(10, 2.0 * n), sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], ds.channels):
            ax.plot(
                t, (before[c] - ds.measured(c)) / ds.scales[c], color="C0", lw=0.7, label="before"
            )
            ax.plot(
                t, (after[c] - ds.measured(c)) / ds.scales[c], color="C3", lw=0.7, label="after"
            )
            ax.set_ylabel(f"{c} residual / scale")
            if split_t is not None:
                ax.axvline(split_t, color="k", ls=":", lw=0.8)
        axes[0, 0].legend(loc="upper right", fontsize=7)
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{ds.name}: model minus recorded, normalised by the channel scale")
        fig.tight_layout()
        name = f"residuals_{ds.name}.png"
        fig.savefig(out_dir / name, dpi=90)
        plt.close(fig)
        written.append(name)
    return written


def _markdown(diag: Diagnosis, data: dict, plots: Sequence[str]) -> str:
    """``report.md``: the result, how sure, the candidates, the base fit, the residuals."""
    lines = [
        "# Identification report",
        "",
        "Recordings: " + ", ".join(f"`{n}`" for n in data["recordings"]) + ".",
        f"Held-out data: {json.dumps(data['holdout'])}.",
        "Sensor noise (white, from the recordings alone; `train --rig` and `bench --rig` "
        "give the fitted rig this noise): "
        + (", ".join(f"{c} {v:.3g}" for c, v in data["sensor_noise"].items()) or "-")
        + " (SI units).",
        "",
    ]
    if data["status"] != "complete":
        lines += [
            f"**Status: {data['status']}.** The run is not finished: this report holds what "
            f"it found so far. Still being checked: {data['still_checking']}.",
            "",
        ]
    if data["issues"]:
        lines += ["## Data issues", ""] + [f"- {i}" for i in data["issues"]] + [""]
    lines += _result_lines(data) + _drift_lines(data) + _nrmse_lines(data)
    lines += _confidence_lines(data) + _stand_in_lines(data)
    lines += _per_recording_lines(data) + _screening_lines(data)
    lines += _candidate_lines(data) + _calibration_lines(data) + _residual_lines(data)
    lines += stage_cost_lines(
        data["stage_costs"], data["kernel_lane_substeps_per_s"], data["simulation_threads"]
    )
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    lines += [
        "",
        "Fitted parameter sets: `fitted_base.yaml` (calibrated base), `fitted_final.yaml` "
        "(with the selected plant effects; sensor-side values are in `diagnosis.json`).",
        "",
    ]
    return "\n".join(lines)


def _result_lines(data: dict) -> list[str]:
    """The selected effects (or none), a suggested experiment, what stays unexplained."""
    lines = ["## Result", ""]
    if data["quick"]:
        lines.append(
            "Quick mode: the candidates were screened (one Gauss-Newton step each), "
            "none refitted or selected; see the screening below for those worth a "
            "full run."
        )
    elif data["selected"]:
        lines.append(
            "Selected effect(s): "
            + ", ".join(f"**{s}**" for s in data["selected"])
            + f". Runner-up in round 1: {data['runner_up'] or '-'}."
        )
        for c in data["confidence"]:
            if c.get("flagged"):
                lines.append(f"Flagged: **{c['effect']}**: " + "; ".join(c["flagged"]) + ".")
    else:
        lines.append(
            "Selected effects: **none** (no candidate passed the acceptance rules). "
            f"Best-scoring candidate: {data['runner_up'] or '-'}."
        )
    if data["suggested_experiment"]:
        lines.append(f"Suggested experiment: {data['suggested_experiment']}")
    unexplained = [c for c, r in data["after_residuals"].items() if not r["whiteness"]["white"]]
    if unexplained and not data["quick"]:
        lines.append(
            "The residual after the selected model is not white on "
            + ", ".join(unexplained)
            + " (Ljung-Box): part of the error is systematic "
            "and no accepted candidate explains it."
        )
    return lines


def _drift_lines(data: dict) -> list[str]:
    """The base parameters fitted outside their plausible range, and what they may stand
    for (:mod:`.drift`)."""
    if not data["base_drift"]:
        return []
    lines = [
        "",
        "## Base parameters outside their plausible range",
        "",
        "A base parameter fitted far outside what a real rig can have is itself evidence "
        "of a missing effect: the model bends it to take up the effect's part of the data. "
        "One held at its floor sits on a plausible edge the fit does not simulate beyond.",
        "",
        "| parameter | nominal | fitted | plausible range | factor outside | with the "
        "selected effects | may stand for | why |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for d in data["base_drift"]:
        lo, hi = d["plausible_range"]
        factor = "-" if d["factor_outside"] is None else f"{d['factor_outside']:.2f} x"
        if d.get("held_at_bound"):
            factor = "held at its floor,"
        lines.append(
            f"| {d['parameter']} | {_fmt(d['nominal'])} {d['unit']} | {_fmt(d['fitted'])} | "
            f"[{_fmt(lo, 3)}, {_fmt(hi, 3)}] | {factor} {d['direction']} | "
            f"{_fmt(d['final'])} | {', '.join(d['may_stand_for']) or '-'} | "
            f"{d['explanation']} |"
        )
    tried = {c["name"]: c for c in data["candidates"] if c["round"] == 1}
    pointed = [f"{e} ({_tried(tried.get(e))})" for e in data["suggested_by_drift"]]
    lines += ["", "Effects these drifts point at: " + (", ".join(pointed) or "-") + "."]
    return lines


def _tried(c: dict | None) -> str:
    """How round 1 tried a candidate (its score in :func:`_candidate_lines`'s table)."""
    if c is None:
        return "not tried"
    if not c["refitted"]:
        return "screened, not refitted"
    return "refitted, accepted" if c["accepted"] else "refitted, not accepted"


def _nrmse_lines(data: dict) -> list[str]:
    """The mean held-out NRMSE before and after, per channel."""
    lines = [
        "",
        "Mean held-out NRMSE: before "
        + _fmt(data["baseline_nrmse_mean"])
        + ", after "
        + _fmt(data["after_nrmse_mean"])
        + " (NRMSE = RMSE / channel scale: supply minus "
        "ambient pressure for p1, p2; that times the cap area for f; half the stroke for x).",
        "",
        "| channel | before | after |",
        "|---|---|---|",
    ]
    for c in data["baseline_nrmse"]:
        lines.append(
            f"| {c} | {_fmt(data['baseline_nrmse'][c])} | {_fmt(data['after_nrmse'].get(c))} |"
        )
    return lines


def _candidate_lines(data: dict) -> list[str]:
    """The acceptance rules and every candidate's score, parameters and verdict."""
    th = data["thresholds"]
    lines = [
        "",
        "## Candidates",
        "",
        f"Accepted when the held-out NRMSE falls by at least "
        f"{100 * th['min_relative_improvement']:.0f} % (pooled over the held-out samples; "
        f"with {th.get('median_from_recordings', 3)} or more held-out recordings, the median "
        "of the improvements on the recordings the effect acts on), the "
        "autocorrelation-corrected BIC "
        f"falls by at least {th['min_ic_drop']:g}, and the effect's parameters are identified "
        "(confidence interval narrower than the plausible range, excluding the neutral "
        "value) and plausible; a candidate with a value outside its plausible range, or "
        "whose only shortfall is an interval wider than the plausible range (the effect "
        "shown, its strength not pinned down), is accepted, flagged, when its held-out "
        "improvement is at least "
        f"{100 * th.get('min_improvement_when_implausible', math.inf):.0f} %.",
        "",
        "| round | candidate | score (held-out improvement) | delta BIC | held-out NRMSE | "
        "parameters (95 % CI) | accepted | why not (or notes) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in data["candidates"]:
        params = "; ".join(
            f"{n} = {_fmt(p['value'])} [{_fmt(p['ci'][0], 3)}, {_fmt(p['ci'][1], 3)}] {p['unit']}"
            for n, p in c["parameters"].items()
        )
        score = "-" if c["score"] is None else f"{100 * c['score']:.1f} %"
        if not c["refitted"]:
            score += " (screening)"
        lines.append(
            f"| {c['round']} | {c['name']} | {score} | "
            f"{_fmt(c['delta_ic'], 3)} | {_fmt(c['heldout_nrmse_mean'])} | {params} | "
            f"{'yes' if c['accepted'] else 'no'} | "
            f"{'; '.join([*c['reasons'], *c.get('flagged', []), *c.get('notes', [])])} |"
        )
    if data["skipped"]:
        lines += ["", "Not tried: " + "; ".join(f"{k} ({v})" for k, v in data["skipped"].items())]
    return lines


def _calibration_lines(data: dict) -> list[str]:
    """The calibrated base parameters, their confidence and correlations."""
    cal = data["calibration"]
    lines = [
        "",
        "## Calibrated base parameters",
        "",
        f"Fit on the training data: {cal['n_residuals']} residuals, lag-1 autocorrelation "
        f"{cal['lag1_autocorrelation']:.3f} (effective samples {cal['effective_samples']:.0f}), "
        f"Jacobian condition number {_fmt(cal['condition_number'])}.",
        "",
        "| parameter | value | 95 % CI | unit | identified | notes |",
        "|---|---|---|---|---|---|",
    ]
    for name, p in cal["parameters"].items():
        lines.append(
            f"| {name} | {_fmt(p['value'], 6)} | [{_fmt(p['ci'][0], 5)}, "
            f"{_fmt(p['ci'][1], 5)}] | {p['unit']} | {'yes' if p['identified'] else 'no'} | "
            f"{'; '.join(p['flags'])} |"
        )
    if cal["correlations"]:
        lines += [
            "",
            "Strongly correlated estimates: "
            + "; ".join(f"{a} / {b} ({r:+.3f})" for a, b, r in cal["correlations"])
            + ".",
        ]
    return lines


def _residual_lines(data: dict) -> list[str]:
    """The held-out residual analysis per channel, before and after."""
    lines = [
        "",
        "## Residual analysis (held-out data)",
        "",
        "| channel | model | NRMSE | bias | flow | after flow | rest | reversal | "
        "Ljung-Box p | white | max input xcorr (bound) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, res in (("before", data["baseline_residuals"]), ("after", data["after_residuals"])):
        for c, r in res.items():
            ph = r["phases"]
            xc = r["input_correlation"]
            lines.append(
                f"| {c} | {label} | {_fmt(r['nrmse'])} | {_fmt(r['bias'], 3)} | "
                + " | ".join(
                    _fmt(ph[k]["nrmse"], 3) for k in ("flow", "after_flow", "rest", "reversal")
                )
                + f" | {_fmt(r['whiteness'].get('p_value'), 3)}"
                + f" | {'yes' if r['whiteness']['white'] else 'no'}"
                f" | {_fmt(xc['max_abs'], 3)} ({_fmt(xc['bound'], 2)}) |"
            )
    return lines


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:+.1f} %"


def _holds(c: dict) -> str:
    """'yes', or 'no' and whether it holds on the held-out recordings it can act on."""
    if c["holds_on_every_heldout_recording"]:
        return "yes"
    acts_on = c.get("acts_on", [])
    if not acts_on or len(acts_on) == len(c["heldout_improvement_per_recording"]):
        return "no"
    where = "yes" if c.get("holds_where_it_acts") else "no"
    return f"no; {where} on the {len(acts_on)} it acts on ({', '.join(acts_on)})"


def _explains(c: dict) -> str:
    """Each held-out channel's NRMSE change with the effect, largest drop first
    (e.g. 'p1 -62.0 %')."""
    drops = sorted((c.get("explains_channels") or {}).items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} {_pct(-v)}" for k, v in drops) or "-"


def _confidence_lines(data: dict) -> list[str]:
    """How sure the tool is of each selected effect."""
    if not data["confidence"]:
        return []
    lines = [
        "",
        "## How sure",
        "",
        "| effect | held-out improvement (over the model before it) | runner-up | margin "
        "over the runner-up | margin over the effects before it per experiment type | "
        "delta BIC | supported by (held out) | explains (held-out channels) | holds on every "
        "held-out recording |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in data["confidence"]:
        lines.append(
            f"| {c['effect']} | {_pct(c['margin_over_none'])} | "
            f"{c['runner_up'] or '-'} ({_pct(c['runner_up_improvement'])}"
            f"{'' if c['runner_up_refitted'] in (True, None) else ', screened'}) | "
            f"{_pct(c['margin_over_runner_up'])} | {_pct(c.get('margin_over_freer_form'))} | "
            f"{_fmt(c['delta_ic'], 3)} | "
            f"{', '.join(c['supported_by']) or '-'} | "
            f"{_explains(c)} | "
            f"{_holds(c)} |"
        )
    return lines


def _stand_in_lines(data: dict) -> list[str]:
    """The backward check after the rounds (.stand_ins): each earlier effect's worth with
    the later ones in the model, and which were dropped."""
    tried = data.get("stand_in_check") or []
    if not tried:
        return []
    threshold = f"{100 * data['thresholds']['min_relative_improvement']:.0f} %"
    lines = [
        "",
        "## Stand-in check",
        "",
        "Each effect selected before the last round, refitted out of the final model: "
        f"dropped when the model with it is less than {threshold} better on held-out data.",
        "",
        "| effect | held-out NRMSE without it | improvement with it | judged by | dropped |",
        "|---|---|---|---|---|",
    ]
    for t in tried:
        lines.append(
            f"| {t['name']} | {_fmt(t['heldout_nrmse_mean_without'])} | "
            f"{_pct(t['improvement_with'])} | {t['judged_by']} | "
            f"{'**yes**' if t['dropped'] else 'no'} |"
        )
    return lines


def _per_recording_lines(data: dict) -> list[str]:
    """Held-out NRMSE before and after, per recording and channel."""
    rows = data["per_recording"]
    if not rows:
        return []
    lines = [
        "",
        "## Held-out error per recording",
        "",
        "| recording | channel | before | after | change |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        for c, before in r["before"].items():
            after = r["after"].get(c)
            change = None if before in (None, 0) or after is None else (after - before) / before
            lines.append(f"| {name} | {c} | {_fmt(before)} | {_fmt(after)} | {_pct(change)} |")
    return lines


def _screening_lines(data: dict) -> list[str]:
    """The screening's ranking of each round (one Gauss-Newton step per candidate)."""
    lines = []
    for rnd in data["screening"]:
        ranking = rnd["ranking"]
        lines += [
            "",
            f"## Screening, round {rnd['round']}",
            "",
            "One Gauss-Newton step per candidate from the current model, ranked by "
            "the linearised BIC change on the training rows (a ranking; refits "
            "decide)"
            + (
                "; quick mode simulates the training rows only, so nothing is predicted held out:"
                if data["quick"]
                else ":"
            ),
            "",
            "| candidate | predicted BIC change (ranks) | predicted training | predicted "
            "held out | per held-out recording |",
            "|---|---|---|---|---|",
        ]
        for r in ranking:
            per = ", ".join(f"{k} {_pct(v)}" for k, v in r["predicted_per_recording"].items())
            lines.append(
                f"| {r['name']} | {_fmt(r['predicted_delta_ic'], 3)} | "
                f"{_pct(r['predicted_training_improvement'])} | "
                f"{_pct(r['predicted_heldout_improvement'])} | {per} |"
            )
    return lines


def _save_fit(diag: Diagnosis, fit, path: Path, notes: str) -> None:
    from pneumatic_env.params import save_parameters

    values = fit.file_values(diag.datasets)
    std = {k: v for k, v in fit.std.items() if k in values and math.isfinite(v)}
    save_parameters(path, values, notes=notes, uncertainties=std)


def diagnosis_json(diag: Diagnosis) -> dict:
    """The diagnosis as ``diagnosis.json`` holds it (plain JSON types, no NaN)."""
    return jsonable(diag.to_json(), finite=True)


def write_report(diag: Diagnosis, out_dir: str | os.PathLike, plots: bool = True) -> dict:
    """Write the report files into ``out_dir`` (created); returns the diagnosis.json data."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    inputs = []
    for ds in diag.datasets:
        if ds.recording.path is not None:
            csv = Path(ds.recording.path)
            inputs += [csv, csv.with_suffix(".json")]
    names = list(REPORT_FILES) + [
        f"{p}_{ds.name}.png" for ds in diag.datasets for p in ("fit", "residuals")
    ]
    _check_outputs(out_dir, inputs, names)
    data = diagnosis_json(diag)
    (out_dir / "diagnosis.json").write_text(
        json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8"
    )
    recs = ", ".join(data["recordings"])
    _save_fit(
        diag,
        diag.base,
        out_dir / "fitted_base.yaml",
        f"pneumatic_env identify: calibrated base model on {recs}",
    )
    _save_fit(
        diag,
        diag.final,
        out_dir / "fitted_final.yaml",
        f"pneumatic_env identify on {recs}; selected effects: "
        + (", ".join(diag.selected) or "none"),
    )
    written = _plots(diag, out_dir) if plots and diag.predictions else []
    (out_dir / "report.md").write_text(_markdown(diag, data, written), encoding="utf-8")
    return data
