"""The identification evaluation on multi-effect rigs (studies/identification_eval.py):
its jobs and its scoring, on stub results (no diagnosis is run)."""

from __future__ import annotations

import argparse

import pytest

from pneumatic_env.studies.identification_eval import (
    _rig_jobs,
    multi_effect_markdown,
    refitted_in_round_1,
    screening_markdown,
    summarise_multi_effect,
    summarise_screening,
)


def _args(**kw):
    base = dict(
        campaign="user13", seeds=[1, 2], rigs=None, tube_length=0.5, jobs=2, out=".", quick=False
    )
    return argparse.Namespace(**{**base, **kw})


def test_multi_effect_rigs_become_one_job_per_rig_and_seed():
    args = _args(rigs=["tube_waves+heat_transfer+spool_friction@2", "leakage+coil_lag=0.5"])
    jobs = _rig_jobs(args, ["leakage"], local=True)
    assert len(jobs) == 4
    first, last = jobs[0], jobs[-1]
    assert first["effects"] == {"tube_waves": 1.0, "heat_transfer": 1.0, "spool_friction": 1.0}
    assert first["rig"] == {"tube_length_m": 2.0} and first["label"] == first["effect"]
    assert last["effects"] == {"leakage": 1.0, "coil_lag": 0.5} and last["seed"] == 2
    assert last["rig"] == {"tube_length_m": 0.5}
    with pytest.raises(ValueError, match="not allowed"):
        _rig_jobs(_args(rigs=["leakage+nonsense"]), [], local=True)


def test_multi_effect_scoring_counts_recall_and_false_effects():
    def result(effects, selected, seconds):
        return {
            "label": "+".join(effects),
            "seed": 1,
            "effects": dict.fromkeys(effects, 1.0),
            "selected": selected,
            "seconds": seconds,
        }

    results = [
        result(["leakage", "coil_lag"], ["coil_lag", "leakage"], 100.0),  # all found
        result(["tube_waves", "heat_transfer", "spool_friction"], ["tube_waves"], 300.0),
        result(["supply_droop", "pressure_sensor_lag"], ["supply_droop", "stribeck"], 200.0),
        result(["leakage", "supply_ripple"], ["leakage"], 50.0),  # ripple: outside the catalog
    ]
    summary = summarise_multi_effect(results)
    assert summary["all_found"] == 2
    assert summary["no_false_effect"] == 3
    assert summary["recall_mean"] == pytest.approx((1 + 1 / 3 + 1 / 2 + 1) / 4)
    assert summary["rigs"][2]["false_effects"] == ["stribeck"]
    assert (summary["seconds_median"], summary["seconds_max"]) == (200.0, 300.0)
    block = multi_effect_markdown(summary, _args(rigs=["leakage+coil_lag"]))
    assert "Every effect found: 2 of 4" in block and "| stribeck |" in block


def test_screening_recall_reads_round_1_refits_from_quick_and_full_records():
    """``--quick``: round 1's refits are the screening's top ``refit_top`` and
    ``always_refit`` (config); a full record lists its refits. The summary counts rigs
    whose every catalog effect is among them, and first places of single-effect rigs."""
    from pneumatic_env.identification.config import load_config

    cfg = load_config()
    top = int(cfg.number("screening", "refit_top"))
    always = cfg.names("screening", "always_refit")
    ranking = ["leakage", "coil_lag", "iso_flow_law", "tube_volume", "stribeck", *always]
    quick = {"quick": True, "screening": [{"ranking": [{"name": n} for n in ranking]}]}
    assert refitted_in_round_1(quick) == ranking[:top] + list(always)
    full = {
        "quick": False,
        "candidates": [
            {"name": "leakage", "round": 1, "refitted": True},
            {"name": "coil_lag", "round": 1, "refitted": False},
            {"name": "stribeck", "round": 2, "refitted": True},
        ],
    }
    assert refitted_in_round_1(full) == ["leakage"]

    def result(effect, effects, first, refitted, seconds):
        return {
            "label": effect,
            "effect": effect,
            "effects": effects,
            "seed": 1,
            "screening_first": first,
            "refitted_round_1": refitted,
            "seconds": seconds,
        }

    results = [
        result("leakage", None, ["leakage", "coil_lag"], ["leakage", "coil_lag"], 10.0),
        result("coil_lag", None, ["leakage", "coil_lag"], ["leakage", "coil_lag"], 12.0),
        result("heat_transfer", None, ["iso_flow_law"], ["iso_flow_law"], 14.0),  # missed
        result("none", None, ["leakage"], ["leakage"], 9.0),  # no catalog effect: not counted
        result("a+b", {"leakage": 1.0, "supply_ripple": 1.0}, ["x"], ["leakage"], 20.0),
        result("c+d", {"leakage": 1.0, "coil_lag": 1.0}, ["x"], ["coil_lag"], 30.0),
    ]
    summary = summarise_screening(results)
    assert (summary["n_rigs"], summary["all_refitted"], summary["any_refitted"]) == (5, 3, 4)
    assert (summary["n_single"], summary["first"]) == (3, 1)
    assert summary["missed"] == ["heat_transfer seed 1: heat_transfer", "c+d seed 1: leakage"]
    assert (summary["seconds_median"], summary["seconds_max"]) == (14.0, 30.0)
    block = screening_markdown(summary, results, _args(quick=True, effects=None))
    assert "among round 1's refits: 3 of 5 rigs" in block and "later rounds" in block
