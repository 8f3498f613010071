"""The stand-in check after the greedy rounds (pneumatic_env/identification/stand_ins.py).

The backward elimination's bookkeeping is checked here with the refits replaced by their
outcomes (a refit costs seconds to minutes; the suite has no room for a campaign per
case). On real fits the check runs in
``test_identification_campaign.py::test_greedy_rounds_find_both_effects_of_a_two_effect_rig``
(three seeds of a two-effect rig: both effects kept), and docs/identification.md gives
it on the evaluation's wall-heat + spool-friction rig, where round 1 accepted a stand-in.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from pneumatic_env.identification import stand_ins

MIN_REL = 0.10  # the threshold the check is given (the config's is 10 % too)


def _state(names):
    """A selection of ``names`` in the order accepted, with an accepted score each."""
    selected = [SimpleNamespace(name=n) for n in names]
    return SimpleNamespace(
        selected=selected,
        confidence=[{"effect": n} for n in names],
        scores=[SimpleNamespace(name=n, accepted=True, reasons=[]) for n in names],
        current="final fit",
        current_mean=0.010,
        current_per={"r1": 0.010},
    )


def _run(monkeypatch, names, worth):
    """``drop_stand_ins`` with each removal's outcome given by ``worth[name]`` (the full
    model's held-out improvement over the model without it); returns the state, the
    removals tried and the order they were tried in."""
    tried_order = []

    def trial(ctx, state, effect):
        tried_order.append(effect.name)
        without = 0.010 / (1.0 - worth[effect.name])
        return stand_ins.Removal(
            effect.name, f"fit without {effect.name}", without, {"r1": without},
            worth[effect.name], "test",
        )  # fmt: skip

    monkeypatch.setattr(stand_ins, "removal_trial", trial)
    ctx = SimpleNamespace(
        settings=SimpleNamespace(min_rel=MIN_REL), plan=SimpleNamespace(refit=1.0), timings={}
    )
    state = _state(names)
    tried = stand_ins.drop_stand_ins(ctx, state)
    assert ctx.timings["stand_in_check"] >= 0.0
    return state, tried, tried_order


def test_the_weakest_earlier_effect_below_the_threshold_is_dropped(monkeypatch):
    """Three effects; the first is worth 2 % with the later two in the model: it is dropped,
    its model (the one without it) becomes the current one, its confidence entry goes and
    its score is refused with the reason; the second, worth 50 %, is then kept, and the
    last round's effect is never retried."""
    state, tried, order = _run(monkeypatch, ["a", "b", "c"], {"a": 0.02, "b": 0.5, "c": 0.0})
    assert [c.name for c in state.selected] == ["b", "c"]
    assert [c["effect"] for c in state.confidence] == ["b", "c"]
    assert order == ["a", "b", "b"] and "c" not in order
    assert [(t["name"], t["dropped"]) for t in tried] == [("a", True), ("b", False), ("b", False)]
    assert state.current == "fit without a"
    assert state.current_mean == pytest.approx(0.010 / 0.98)
    score_a = state.scores[0]
    assert not score_a.accepted
    assert "stand-in" in score_a.reasons[-1] and "b, c" in score_a.reasons[-1]
    assert all(s.accepted for s in state.scores[1:])


def test_effects_that_earn_their_place_are_kept(monkeypatch):
    """Every earlier effect at or above the threshold: nothing changes."""
    state, tried, _ = _run(monkeypatch, ["a", "b", "c"], {"a": MIN_REL, "b": 0.3, "c": 0.0})
    assert [c.name for c in state.selected] == ["a", "b", "c"]
    assert state.current == "final fit" and all(s.accepted for s in state.scores)
    assert [t["dropped"] for t in tried] == [False, False]


def test_stand_ins_go_one_at_a_time_down_to_the_last_effect(monkeypatch):
    """Two stand-ins: the weaker goes first, then the other (retried without it); the
    last round's effect stays however little the others were worth."""
    state, tried, order = _run(monkeypatch, ["a", "b", "c"], {"a": 0.05, "b": 0.01, "c": 0.0})
    assert [c.name for c in state.selected] == ["c"]
    assert order == ["a", "b", "a"]
    assert [t["name"] for t in tried if t["dropped"]] == ["b", "a"]
