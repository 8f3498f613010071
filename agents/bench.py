"""The force-tracking benchmark: ``pneumatic-env bench`` (suite: configs/benchmark.yaml).

One native vector env per variant runs every task of the suite at once (one env per task,
each with its own reference and seed); the controller acts on the whole batch. Metrics per
task: RMS and peak tracking error (N and % of the force scale), control effort (RMS
current), chatter (RMS of current differences), air consumption (exhaust mass), and from the
chirp the closed-loop -3 dB bandwidth (method: docs/benchmark.md, :func:`frequency_response`).
Output: results.csv, results.md, results.json and PNG plots in ``--out``; :func:`leaderboard`
merges several result directories into one Markdown table. The suite file is read by
``agents/suite.py`` (re-exported here).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

from pneumatic_env import ids
from pneumatic_env.envs.tasks import scale_spec  # scale-unit reference spec -> SI
from pneumatic_env.params import load_numerics

from .base import Controller, ControllerContext
from .registry import resolve_controller
from .suite import BenchTask, Suite, load_suite, parse_variant

__all__ = [
    "Suite",
    "BenchTask",
    "load_suite",
    "parse_variant",
    "make_env",
    "closed_loop",
    "frequency_response",
    "bandwidth",
    "error_bandwidth",
    "task_metrics",
    "resolve_controller",
    "run_suite",
    "write_results",
    "read_results",
    "leaderboard",
    "METRIC_COLUMNS",
    "CSV_COLUMNS",
    "add_arguments",
    "run",
]

METRIC_COLUMNS = (
    "rms_error_n",
    "rms_error_pct",
    "peak_error_n",
    "peak_error_pct",
    "bandwidth_hz",
    "bandwidth_lower_bound",
    "error_bandwidth_hz",
    "error_bandwidth_lower_bound",
    "effort_rms_a",
    "chatter_rms_a",
    "air_mg",
)
CSV_COLUMNS = (
    "suite_version",
    "controller",
    "variant",
    "task",
    "duration_s",
    "force_scale_n",
) + METRIC_COLUMNS


def make_env(variant: str, n_envs: int, n_steps: int, task: str = ids.FORCE_TRACK, **options):
    """The native vector env of ``variant`` with ``n_envs`` envs and ``n_steps``-step episodes."""
    return gym.make_vec(
        parse_variant(variant, task), num_envs=n_envs, max_episode_steps=int(n_steps), **options
    )


# --------------------------------------------------------------------------- running


def closed_loop(
    env, controller: Controller, references: Sequence[dict], seeds: Sequence[int], n_steps: int
) -> dict:
    """Run ``controller`` on the vector ``env``, env i tracking ``references[i]`` (scale units).

    Env i is reset with ``seeds[i]`` and ``options={"reference": ...}`` (its reference in SI),
    so its episode is that of the single env ``gym.make(id, reference=<SI spec>)`` reset
    with that seed. Returns arrays of shape (n_steps, n_envs): ``force_n``, ``reference_n``,
    ``current_a``, ``exhaust_kg``.
    """
    n = env.num_envs
    if len(references) != n or len(seeds) != n:
        raise ValueError(
            f"closed_loop: {len(references)} references and {len(seeds)} seeds for {n} envs"
        )
    limit = getattr(env, "max_episode_steps", None)
    if limit is not None and n_steps > limit:
        raise ValueError(
            f"closed_loop: n_steps = {n_steps} is longer than the env's episodes "
            f"({limit} steps): make the env with max_episode_steps >= n_steps"
        )
    scale = env.unwrapped.reference_scale
    obs, _ = env.reset(
        seed=[int(s) for s in seeds],
        options={"reference": [scale_spec(spec, scale) for spec in references]},
    )
    controller.reset()
    out = {k: np.empty((n_steps, n)) for k in ("force_n", "reference_n", "current_a", "exhaust_kg")}
    for k in range(n_steps):
        action = controller.act(obs)
        obs, _, _, _, info = env.step(np.asarray(action, dtype=np.float64).reshape(n, 1))
        out["reference_n"][k] = info["reference"]
        out["force_n"][k] = info["reference"] + info["tracking_error"]
        out["current_a"][k] = info["coil_current_a"]
        out["exhaust_kg"][k] = info["exhaust_mass_kg"]
    return out


# --------------------------------------------------------------------------- metrics


def frequency_response(
    reference: np.ndarray,
    output: np.ndarray,
    dt_s: float,
    f_lo_hz: float,
    f_hi_hz: float,
    bins_per_octave: float = 6.0,
):
    """Closed-loop frequency response from a chirp: band-averaged H1 estimate.

    With R, Y the FFTs of the mean-removed reference and output, each log-frequency band
    (``bins_per_octave`` per octave between f_lo and f_hi) gets H = sum(Y conj(R)) / sum(|R|^2)
    over the FFT lines in it. Returns (band centre frequencies in Hz, complex H).
    """
    r = np.asarray(reference, float) - np.mean(reference)
    y = np.asarray(output, float) - np.mean(output)
    R, Y = np.fft.rfft(r), np.fft.rfft(y)
    f = np.fft.rfftfreq(r.size, dt_s)
    n_bands = max(int(np.ceil(np.log2(f_hi_hz / f_lo_hz) * bins_per_octave)), 1)
    edges = f_lo_hz * 2.0 ** (np.arange(n_bands + 1) / bins_per_octave)
    centres, H = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        power = np.sum(np.abs(R[sel]) ** 2)
        if not sel.any() or power == 0:
            continue
        centres.append(np.sqrt(lo * hi))
        H.append(np.sum(Y[sel] * np.conj(R[sel])) / power)
    return np.array(centres), np.array(H)


def _first_crossing(freqs_hz, values, level, falling: bool):
    """First frequency where ``values`` crosses ``level`` (log-f interpolation between bands)."""
    bad = values < level if falling else values >= level
    hits = np.flatnonzero(bad)
    if hits.size == 0:
        return float(freqs_hz[-1]), True
    j = int(hits[0])
    if j == 0:
        return float(freqs_hz[0]), False
    v0, v1 = values[j - 1], values[j]
    w = (v0 - level) / (v0 - v1)
    return float(np.exp(np.log(freqs_hz[j - 1]) + w * np.log(freqs_hz[j] / freqs_hz[j - 1]))), False


def bandwidth(freqs_hz: np.ndarray, response: np.ndarray, level: float = 1 / math.sqrt(2)):
    """First frequency where the closed-loop gain |H| = |F/r| falls below ``level`` (-3 dB).

    Returns (bandwidth in Hz, lower_bound); ``lower_bound`` is True when |H| stays above the
    level over the whole band, and the bandwidth is then the highest band centre.
    """
    return _first_crossing(freqs_hz, np.abs(response), level, falling=True)


def error_bandwidth(freqs_hz: np.ndarray, response: np.ndarray, level: float = 1 / math.sqrt(2)):
    """First frequency where the tracking error |1 - H| = |E/r| rises to ``level`` (-3 dB).

    Unlike :func:`bandwidth` it counts phase errors: a pure delay D keeps |H| = 1 but has
    |1 - H| = 2 |sin(pi f D)|. Returns (Hz, lower_bound) as :func:`bandwidth`.
    """
    return _first_crossing(freqs_hz, np.abs(1.0 - response), level, falling=False)


def task_metrics(force_n, reference_n, current_a, exhaust_kg, scale_n: float) -> dict:
    """Tracking, effort, chatter and air metrics of one task (arrays over its steps)."""
    e = np.asarray(force_n) - np.asarray(reference_n)
    rms, peak = float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e)))
    i = np.asarray(current_a)
    return {
        "rms_error_n": rms,
        "rms_error_pct": 100 * rms / scale_n,
        "peak_error_n": peak,
        "peak_error_pct": 100 * peak / scale_n,
        "effort_rms_a": float(np.sqrt(np.mean(i**2))),
        "chatter_rms_a": float(np.sqrt(np.mean(np.diff(i) ** 2))) if i.size > 1 else 0.0,
        "air_mg": 1e6 * float(exhaust_kg[-1]),
    }


# --------------------------------------------------------------------------- controllers

# --------------------------------------------------------------------------- suite run


def run_suite(
    controller: str,
    variants: Sequence[str] | None = None,
    suite: Suite | None = None,
    config: str | None = None,
    progress: Callable[[str], None] | None = None,
    env_options: dict | None = None,
):
    """Run every task on every variant; returns (rows for the CSV, traces per variant).

    ``env_options``: more env keyword arguments (e.g. ``plant`` for a perturbed plant)."""
    suite = suite or load_suite()
    variants = list(variants or suite.variants)
    rows, traces = [], {}
    dt = load_numerics()["control_dt_s"]
    steps = [int(round(t.duration_s / dt)) for t in suite.tasks]
    n_steps = max(steps)
    for variant in variants:
        parse_variant(variant, suite.task)
        cspec = resolve_controller(controller, variant, config, suite.preview_steps)
        options = {**cspec.env_options, **(env_options or {})}
        env = make_env(variant, len(suite.tasks), n_steps, suite.task, **options)
        dt, scale = env.unwrapped.control_dt_s, env.unwrapped.reference_scale
        ctrl = cspec.build(ControllerContext.from_env(env))
        if progress:
            progress(f"{cspec.name} on {variant}: {len(suite.tasks)} tasks, {n_steps} steps")
        tr = closed_loop(
            env, ctrl, [t.reference for t in suite.tasks], [t.seed for t in suite.tasks], n_steps
        )
        env.close()
        traces[variant] = {"dt_s": dt, "scale_n": scale, "steps": steps, **tr}
        for i, task in enumerate(suite.tasks):
            k = steps[i]
            m = task_metrics(
                tr["force_n"][:k, i],
                tr["reference_n"][:k, i],
                tr["current_a"][:k, i],
                tr["exhaust_kg"][:k, i],
                scale,
            )
            for key in ("bandwidth", "error_bandwidth"):
                m[f"{key}_hz"], m[f"{key}_lower_bound"] = math.nan, ""
            if task.name == suite.bandwidth_task:
                ref = task.reference
                kk = min(k, int(round(ref["duration_s"] / dt)))
                f, H = frequency_response(
                    tr["reference_n"][:kk, i],
                    tr["force_n"][:kk, i],
                    dt,
                    ref["f0_hz"],
                    ref["f1_hz"],
                    suite.bins_per_octave,
                )
                bw, lower = bandwidth(f, H, suite.bandwidth_level)
                m["bandwidth_hz"], m["bandwidth_lower_bound"] = bw, bool(lower)
                bw, lower = error_bandwidth(f, H, suite.bandwidth_level)
                m["error_bandwidth_hz"], m["error_bandwidth_lower_bound"] = bw, bool(lower)
                traces[variant]["response"] = (f, H)
            rows.append(
                {
                    "suite_version": suite.version,
                    "controller": cspec.name,
                    "variant": variant,
                    "task": task.name,
                    "duration_s": task.duration_s,
                    "force_scale_n": scale,
                    **m,
                }
            )
    return rows, traces


# --------------------------------------------------------------------------- output


def _fmt(value, digits=2) -> str:
    if isinstance(value, str):
        return value
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, bool):
        return "yes" if value else ""
    return f"{value:.{digits}f}"


def _bandwidth_text(row, key: str = "bandwidth") -> str:
    bw = row.get(f"{key}_hz")
    if bw in ("", None) or (isinstance(bw, float) and math.isnan(bw)):
        return ""
    lower = row.get(f"{key}_lower_bound") in (True, "True", "true", "yes")
    return (">= " if lower else "") + f"{float(bw):.1f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def results_markdown(rows: list[dict], command: str = "", suite: Suite | None = None) -> str:
    """results.md: one table per variant (tasks x metrics)."""
    ctrl = rows[0]["controller"] if rows else ""
    version = rows[0]["suite_version"] if rows else ""
    parts = [f"# Benchmark results: {ctrl} (suite {version})", ""]
    if command:
        parts += [f"Command: `{command}`", ""]
    parts += [
        "Errors in N and in % of the force scale; effort = RMS coil current, chatter = "
        "RMS of the current's step-to-step change, air = exhaust mass over the task; "
        "bandwidth = -3 dB of |F/r|, error bw = frequency where |1 - F/r| reaches -3 dB, "
        "both estimated from the chirp (docs/benchmark.md).",
        "",
    ]
    header = [
        "task",
        "RMS err (N)",
        "RMS err (%)",
        "peak err (N)",
        "peak err (%)",
        "bandwidth (Hz)",
        "error bw (Hz)",
        "effort (A)",
        "chatter (A)",
        "air (mg)",
    ]
    for variant in dict.fromkeys(r["variant"] for r in rows):
        sel = [r for r in rows if r["variant"] == variant]
        parts += [f"## {variant} (force scale {float(sel[0]['force_scale_n']):.1f} N)", ""]
        parts.append(
            markdown_table(
                header,
                [
                    [
                        r["task"],
                        _fmt(r["rms_error_n"]),
                        _fmt(r["rms_error_pct"]),
                        _fmt(r["peak_error_n"]),
                        _fmt(r["peak_error_pct"]),
                        _bandwidth_text(r),
                        _bandwidth_text(r, "error_bandwidth"),
                        _fmt(r["effort_rms_a"], 3),
                        _fmt(r["chatter_rms_a"], 4),
                        _fmt(r["air_mg"], 1),
                    ]
                    for r in sel
                ],
            )
        )
        parts.append("")
    return "\n".join(parts)


def write_results(
    out: str | Path, rows: list[dict], traces: dict, suite: Suite, command: str = ""
) -> list[Path]:
    """results.csv, results.md, results.json and the plots; returns the written paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with open(out / "results.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in rows:  # NaN (no bandwidth outside the chirp task) as an empty cell
            w.writerow(
                {
                    k: "" if isinstance(r[k], float) and math.isnan(r[k]) else r[k]
                    for k in CSV_COLUMNS
                }
            )
    written.append(out / "results.csv")
    (out / "results.md").write_text(results_markdown(rows, command, suite), encoding="utf-8")
    written.append(out / "results.md")
    meta = {
        "suite_version": suite.version,
        "suite_path": suite.path,
        "command": command,
        "controller": rows[0]["controller"] if rows else "",
        "variants": list(traces),
    }
    (out / "results.json").write_text(json.dumps(meta, indent=2), encoding="utf-8")
    written.append(out / "results.json")
    written += _plots(out, traces, suite, meta["controller"])
    return written


def _plots(out: Path, traces: dict, suite: Suite, controller: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    names = [t.name for t in suite.tasks]
    for key, title in (("sine_task", "sine"), ("chirp_task", "chirp")):
        task = suite.plot_tasks.get(key)
        if task is None:
            continue
        i = names.index(task)
        fig, axes = plt.subplots(len(traces), 1, figsize=(8, 2.2 * len(traces)), squeeze=False)
        for ax, (variant, tr) in zip(axes[:, 0], traces.items()):
            k = tr["steps"][i]
            t = (np.arange(k) + 1) * tr["dt_s"]
            ax.plot(t, tr["reference_n"][:k, i], "k--", lw=1, label="reference")
            ax.plot(t, tr["force_n"][:k, i], lw=1, label="force")
            ax.set_ylabel("F (N)")
            ax.set_title(f"{variant}", fontsize=9)
        axes[0, 0].legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("t (s)")
        fig.suptitle(f"{controller}: {task} (suite {suite.version})")
        fig.tight_layout()
        path = out / f"tracking_{title}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    if any("response" in tr for tr in traces.values()):
        fig, ax = plt.subplots(figsize=(6, 3.5))
        for variant, tr in traces.items():
            if "response" in tr:
                f, H = tr["response"]
                ax.semilogx(
                    f, 20 * np.log10(np.maximum(np.abs(H), 1e-6)), marker=".", label=variant
                )
        ax.axhline(20 * np.log10(suite.bandwidth_level), color="k", ls=":", lw=1)
        ax.set_xlabel("f (Hz)")
        ax.set_ylabel("|F/r| (dB)")
        ax.set_title(f"{controller}: closed loop from the chirp")
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / "frequency_response.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    return written


def read_results(path: str | Path) -> list[dict]:
    """Rows of a results.csv (or of ``<dir>/results.csv``), numbers as floats."""
    path = Path(path)
    if path.is_dir():
        path = path / "results.csv"
    if not path.is_file():
        raise FileNotFoundError(f"no results.csv at {str(path)!r}")
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: missing column(s) {missing}")
        rows = []
        for r in reader:
            for k in (
                "duration_s",
                "force_scale_n",
                "rms_error_n",
                "rms_error_pct",
                "peak_error_n",
                "peak_error_pct",
                "bandwidth_hz",
                "error_bandwidth_hz",
                "effort_rms_a",
                "chatter_rms_a",
                "air_mg",
            ):
                r[k] = float(r[k]) if r[k] != "" else math.nan
            rows.append(r)
    return rows


LEADERBOARD_HEADER = (
    "variant",
    "controller",
    "mean RMS err (%)",
    "steps RMS (%)",
    "sine 10 Hz RMS (%)",
    "sines peak err (%)",
    "bandwidth (Hz)",
    "error bw (Hz)",
    "mean effort (A)",
    "mean chatter (A)",
    "air (mg)",
)


def leaderboard(paths: Sequence[str | Path]) -> str:
    """One Markdown table over several results (dirs or CSVs): a row per controller and variant.

    Columns: mean RMS error over all tasks, over the steps, on the 10 Hz sine (% of the force
    scale), the largest peak error of the sine tasks, the two chirp bandwidths, mean effort
    and chatter, total air. Sorted by variant, then mean RMS error. Results of different
    suite versions are refused.
    """
    rows = [r for p in paths for r in read_results(p)]
    versions = sorted({r["suite_version"] for r in rows})
    if len(versions) > 1:
        raise ValueError(f"leaderboard: results from different suite versions {versions}")
    table = []
    for key in dict.fromkeys((r["variant"], r["controller"]) for r in rows):
        sel = [r for r in rows if (r["variant"], r["controller"]) == key]

        def mean_of(pred, sel=sel):
            vals = [r["rms_error_pct"] for r in sel if pred(r["task"])]
            return float(np.mean(vals)) if vals else math.nan

        bw = next((r for r in sel if not math.isnan(r["bandwidth_hz"])), {})
        sine_peaks = [r["peak_error_pct"] for r in sel if r["task"].startswith("sine")]
        table.append(
            (
                key[0],
                key[1],
                float(np.mean([r["rms_error_pct"] for r in sel])),
                mean_of(lambda t: t.startswith("step")),
                mean_of(lambda t: t == "sine_10hz"),
                max(sine_peaks) if sine_peaks else math.nan,
                _bandwidth_text(bw),
                _bandwidth_text(bw, "error_bandwidth"),
                float(np.mean([r["effort_rms_a"] for r in sel])),
                float(np.mean([r["chatter_rms_a"] for r in sel])),
                float(np.sum([r["air_mg"] for r in sel])),
            )
        )
    order = list(dict.fromkeys(r["variant"] for r in rows))
    table.sort(key=lambda t: (order.index(t[0]), t[2]))
    body = [
        [v, c, _fmt(m), _fmt(s), _fmt(s10), _fmt(p), bw, ebw, _fmt(e, 3), _fmt(ch, 4), _fmt(a, 0)]
        for v, c, m, s, s10, p, bw, ebw, e, ch, a in table
    ]
    title = f"Suite {versions[0]}" if versions else "Suite"
    return f"{title}\n\n" + markdown_table(LEADERBOARD_HEADER, body)


# --------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--controller",
        help="pid | sliding_mode | zero | a shipped policy "
        "(--list) | path to a trained policy (.npz export or SB3 .zip)",
    )
    parser.add_argument(
        "--list",
        action="store_true",
        help="print every controller name --controller accepts, one a line",
    )
    parser.add_argument(
        "--variants",
        nargs="+",
        metavar="VARIANT",
        help="subset of the suite's variants, e.g. Numatics-0.5m Airpel-2m",
    )
    parser.add_argument(
        "--config",
        help="controller config YAML (default: "
        "configs/agents/<controller>-<variant>.yaml or <controller>.yaml)",
    )
    parser.add_argument("--suite", help="suite file (default configs/benchmark.yaml)")
    parser.add_argument("--out", help="output directory (default runs/bench/<controller>)")
    parser.add_argument(
        "--leaderboard",
        nargs="+",
        metavar="RESULTS",
        help="instead of running: merge these result dirs/CSVs into one "
        "Markdown table (written to --out if given, else printed)",
    )


def run(args: argparse.Namespace) -> int:
    if args.list:
        from .registry import controller_names

        print("\n".join(controller_names()))
        return 0
    if args.leaderboard:
        text = leaderboard(args.leaderboard)
        if args.out:
            Path(args.out).write_text(text + "\n", encoding="utf-8")
            print(f"wrote {args.out}")
        else:
            print(text)
        return 0
    if not args.controller:
        raise SystemExit("pneumatic-env bench: give --controller (or --leaderboard, --list)")
    suite = load_suite(args.suite)
    for variant in args.variants or suite.variants:  # a bad name fails before any run
        resolve_controller(args.controller, variant, args.config, suite.preview_steps)
    name = Path(args.controller).stem if Path(args.controller).suffix else args.controller
    out = Path(args.out or Path("runs") / "bench" / name)
    command = (
        "pneumatic-env bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        if len(sys.argv) > 1 and sys.argv[1] == "bench"
        else ""
    )
    rows, traces = run_suite(
        args.controller,
        args.variants,
        suite,
        args.config,
        progress=lambda msg: print(msg, flush=True),
    )
    for p in write_results(out, rows, traces, suite, command):
        print(f"wrote {p}")
    return 0
