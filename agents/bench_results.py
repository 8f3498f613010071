"""The benchmark's results: results.csv/.md/.json and plots in a directory, read back,
and merged into one leaderboard table (:func:`leaderboard`). Columns:
:data:`CSV_COLUMNS`; running the suite is :mod:`.bench`'s.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pneumatic_env.text_format import number_text

from .suite import Suite

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


def _fmt(value, digits=2) -> str:
    return number_text(value, digits, fixed=True, missing="", not_finite="")


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
    meta: dict[str, Any] = {
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
