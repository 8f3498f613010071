"""The issue-35 evaluation harness (studies/rig_eval.py): its bookkeeping on stub stages
(checkpoints, resume, the summary's statistics); the full pipeline in one slow test."""

from __future__ import annotations

import json

import pytest

from pneumatic_env.studies import rig_eval
from pneumatic_env.studies.rig_eval import EVAL_RIGS, Plan, run_evaluation

CALLS: list[tuple] = []
#: stub suite RMS errors (%): the baselines per rig, the trained controller per seed
BASELINES = {"pid": 6.0, "sliding_mode": 5.0, "ppo_residual": 7.0}


def _prepare(job):
    CALLS.append(("prepare", job["rig"][0]))
    baselines = {k: {"rms_error_pct": v} for k, v in BASELINES.items()}
    baselines["ppo_pure"] = {"skipped": "no shipped policy"}
    return {"rig": job["rig"][0], "baselines": baselines}


def _train(job):
    CALLS.append(("train", job["rig"][0], job["seed"]))
    scale = 1.0 if job["rig"][0] == EVAL_RIGS[0].name else 0.5
    rms = scale * job["seed"]
    return {
        "rig": job["rig"][0],
        "seed": job["seed"],
        "rms_error_pct": rms,
        "base_alone_rms_error_pct": rms + 0.25,
    }


def _skipping_train(job):
    return {"rig": job["rig"][0], "seed": job["seed"], "skipped": "train --rig is missing"}


def test_the_harness_checkpoints_each_result_and_resumes(tmp_path):
    CALLS.clear()
    plan = Plan(rigs=EVAL_RIGS[:2], seeds=(1, 2, 3, 4))
    summary = run_evaluation(plan, tmp_path, 1, prepare=_prepare, train=_train, log=lambda s: None)
    assert len(CALLS) == 2 + 2 * 4
    for rig in EVAL_RIGS[:2]:
        assert (tmp_path / rig.name / "rig.json").is_file()
        assert sorted(p.name for p in (tmp_path / rig.name).glob("seed_*.json")) == [
            f"seed_{s}.json" for s in (1, 2, 3, 4)
        ]
    first, second = (summary["rigs"][r.name] for r in EVAL_RIGS[:2])
    assert first["best_classical"] == "sliding_mode" and first["n_seeds"] == 4
    # IQM of 1, 2, 3, 4: the mean of the middle two
    assert first["trained_iqm_rms_pct"]["value"] == pytest.approx(2.5)
    assert first["ratio_to_best_classical"]["value"] == pytest.approx(2.5 / 5.0)
    low, high = (first["ratio_to_best_classical"][k] for k in ("low", "high"))
    assert low <= 0.5 <= high and low < high
    assert second["ratio_to_best_classical"]["value"] == pytest.approx(1.25 / 5.0)
    assert summary["ratio_median"] == pytest.approx((0.5 + 0.25) / 2)
    assert summary["ratio_worst"] == pytest.approx(0.5)
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    # a rerun reads every finished result back; one more seed runs only that seed
    CALLS.clear()
    assert run_evaluation(plan, tmp_path, 1, prepare=_prepare, train=_train, log=print) == summary
    assert CALLS == []
    more = Plan(rigs=EVAL_RIGS[:2], seeds=(1, 2, 3, 4, 5))
    run_evaluation(more, tmp_path, 1, prepare=_prepare, train=_train, log=print)
    assert sorted(CALLS) == sorted(("train", r.name, 5) for r in EVAL_RIGS[:2])


def test_the_summary_of_a_stopped_run_reads_its_checkpoints(tmp_path, capsys):
    """``--summary`` runs nothing and gives the figures of the stages already written:
    those of a run stopped after some seeds, as the run itself would summarise them."""
    plan = Plan(rigs=EVAL_RIGS[:2], seeds=(1, 2, 3))
    summary = run_evaluation(plan, tmp_path, 1, prepare=_prepare, train=_train, log=print)
    (tmp_path / EVAL_RIGS[1].name / "seed_3.json").unlink()  # stopped before this seed
    rigs, trained = rig_eval.finished(plan, tmp_path)
    assert rigs == {r.name: _prepare({"rig": list(r)}) for r in EVAL_RIGS[:2]}
    assert [len(trained[r.name]) for r in EVAL_RIGS[:2]] == [3, 2]
    partial = rig_eval.summarise(rigs, trained)
    assert partial["rigs"][EVAL_RIGS[0].name] == summary["rigs"][EVAL_RIGS[0].name]
    assert partial["rigs"][EVAL_RIGS[1].name]["n_seeds"] == 2
    CALLS.clear()
    names = [r.name for r in EVAL_RIGS[:2]]
    assert rig_eval.main(["--out", str(tmp_path), "--summary", "--rigs", *names]) == 0
    assert CALLS == []  # nothing ran
    out = capsys.readouterr().out
    assert all(f"| {n} |" in out for n in names) and "ratio over rigs" in out
    # per seed: the trained controller's error beside its base's alone
    assert f"| {names[0]} | 2 | 2.00 | 2.25 |" in out


def test_a_missing_trainer_is_reported_not_scored(tmp_path):
    plan = Plan(rigs=EVAL_RIGS[:1], seeds=(1,))
    summary = run_evaluation(
        plan, tmp_path, 1, prepare=_prepare, train=_skipping_train, log=lambda s: None
    )
    assert summary["n_rigs_trained"] == 0 and summary["ratio_median"] is None
    assert summary["skipped"] == ["train --rig is missing"]
    assert "train --rig is missing" in rig_eval._table(summary)


def test_the_evaluation_rigs_are_the_issues():
    """At least 8 rigs; single effects and combinations of two and three, the tube effect
    with heat transfer and spool friction among them; every rig off nominal (a seed)."""
    sizes = [len(r.effects) for r in EVAL_RIGS]
    assert len(EVAL_RIGS) >= 8 and {1, 2, 3} <= set(sizes)
    assert any(
        {e for e, _ in r.effects} == {"tube_waves", "heat_transfer", "spool_friction"}
        for r in EVAL_RIGS
    )
    assert len({r.seed for r in EVAL_RIGS}) == len(EVAL_RIGS)


def test_trainings_run_one_at_a_time_by_default(tmp_path, monkeypatch):
    """The rigs' stages share the processes; each training gets the machine (a wall-time
    budget shared by two trainings buys each a fifth of the samples)."""
    seen, real = [], rig_eval._run

    def spy(tasks, processes, ray_address):
        seen.append((tasks[0][0].__name__, processes))
        return real(tasks, 1, None)

    monkeypatch.setattr(rig_eval, "_run", spy)
    plan = Plan(rigs=EVAL_RIGS[:2], seeds=(1, 2))
    run_evaluation(plan, tmp_path, 2, prepare=_prepare, train=_train, log=lambda s: None)
    assert seen == [("_prepare", 2), ("_train", 1)]
    run_evaluation(
        plan,
        tmp_path / "b",
        2,
        prepare=_prepare,
        train=_train,
        log=lambda s: None,
        train_processes=2,
    )
    assert seen[-1] == ("_train", 2)
