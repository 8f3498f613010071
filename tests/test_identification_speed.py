"""Identification speed: the fit's simulations shared out over threads, bit for bit; the
screening from a base fit stopped early.

The recordings come from the virtual rig (synthetic, never measured), 0.3-1 s long.
"""

from __future__ import annotations

import copy
import math
import threading

import numpy as np
import pytest

from pneumatic_env.identification import problem as fit_problem
from pneumatic_env.identification.calibrate import diagnosis_fit_stops, run_fit
from pneumatic_env.identification.candidates import available_candidates
from pneumatic_env.identification.checks import read_checked
from pneumatic_env.identification.config import load_config
from pneumatic_env.identification.datasets import base_fit_parameters, prepare_datasets
from pneumatic_env.identification.diagnose import diagnose, stopped_early
from pneumatic_env.identification.holdout import Holdout
from pneumatic_env.identification.screening import screen_candidates
from pneumatic_env.studies.virtual_rig import make_recording

ROLLOUT_PIECE = fit_problem._rollout_piece


@pytest.fixture(scope="module")
def clamped_and_spring(tmp_path_factory):
    """A clamped-rod and a spring-rod recording of one rig (the moving rod has its own
    substep, so its columns are a batch of their own)."""
    out = tmp_path_factory.mktemp("speed")
    paths = [
        make_recording(out, name=piston, effect="none", seed=3, duration_s=0.3, piston=piston)
        for piston in ("fixed", "spring")
    ]
    cfg = load_config()
    datasets, _ = prepare_datasets([read_checked(p) for p in paths], None, cfg)
    return datasets, base_fit_parameters(datasets, None, cfg), cfg


def _jacobian(datasets, free, cfg, threads: int, monkeypatch) -> tuple[np.ndarray, set]:
    """A base Jacobian at the start with ``threads`` threads, and the threads it ran on."""
    ran_on: set[str] = set()

    def recorded(*args):
        ran_on.add(threading.current_thread().name)
        return ROLLOUT_PIECE(*args)

    monkeypatch.setattr(fit_problem, "_threads", lambda: threads)
    monkeypatch.setattr(fit_problem, "_rollout_piece", recorded)
    problem = fit_problem.FitProblem(datasets, free, config=cfg)
    u = problem.initial_u()
    problem.jacobian(u)  # the unperturbed run first, as least_squares does
    ran_on.clear()
    problem._jac_cache.clear()
    return problem.jacobian(u), ran_on


def test_threaded_jacobian_equals_the_serial_one(clamped_and_spring, monkeypatch):
    datasets, free, cfg = clamped_and_spring
    serial, serial_threads = _jacobian(datasets, free, cfg, 1, monkeypatch)
    threaded, pool_threads = _jacobian(datasets, free, cfg, 2, monkeypatch)
    assert serial_threads == {threading.current_thread().name}
    assert len(pool_threads) == 2 and threading.current_thread().name not in pool_threads
    assert np.count_nonzero(serial) > serial.shape[1]  # every column moves something
    assert np.array_equal(serial, threaded)


def test_simulate_jobs_splits_columns_and_keeps_their_order(clamped_and_spring, monkeypatch):
    """Each job's columns come back in its order, whatever pieces they were run in."""
    datasets, _, _ = clamped_and_spring
    columns = [{"supply_pressure_pa": p} for p in (5.0e5, 5.5e5, 6.0e5, 6.5e5, 7.0e5)]
    monkeypatch.setattr(fit_problem, "_threads", lambda: 2)
    both = fit_problem.simulate_jobs([(ds, columns, 200, None, None) for ds in datasets])
    for ds, sims in zip(datasets, both):
        for j, column in enumerate(columns):
            alone = fit_problem.simulate_jobs([(ds, [column], 200, None, None)])[0]
            for c in ds.channels:
                assert np.array_equal(sims[c][:, j], alone[c][:, 0])


def test_unlike_columns_run_in_pieces_of_their_own_and_alone_bit_for_bit(
    clamped_and_spring, monkeypatch
):
    """A job mixing columns that run different kernel loops (the paper's model, a leak,
    an exhaust node, a supply node, the energy equation) runs each kind in pieces of its
    own, so a costly node column never sets the loop of a cheap one, and every column's
    result is the one it has simulated alone."""
    datasets, _, _ = clamped_and_spring
    kinds = [
        {},
        {"rod_seal_leak_area_m2": 2e-8},
        {"exhaust_vent_area_m2": 5e-6},
        {"supply_resistance_pa_s_per_kg": 2e7},
        {"wall_heat_transfer_w_per_k": 0.05},
    ]
    columns = [{**kind, "supply_pressure_pa": p} for p in (5.5e5, 6.0e5) for kind in kinds]
    pieces: list[np.ndarray] = []

    def recorded(ds, params, *args):
        pieces.append(params.copy())
        return ROLLOUT_PIECE(ds, params, *args)

    monkeypatch.setattr(fit_problem, "_threads", lambda: 2)
    monkeypatch.setattr(fit_problem, "_rollout_piece", recorded)
    for ds in datasets:
        pieces.clear()
        mixed = fit_problem.simulate_jobs([(ds, columns, 200, None, None)])[0]
        names = [next(iter(kind), "none") for kind in kinds]
        row = {n: fit_problem._ROW[n] for n in names if n != "none"}
        for params in pieces:  # one kind per piece: the kind's row set on all or none
            set_on = {n for n, r in row.items() if np.any(params[r] != params[r, 0])}
            assert not set_on, f"{ds.name}: a piece mixes columns with and without {set_on}"
        assert len(pieces) >= len(kinds)
        monkeypatch.setattr(fit_problem, "_rollout_piece", ROLLOUT_PIECE)
        for j, column in enumerate(columns):
            alone = fit_problem.simulate_jobs([(ds, [column], 200, None, None)])[0]
            for c in ds.channels:
                assert np.array_equal(mixed[c][:, j], alone[c][:, 0]), (ds.name, column, c)
        monkeypatch.setattr(fit_problem, "_rollout_piece", recorded)


def test_pieces_stay_whole_when_the_threads_balance_and_split_when_they_do_not():
    """Whole pieces keep more lanes per chunk: five recordings' Jacobians whose costs
    balance on two threads run as they are; a lone piece is shared by both threads, and
    every column is run exactly once."""

    def task(cost, n_cols, k):
        return (cost, cost, k, np.arange(n_cols), 8)

    recordings = [task(c, 11, k) for k, c in enumerate((3.0, 2.0, 3.0, 4.0, 6.0))]
    assert fit_problem._balanced(recordings, 2) == recordings
    lone = fit_problem._balanced([task(10.0, 11, 0)], 2)
    assert sorted(t[3].size for t in lone) == [5, 6]
    assert sorted(np.concatenate([t[3] for t in lone])) == list(range(11))
    assert sum(t[0] for t in lone) == pytest.approx(10.0)
    uneven = fit_problem._balanced([task(9.0, 4, 0), task(1.0, 3, 1)], 2)
    assert fit_problem._makespan([t[0] for t in uneven], 2) <= 1.1 * 10.0 / 2 + 1e-9
    assert fit_problem._balanced(recordings, 1) == recordings


def test_early_screening_ranks_the_true_effect_first(tmp_path):
    """The base fit stops for the screening once its cost has stopped falling fast
    (``screening.early_relative_decrease``), and the screening from that point still
    ranks the rig's leak first; with ``quick`` the base fit is left there."""
    paths = [
        make_recording(
            tmp_path, name=piston, effect="leakage", seed=1, duration_s=1.0, piston=piston
        )
        for piston in ("fixed", "spring")
    ]
    candidates = ["leakage", "pressure_sensor_offset", "pressure_sensor_lag", "supply_droop"]
    diag = diagnose([read_checked(p) for p in paths], candidates=candidates, quick=True)
    assert stopped_early(diag.base)
    n_min = load_config().number("screening", "early_min_jacobians")
    assert diag.base.n_jacobians >= n_min
    ranking = [entry["name"] for entry in diag.screening[0]["ranking"]]
    assert ranking[0] == "leakage"
    # quick screens on the training rows only: the same ranking, to the bit, as a screening
    # that simulates the held-out data too, and no held-out prediction
    assert all(e["predicted_heldout_improvement"] is None for e in diag.screening[0]["ranking"])
    cfg = load_config()
    datasets, _ = prepare_datasets([read_checked(p) for p in paths], None, cfg)
    split = Holdout(datasets, "auto", cfg)
    full = screen_candidates(
        available_candidates(candidates, cfg),
        diag.base,
        list(diag.base.parameters),
        datasets,
        split.train,
        split.train_n,
        split.held,
        split.held_masks,
        cfg,
    )
    assert [(s.name, s.predicted_delta_ic) for s in full] == [
        (e["name"], e["predicted_delta_ic"]) for e in diag.screening[0]["ranking"]
    ]
    assert any(math.isfinite(s.predicted_heldout) for s in full)


def test_a_fit_stops_where_its_cost_levels_off_close_to_the_converged_cost(tmp_path):
    """With the config's plateau (``fit.plateau_*``: the robust cost fell by less than
    0.3 % over 3 Jacobians) a fit stops early. From the config's nominal start on clean
    rigs (four seeds: where the plateau saves a Jacobian depends on the path, and on the
    machine's rounding, so one or two seeds decide nothing) it never costs more Jacobians
    than the fit run to the tolerance, lands within 2 % of its cost, and stops by the
    plateau with fewer Jacobians on at least one."""
    cfg = load_config()
    plateau = diagnosis_fit_stops(cfg)["plateau"]
    stopped_by_plateau = 0
    for seed in (3, 4, 5, 6):
        paths = [
            make_recording(
                tmp_path / str(seed),
                name=piston,
                effect="none",
                seed=seed,
                duration_s=0.5,
                piston=piston,
            )
            for piston in ("fixed", "spring")
        ]
        datasets, _ = prepare_datasets([read_checked(p) for p in paths], None, cfg)
        free = base_fit_parameters(datasets, None, cfg)

        full, levelled = (
            run_fit(
                fit_problem.FitProblem(datasets, free, config=cfg),
                tolerance=1e-8,
                friction_restarts=False,
                plateau=rule,
            )
            for rule in (None, plateau)
        )
        assert levelled.n_jacobians <= full.n_jacobians
        assert levelled.cost_history[-1] <= 1.02 * full.cost_history[-1]
        if levelled.message.startswith("levelled off"):
            # the rule: the last cost is less than 0.3 % below the one 3 Jacobians before
            before, now = levelled.cost_history[-1 - plateau[1]], levelled.cost_history[-1]
            assert (before - now) / before < plateau[0]
            stopped_by_plateau += levelled.n_jacobians < full.n_jacobians
    assert stopped_by_plateau >= 1


def test_always_refit_adds_the_named_candidates_below_the_top_once():
    """``screening.always_refit`` names candidates refitted whatever their screening rank:
    picked from below the top unless the top or the drift picks already hold them; an
    unknown name is refused, naming the field, the value and what is allowed."""
    from types import SimpleNamespace

    from pneumatic_env.identification.config import (
        ConfigError,
        IdentificationConfig,
        load_config,
    )
    from pneumatic_env.identification.selection import form_picks

    cfg = load_config()
    assert "heat_transfer" in cfg.names("screening", "always_refit")
    screens = [SimpleNamespace(name=n) for n in ("leakage", "coil_lag", "heat_transfer", "lugre")]
    top = screens[:2]
    assert [s.name for s in form_picks(cfg, screens[2:], top)] == ["heat_transfer"]
    assert form_picks(cfg, screens[3:], screens[:3]) == []  # ranked in the top: not twice
    assert form_picks(cfg, screens[2:], [*top, screens[2]]) == []  # a drift pick already
    raw = copy.deepcopy(dict(cfg.raw))  # the loaded config is cached: change a copy
    raw["screening"]["always_refit"]["value"] = ["heat_transfer", "warp_drive"]
    wrong = IdentificationConfig(raw, cfg.path)
    with pytest.raises(ConfigError, match=r"always_refit names \['warp_drive'\].*allowed are"):
        form_picks(wrong, screens, top)


def test_a_close_rival_of_a_refitted_candidate_is_refitted_too():
    """A candidate below the top whose separating-experiment rival is refitted is refitted
    too when its predicted BIC drop is at least ``screening.rival_refit_ratio`` of the
    rival's (the user13 leak + coil-lag rig: the leak at -42 behind the null leak at -51);
    not when it is further behind, not a rival, or the rival's drop is below the BIC
    threshold; a ratio outside [0, 1] is refused naming the field."""
    from types import SimpleNamespace

    from pneumatic_env.identification.config import (
        ConfigError,
        IdentificationConfig,
        load_config,
    )
    from pneumatic_env.identification.selection import rival_picks

    cfg = load_config()
    ratio = cfg.number("screening", "rival_refit_ratio")
    assert 0.0 < ratio < 1.0

    def screen(name, ic):
        return SimpleNamespace(name=name, predicted_delta_ic=ic)

    top = [screen("channel_time_skew", -61.0), screen("valve_null_leak", -51.0)]
    close = screen("leakage", -51.0 * (ratio + 0.05))
    far = screen("leakage", -51.0 * (ratio - 0.05))
    stranger = screen("lugre", -50.0)  # close, but no rival of a refitted one
    assert rival_picks(cfg, [close, stranger], top) == [close]
    assert rival_picks(cfg, [close], [*top, close]) == []  # a drift or form pick already
    assert rival_picks(cfg, [far, stranger], top) == []
    weak = [screen("valve_null_leak", -5.0)]  # a rival that would not pass the BIC test
    assert rival_picks(cfg, [screen("leakage", -5.0)], weak) == []
    raw = copy.deepcopy(dict(cfg.raw))
    raw["screening"]["rival_refit_ratio"]["value"] = 1.5
    with pytest.raises(ConfigError, match=r"rival_refit_ratio = 1.5 is not allowed: must be <= 1"):
        rival_picks(IdentificationConfig(raw, cfg.path), [close], top)
