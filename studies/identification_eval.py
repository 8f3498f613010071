"""Evaluate the diagnosis on the virtual rig: confusion matrix, detection vs strength, FDR.

``python -m pneumatic_env.studies.identification_eval [--jobs 2] [--seeds 1,2,3]
[--docs docs/identification.md]``

``--campaign standard`` (or ``clamped``, ``small``) evaluates campaigns instead: each rig
records the experiments of :data:`.rig_campaign.CAMPAIGNS` (clamped steps, multisine and
pulse trains, a spring, a free rod), all diagnosed at once with greedy selection; the
report is the confusion matrix of the first effect, the rigs with a false second effect
and the wall time per rig (block ``evaluate-campaign`` in ``--docs``). ``--ray-address``
runs the rigs as Ray tasks on a cluster (the ``distributed`` extra); local processes by
default.

``--rigs "tube_waves+heat_transfer+spool_friction" "leakage+coil_lag@1"`` (with
``--campaign``) evaluates multi-effect rigs (:mod:`.rig_multi_effect`; ``NAME=S`` sets a
strength, ``@L`` the tube length in m, default ``--tube-length``): each rig scores its
recall (the share of its effects selected), whether every effect was found, and whether a
false effect was selected; the time per rig as median and max.

``--quick`` (with ``--campaign``) runs each rig's first screening only (``identify
--quick``) and reports the screening's recall: whether each rig's effects are among the
candidates round 1 refits (its top ``screening.refit_top`` and ``screening.always_refit``;
a full run may add a drift pick), and on single-effect rigs whether the true one is first.

``--seeds`` repeats every cell with other seeds (base-parameter perturbation, excitation
draws and sensor noise): the confusion matrix and the detection table then count
recordings over the seeds (stability across noise seeds); the run time grows linearly
(about 4 min per seed with 2 processes on a 2-core machine).

For each true effect (every rig effect whose candidate the kernel has, plus ``none`` and
``supply_ripple``, which no candidate models; some effects in extra rig set-ups, see
:data:`EXTRA_SETUPS`) it writes a synthetic recording at strength 1 and diagnoses it with
every available candidate (one selection round: the first choice is what the confusion
matrix counts). For a few effects it repeats this at other strengths (detection rate vs
strength). The false-discovery rate is the share of diagnoses that selected something other
than the truth among those that selected anything. Results go to ``--out`` (JSON) and, with
``--docs``, replace the block between
``<!-- evaluate:begin -->`` and ``<!-- evaluate:end -->`` in that Markdown file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

BEGIN, END = "<!-- evaluate:begin -->", "<!-- evaluate:end -->"
CAMPAIGN_BEGIN, CAMPAIGN_END = "<!-- evaluate-campaign:begin -->", "<!-- evaluate-campaign:end -->"
OUT_OF_CATALOG = ("supply_ripple",)
#: Rig set-ups besides the default (Numatics, 0.5 m tube, rod clamped) for effects the
#: default cannot show: (label suffix, run_rig keyword arguments). Stribeck and LuGre
#: friction need a moving piston; "none" is also recorded on a
#: spring rod (moving-piston fits, with their static-friction restarts, must not invent
#: an effect either); the tube volume is also tried with a 2 m tube (16 cm^3 of air), and
#: the segmented line of ``tube_waves`` with a 2 m tube (where the candidate's friction,
#: lumped at the line's ends, differs most from the line's own).
EXTRA_SETUPS = {
    "none": [("", {}), ("spring rod", {"piston": "spring"})],
    "stribeck": [("spring rod", {"piston": "spring"})],
    "lugre": [("spring rod", {"piston": "spring"})],
    "tube_volume": [("", {}), ("2 m tube", {"tube_length_m": 2.0})],
    "tube_waves": [("", {}), ("2 m tube", {"tube_length_m": 2.0})],
}


def evaluate_one(job: dict) -> dict:
    """Make one rig recording and diagnose it; returns what was found."""
    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.diagnose import diagnose

    from .virtual_rig import make_recording

    t0 = time.time()
    suffix = job["label"][len(job["effect"]) :].strip(" ()").replace(" ", "_")
    name = f"{job['effect']}{'_' + suffix if suffix else ''}_s{job['strength']:g}_seed{job['seed']}"
    path = make_recording(
        job["workdir"],
        name=name,
        effect=job["effect"],
        strength=job["strength"],
        seed=job["seed"],
        duration_s=job["duration_s"],
        overwrite=True,
        **job["rig"],
    )
    diag = diagnose([read_checked(path)], candidates=job["candidates"], max_effects=1, jobs=1)
    data = diag.to_json()
    return {
        **{k: job[k] for k in ("effect", "label", "strength", "seed")},
        "selected": data["selected"],
        "winner": data["winner"],
        "runner_up": data["runner_up"],
        "baseline_nrmse_mean": data["baseline_nrmse_mean"],
        "after_nrmse_mean": data["after_nrmse_mean"],
        "scores": {c["name"]: c["score"] for c in data["candidates"]},
        "seconds": time.time() - t0,
    }


def evaluate_campaign(job: dict) -> dict:
    """Record one rig's campaign (:mod:`.rig_campaign`) and diagnose it whole (greedy
    selection up to the config's number of effects); returns what was found."""
    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.diagnose import diagnose
    from pneumatic_env.identification.report import diagnosis_json

    from .rig_campaign import make_campaign

    t0 = time.time()
    name = f"{job['label'].replace(' ', '_').replace('(', '').replace(')', '')}_seed{job['seed']}"
    # a rig already diagnosed with the same job (an interrupted evaluation run again) is
    # read back, not redone
    saved = Path(job["workdir"]) / name / "result.json"
    key = {
        k: job.get(k)
        for k in (
            "effect",
            "label",
            "strength",
            "seed",
            "campaign",
            "candidates",
            "effects",
            "rig",
            "quick",
        )
    }
    if saved.is_file():
        previous = json.loads(saved.read_text(encoding="utf-8"))
        if previous.get("job") == key:
            return previous["result"]
    paths = make_campaign(
        Path(job["workdir"]) / name,
        effect=job["effect"],
        strength=job["strength"],
        seed=job["seed"],
        campaign=job["campaign"],
        overwrite=True,
        effects=job.get("effects"),
        **job["rig"],
    )
    t1 = time.time()
    diag = diagnose(
        [read_checked(p) for p in paths],
        candidates=job["candidates"],
        jobs=job["jobs"],
        quick=bool(job.get("quick")),
    )
    data = diag.to_json()
    # the whole diagnosis beside the rig's recordings: a miss can be read without a rerun
    (Path(job["workdir"]) / name / "diagnosis.json").write_text(
        json.dumps(diagnosis_json(diag), indent=1, allow_nan=False) + "\n", encoding="utf-8"
    )
    result = {
        **{k: job[k] for k in ("effect", "label", "strength", "seed")},
        "effects": job.get("effects"),
        "selected": data["selected"],
        "winner": data["winner"],
        "runner_up": data["runner_up"],
        "confidence": data["confidence"],
        "baseline_nrmse_mean": data["baseline_nrmse_mean"],
        "after_nrmse_mean": data["after_nrmse_mean"],
        "screening_first": [r["name"] for r in data["screening"][0]["ranking"][:3]]
        if data["screening"]
        else [],
        "refitted_round_1": refitted_in_round_1(data),
        "record_seconds": t1 - t0,
        "seconds": time.time() - t1,
        "timings_s": data["timings_s"],
    }
    saved.write_text(json.dumps({"job": key, "result": result}, indent=1) + "\n", encoding="utf-8")
    return result


def refitted_in_round_1(data: dict) -> list[str]:
    """The candidates round 1 refits (a full run's record); for ``--quick``, which stops
    after the screening, those a full run would refit from the same screening: its top
    ``screening.refit_top`` and ``screening.always_refit`` (a full run may add a drift
    pick, so this is a lower bound)."""
    if not data["quick"]:
        return [c["name"] for c in data["candidates"] if c["round"] == 1 and c["refitted"]]
    from pneumatic_env.identification.config import load_config

    cfg = load_config()
    names = [r["name"] for r in data["screening"][0]["ranking"]] if data["screening"] else []
    top = int(cfg.number("screening", "refit_top", positive=True))
    always = cfg.names("screening", "always_refit")
    return names[:top] + [n for n in names[top:] if n in always]


def summarise_screening(results: list[dict]) -> dict:
    """The screening's recall over rigs with effects in the catalog: rigs whose every true
    effect is among round 1's refits, rigs with at least one there, the misses, and the
    single-effect rigs whose effect the screening ranks first; the time per rig."""
    rigs, all_refitted, any_refitted, first, single = 0, 0, 0, 0, 0
    missed: list[str] = []
    for r in results:
        effects = list(r["effects"] or [r["effect"]])
        truth = [e for e in effects if e not in (*OUT_OF_CATALOG, "none")]
        if not truth:
            continue
        rigs += 1
        absent = [e for e in truth if e not in r["refitted_round_1"]]
        all_refitted += not absent
        any_refitted += len(absent) < len(truth)
        missed += [f"{r['label']} seed {r['seed']}: {e}" for e in absent]
        if len(effects) == 1:
            single += 1
            first += r["screening_first"][:1] == truth
    secs = sorted(r["seconds"] for r in results)
    return {
        "n_rigs": rigs,
        "all_refitted": all_refitted,
        "any_refitted": any_refitted,
        "n_single": single,
        "first": first,
        "missed": missed,
        "seconds_median": secs[len(secs) // 2] if secs else None,
        "seconds_max": secs[-1] if secs else None,
    }


def screening_markdown(summary: dict, results: list[dict], args) -> str:
    """The ``--quick`` block: the screening's recall and first places."""
    n = summary["n_rigs"]
    lines = [
        CAMPAIGN_BEGIN,
        "",
        f"Generated by `python -m pneumatic_env.studies.identification_eval --campaign "
        f"{args.campaign} --quick --seeds {','.join(map(str, args.seeds))}"
        + (f" --effects {','.join(args.effects)}" if args.effects else "")
        + (" --rigs " + " ".join(f'"{r}"' for r in args.rigs) if args.rigs else "")
        + f"` (the first screening only; {len(results)} rigs; synthetic, virtual rig).",
        "",
        f"- Every true effect among round 1's refits: {summary['all_refitted']} of {n} rigs"
        + (f" (missed: {'; '.join(summary['missed'])})" if summary["missed"] else "")
        + f"; at least one of them (a multi-effect rig's later effects are refitted in later "
        f"rounds, after the first is adopted): {summary['any_refitted']} of {n}.",
        f"- Single-effect rigs with the true effect ranked first: {summary['first']} of "
        f"{summary['n_single']}.",
        f"- `--quick` wall time per rig: median {summary['seconds_median']:.0f} s, max "
        f"{summary['seconds_max']:.0f} s.",
        "",
        "| rig | seed | screening's top 3 | round 1 refits | s |",
        "|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (r["label"], r["seed"])):
        lines.append(
            f"| {r['label']} | {r['seed']} | {', '.join(r['screening_first'])} | "
            f"{', '.join(r['refitted_round_1'])} | {r['seconds']:.0f} |"
        )
    lines += ["", CAMPAIGN_END]
    return "\n".join(lines)


def summarise_campaigns(results: list[dict]) -> dict:
    """Confusion (truth -> first selection), right first effect, false second effects."""
    confusion: dict[str, dict[str, int]] = {}
    right, false_second = 0, 0
    for r in results:
        found = r["winner"] or "none"
        confusion.setdefault(r["label"], {}).setdefault(found, 0)
        confusion[r["label"]][found] += 1
        truth = "none" if r["effect"] in OUT_OF_CATALOG else r["effect"]
        right += found == truth
        false_second += any(e != truth for e in r["selected"][1:])
    n = len(results)
    secs = sorted(r["seconds"] for r in results)
    return {
        "confusion": confusion,
        "n_rigs": n,
        "right_first": right,
        "right_first_rate": right / n if n else 0.0,
        "false_second": false_second,
        "false_second_rate": false_second / n if n else 0.0,
        "seconds_median": secs[n // 2] if n else None,
        "seconds_max": secs[-1] if n else None,
    }


def multi_effect_score(result: dict) -> dict:
    """A multi-effect rig's score: its effects the diagnosis can name (those outside the
    catalog left out), the share of them selected (recall), all found, a false one."""
    truth = [e for e in result["effects"] if e not in OUT_OF_CATALOG]
    selected = set(result["selected"])
    found = [e for e in truth if e in selected]
    return {
        "truth": truth,
        "recall": len(found) / len(truth) if truth else 1.0,
        "all_found": len(found) == len(truth),
        "false_effects": sorted(selected - set(truth)),
    }


def summarise_multi_effect(results: list[dict]) -> dict:
    """Over multi-effect rigs: mean recall, rigs with every effect found, rigs with no
    false effect, the time per rig (median, max), and each rig's score."""
    scores = [multi_effect_score(r) for r in results]
    n = len(results)
    secs = sorted(r["seconds"] for r in results)
    return {
        "n_rigs": n,
        "recall_mean": sum(s["recall"] for s in scores) / n if n else 0.0,
        "all_found": sum(s["all_found"] for s in scores),
        "no_false_effect": sum(not s["false_effects"] for s in scores),
        "seconds_median": secs[n // 2] if n else None,
        "seconds_max": secs[-1] if n else None,
        "rigs": [{"label": r["label"], "seed": r["seed"], **s} for r, s in zip(results, scores)],
    }


def campaign_markdown(summary: dict, results: list[dict], args, elapsed_s: float) -> str:
    lines = [
        CAMPAIGN_BEGIN,
        "",
        f"Generated by `python -m pneumatic_env.studies.identification_eval --campaign "
        f"{args.campaign} --seeds {','.join(map(str, args.seeds))}"
        + (f" --effects {','.join(args.effects)}" if args.effects else "")
        + (f" --candidates {args.candidates}" if args.candidates else "")
        + f"` ({summary['n_rigs']} rigs, each a campaign `{args.campaign}`; "
        f"{sum(r['record_seconds'] + r['seconds'] for r in results) / 60:.1f} min of "
        f"recording and diagnosis, {args.jobs} processes per rig). All data are synthetic "
        "(virtual rig).",
        "",
        f"- Right first effect (`none` for clean rigs and for "
        f"{', '.join(OUT_OF_CATALOG)}): {summary['right_first']} of {summary['n_rigs']}.",
        f"- Rigs with a false second effect: {summary['false_second']} of {summary['n_rigs']}.",
        f"- Wall time per rig (diagnosis, {args.jobs} processes per rig run one after the "
        f"other): median {summary['seconds_median']:.0f} s, max "
        f"{summary['seconds_max']:.0f} s.",
        "",
        "| rig effect | seed | selected | runner-up | screening's top 3 | NRMSE before | "
        "after | margin over runner-up | holds on every held-out recording | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (r["label"], r["seed"])):
        conf = r["confidence"][0] if r["confidence"] else {}
        margin = conf.get("margin_over_runner_up")
        lines.append(
            f"| {r['label']} | {r['seed']} | {', '.join(r['selected']) or 'none'} | "
            f"{r['runner_up'] or '-'} | {', '.join(r['screening_first'])} | "
            f"{r['baseline_nrmse_mean']:.4f} | {r['after_nrmse_mean']:.4f} | "
            f"{'-' if margin is None else f'{100 * margin:.0f} %'} | "
            f"{'-' if not conf else ('yes' if conf['holds_on_every_heldout_recording'] else 'no')}"
            f" | {r['seconds']:.0f} |"
        )
    lines += ["", CAMPAIGN_END]
    return "\n".join(lines)


def _write_json(path: Path, summary: dict, results: list, candidates: list, elapsed: float):
    data = {"summary": summary, "results": results, "candidates": candidates, "elapsed_s": elapsed}
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def _run_all(function, jobs: list[dict], processes: int, ray_address: str | None):
    """Results of ``function`` over ``jobs`` as they finish: local processes, or Ray tasks
    on the cluster at ``ray_address`` (Ray is imported only then: the ``distributed``
    extra)."""
    if ray_address:
        import ray

        if not ray.is_initialized():  # a second call (rig_eval's second stage) reuses it
            ray.init(address=None if ray_address == "local" else ray_address)
        remote = ray.remote(function)
        pending = [remote.remote(job) for job in jobs]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
        return
    with ProcessPoolExecutor(max_workers=max(1, processes)) as pool:
        yield from pool.map(function, jobs)


def _truths(args, candidates: list[str]) -> list[str]:
    """The rig effects to evaluate: every one with a candidate, ``none`` and those outside
    the catalog, or the ``--effects`` among them."""
    from .virtual_rig import RIG_EFFECTS

    truths = ["none"] + [e for e in RIG_EFFECTS if e in candidates] + list(OUT_OF_CATALOG)
    if args.effects is not None:
        unknown = sorted(set(args.effects) - set(truths))
        if unknown:
            raise SystemExit(
                f"--effects names {', '.join(unknown)}, not allowed: must be among "
                f"{', '.join(truths)}"
            )
        truths = [e for e in truths if e in args.effects]
    return truths


def _jobs(args, candidates: list[str]) -> list[dict]:
    truths = _truths(args, candidates)
    jobs = []
    common = {"duration_s": args.duration, "candidates": candidates, "workdir": str(args.out)}
    for effect in truths:
        for suffix, rig in EXTRA_SETUPS.get(effect, [("", {})]):
            label = f"{effect} ({suffix})" if suffix else effect
            for seed in args.seeds:
                jobs.append(
                    {
                        "effect": effect,
                        "label": label,
                        "rig": rig,
                        "strength": 1.0,
                        "seed": seed,
                        **common,
                    }
                )
    for effect in [e for e in args.strength_effects if e in truths]:
        suffix, rig = EXTRA_SETUPS.get(effect, [("", {})])[-1]
        label = f"{effect} ({suffix})" if suffix else effect
        for s in args.strengths:
            if s != 1.0:
                for seed in args.seeds:
                    jobs.append(
                        {
                            "effect": effect,
                            "label": label,
                            "rig": rig,
                            "strength": s,
                            "seed": seed,
                            **common,
                        }
                    )
    return jobs


def summarise(results: list[dict], candidates: list[str]) -> dict:
    """Confusion counts (truth -> first selection), detection rates, false-discovery rate."""
    at_one = [r for r in results if r["strength"] == 1.0]
    confusion: dict[str, dict[str, int]] = {}
    for r in at_one:
        found = r["winner"] or "none"
        confusion.setdefault(r["label"], {}).setdefault(found, 0)
        confusion[r["label"]][found] += 1
    detection: dict[str, dict[str, list]] = {}
    for r in results:
        if r["effect"] in candidates:
            d = detection.setdefault(r["label"], {})
            d.setdefault(f"{r['strength']:g}", []).append(r["winner"] == r["effect"])
    detection_rate = {
        e: {s: sum(v) / len(v) for s, v in sorted(d.items(), key=lambda x: float(x[0]))}
        for e, d in detection.items()
    }
    detection_count = {e: {s: [sum(v), len(v)] for s, v in d.items()} for e, d in detection.items()}
    with_selection = [r for r in results if r["winner"]]
    false = [r for r in with_selection if r["winner"] != r["effect"]]
    # the right answer for an effect no candidate models is "none"
    correct_at_one = [
        r
        for r in at_one
        if (r["winner"] or "none") == ("none" if r["effect"] in OUT_OF_CATALOG else r["effect"])
    ]
    return {
        "confusion": confusion,
        "detection_rate": detection_rate,
        "detection_count": detection_count,
        "false_discovery_rate": len(false) / len(with_selection) if with_selection else 0.0,
        "n_with_selection": len(with_selection),
        "n_false": len(false),
        "accuracy_at_strength_1": len(correct_at_one) / len(at_one) if at_one else 0.0,
        "n_at_strength_1": len(at_one),
    }


def markdown(summary: dict, results: list[dict], args, elapsed_s: float) -> str:
    lines = [
        BEGIN,
        "",
        f"Generated by `python -m pneumatic_env.studies.identification_eval "
        f"--duration {args.duration:g} --seeds {','.join(map(str, args.seeds))} "
        f"--strengths {','.join(f'{s:g}' for s in args.strengths)} "
        f"--strength-effects {','.join(args.strength_effects)}"
        + (f" --effects {','.join(args.effects)}" if args.effects else "")
        + "` "
        f"({len(results)} synthetic recordings of {args.duration:g} s, "
        f"{elapsed_s / 60:.1f} min with {args.jobs} processes). All data are synthetic "
        "(virtual rig).",
        "",
        f"- Correct first choice at strength 1 (the rig's effect; `none` for `none` and "
        f"for {', '.join(OUT_OF_CATALOG)}, which no candidate models): "
        f"{summary['accuracy_at_strength_1'] * summary['n_at_strength_1']:.0f} of "
        f"{summary['n_at_strength_1']}.",
        f"- False-discovery rate (a selected effect that is not the truth, over all "
        f"diagnoses that selected one): {summary['n_false']} of "
        f"{summary['n_with_selection']} = {summary['false_discovery_rate']:.2f}.",
        "",
        "Confusion matrix (rows: effect in the rig at strength 1; columns: first effect "
        "selected; `none` = nothing accepted):",
        "",
    ]
    cols = sorted({c for row in summary["confusion"].values() for c in row} | {"none"})
    lines.append("| rig effect | " + " | ".join(cols) + " |")
    lines.append("|---" * (len(cols) + 1) + "|")
    for truth, row in summary["confusion"].items():
        lines.append(f"| {truth} | " + " | ".join(str(row.get(c, "")) for c in cols) + " |")
    strengths = sorted({k for d in summary["detection_rate"].values() for k in d}, key=float)
    lines += [
        "",
        "Detection (first choice = the rig's effect; detected / recordings, over the "
        "noise seeds) vs strength (1 = the realistic value of "
        "`configs/identification.yaml`):",
        "",
        "| effect | " + " | ".join(strengths) + " |",
        "|---" * (len(strengths) + 1) + "|",
    ]
    for effect, counts in summary["detection_count"].items():
        lines.append(
            f"| {effect} | "
            + " | ".join(f"{counts[s][0]}/{counts[s][1]}" if s in counts else "" for s in strengths)
            + " |"
        )
    lines += [
        "",
        "Per recording (held-out mean NRMSE before -> after; runner-up):",
        "",
        "| rig effect | strength | seed | selected | runner-up | NRMSE before | after |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (r["label"], r["strength"], r["seed"])):
        lines.append(
            f"| {r['label']} | {r['strength']:g} | {r['seed']} | "
            f"{', '.join(r['selected']) or 'none'} | {r['runner_up'] or '-'} | "
            f"{r['baseline_nrmse_mean']:.4f} | {r['after_nrmse_mean']:.4f} |"
        )
    lines += ["", END]
    return "\n".join(lines)


def _replace_block(path: Path, block: str, begin: str = BEGIN, end: str = END) -> None:
    text = path.read_text(encoding="utf-8")
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
        text = head + block + tail
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(text, encoding="utf-8")


def _floats(text: str) -> list[float]:
    return [float(t) for t in text.split(",") if t.strip()]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.identification_eval",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--out", type=Path, default=Path("runs/identification-eval"))
    p.add_argument("--duration", type=float, default=1.5, help="recording length in s")
    p.add_argument("--seeds", type=lambda s: [int(x) for x in s.split(",")], default=[1])
    p.add_argument("--strengths", type=_floats, default=[0.25, 0.5, 1.0, 2.0])
    p.add_argument(
        "--strength-effects",
        type=lambda s: s.split(","),
        default=["leakage", "pressure_sensor_lag", "coil_lag"],
    )
    p.add_argument("--candidates", default=None, help="comma-separated (default: all available)")
    p.add_argument(
        "--effects",
        type=lambda s: s.split(","),
        default=None,
        help="comma-separated rig effects to record, 'none' included (default: "
        "none, every effect among the candidates and the out-of-catalog ones)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=2,
        help="local processes (single recordings: one rig each; campaigns: the "
        "rigs run one after the other, each diagnosis refitting in this many)",
    )
    p.add_argument(
        "--campaign",
        default=None,
        metavar="NAME",
        help="evaluate campaigns of experiments per rig (studies/rig_campaign.py: "
        "standard, clamped, small, user13) instead of single recordings",
    )
    p.add_argument(
        "--rigs",
        nargs="+",
        default=None,
        metavar="E1+E2[=S][@L]",
        help="with --campaign: multi-effect rigs, e.g. 'tube_waves+heat_transfer+"
        "spool_friction@2' 'leakage+coil_lag' (strength S, tube length L in m)",
    )
    p.add_argument("--tube-length", type=float, default=0.5, metavar="M")
    p.add_argument(
        "--quick",
        action="store_true",
        help="with --campaign: the first screening only (identify --quick); reports "
        "whether each rig's effects are among round 1's refits",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="run the rigs as tasks on this Ray cluster (needs the 'distributed' "
        "extra); default: local processes",
    )
    p.add_argument(
        "--docs",
        type=Path,
        default=None,
        help="Markdown file whose evaluate block is replaced by the results",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    from pneumatic_env.identification.candidates import available_candidates

    p = _parser()
    args = p.parse_args(argv)
    names = args.candidates.split(",") if args.candidates else None
    candidates = [c.name for c in available_candidates(names)]
    args.out.mkdir(parents=True, exist_ok=True)
    if args.quick and not args.campaign:
        p.error("--quick is not allowed without --campaign (it screens a campaign's rigs)")
    if args.campaign:
        return _main_campaign(args, candidates)
    jobs = _jobs(args, candidates)
    print(
        f"evaluate: {len(jobs)} recordings, {len(candidates)} candidates, {args.jobs} processes",
        flush=True,
    )
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for r in pool.map(evaluate_one, jobs):
            results.append(r)
            print(
                f"  {r['label']:28s} s={r['strength']:<5g} seed={r['seed']}: "
                f"{', '.join(r['selected']) or 'none':24s} ({r['seconds']:.0f} s, "
                f"{time.time() - t0:.0f} s total)",
                flush=True,
            )
    elapsed = time.time() - t0
    summary = summarise(results, candidates)
    _write_json(args.out / "evaluation.json", summary, results, candidates, elapsed)
    block = markdown(summary, results, args, elapsed)
    print(block)
    if args.docs is not None:
        _replace_block(args.docs, block)
    return 0


def _rig_jobs(args, candidates: list[str], local: bool) -> list[dict]:
    """One campaign job per rig and seed: the single effects (``--effects``) or the
    multi-effect rigs (``--rigs``)."""
    from .rig_multi_effect import parse_effects

    common = {
        "strength": 1.0,
        "campaign": args.campaign,
        "candidates": candidates,
        "workdir": str(args.out),
        "jobs": args.jobs if local else 1,
        "quick": args.quick,
    }
    if not args.rigs:
        rigs = [(e, {}, None) for e in _truths(args, candidates)]
    else:
        rigs = []
        for spec in args.rigs:
            effects_text, _, tube = spec.partition("@")
            effects = parse_effects(effects_text)
            rig = {"tube_length_m": float(tube) if tube else args.tube_length}
            rigs.append(("+".join(effects), rig, effects))
    return [
        {"effect": e, "label": e, "rig": rig, "effects": effects, "seed": seed, **common}
        for e, rig, effects in rigs
        for seed in args.seeds
    ]


def multi_effect_markdown(summary: dict, args) -> str:
    """The multi-effect rigs' block: recall, every effect found, no false effect, time."""
    n = summary["n_rigs"]
    lines = [
        CAMPAIGN_BEGIN,
        "",
        f"Generated by `python -m pneumatic_env.studies.identification_eval --campaign "
        f"{args.campaign} --seeds {','.join(map(str, args.seeds))} --rigs "
        + " ".join(f'"{r}"' for r in args.rigs)
        + f"` ({n} multi-effect rigs; synthetic, virtual rig).",
        "",
        f"- Every effect found: {summary['all_found']} of {n}; mean recall "
        f"{summary['recall_mean']:.2f}.",
        f"- No false effect: {summary['no_false_effect']} of {n}.",
        f"- Time per rig: median {summary['seconds_median']:.0f} s, "
        f"max {summary['seconds_max']:.0f} s.",
        "",
        "| rig | seed | recall | false effects |",
        "|---|---|---|---|",
    ]
    for r in summary["rigs"]:
        lines.append(
            f"| {r['label']} | {r['seed']} | {r['recall']:.2f} | "
            f"{', '.join(r['false_effects']) or '-'} |"
        )
    return "\n".join([*lines, "", CAMPAIGN_END])


def _main_campaign(args, candidates: list[str]) -> int:
    # on Ray every task is one rig diagnosed in one process; locally the rigs run one at a
    # time and each diagnosis uses --jobs processes for its refits
    local = args.ray_address is None
    jobs = _rig_jobs(args, candidates, local)
    print(
        f"evaluate: {len(jobs)} campaigns ({args.campaign}), {len(candidates)} candidates",
        flush=True,
    )
    t0 = time.time()
    results = []
    for r in _run_all(evaluate_campaign, jobs, 1 if local else args.jobs, args.ray_address):
        results.append(r)
        print(
            f"  {r['label']:24s} seed={r['seed']}: {', '.join(r['selected']) or 'none':30s} "
            f"({r['seconds']:.0f} s, {time.time() - t0:.0f} s total)",
            flush=True,
        )
    elapsed = time.time() - t0
    if args.quick:
        summary = summarise_screening(results)
        block = screening_markdown(summary, results, args)
    elif args.rigs:
        summary = summarise_multi_effect(results)
        block = multi_effect_markdown(summary, args)
    else:
        summary = summarise_campaigns(results)
        block = campaign_markdown(summary, results, args, elapsed)
    _write_json(args.out / "evaluation_campaign.json", summary, results, candidates, elapsed)
    print(block)
    if args.docs is not None:
        _replace_block(args.docs, block, CAMPAIGN_BEGIN, CAMPAIGN_END)
    return 0


if __name__ == "__main__":
    sys.exit(main())
