"""The step floor of ``studies/step_floor.py``: the fastest constant current on a step,
with the physics it rests on (the paper's tube attenuation, Eqs. 31 and 35)."""

import numpy as np
import pytest

from pneumatic_env.agents.suite import load_suite
from pneumatic_env.studies.step_floor import step_floor

SUITE = load_suite()
STEPS = {t.name: t for t in SUITE.tasks if t.reference.get("kind") == "step"}
FULL_OPEN_A = 1.25  # the valve's holes are fully open from about 1.22 A (Eqs. 43-46)


@pytest.mark.parametrize("task", sorted(STEPS))
def test_a_half_open_valve_fills_a_2m_tube_chamber_faster_than_a_fully_open_one(task):
    """On a 2 m tube the turbulent attenuation of Eq. 31 grows with the flow faster than
    the flow, so a fully open valve reaches a half-scale step far later than a partly open
    one; the floor's best current is the partly open one."""
    both = step_floor("Numatics-2m", {}, STEPS[task], SUITE, currents_a=[0.35, FULL_OPEN_A])
    full = step_floor("Numatics-2m", {}, STEPS[task], SUITE, currents_a=[FULL_OPEN_A])
    assert both["current_a"] == 0.35
    assert full["rms_pct"] > 2.0 * both["rms_pct"]
    assert both["lead_steps"] <= SUITE.preview_steps and 0 < both["rise_steps"] < 200


@pytest.mark.parametrize("task", sorted(STEPS))
def test_the_tubes_air_in_the_chambers_slows_the_fastest_step(task):
    """The tube's own air added to each chamber (about 1.5 x its half-stroke volume on a
    2 m tube) must be filled too: the floor's rise is longer and its error higher."""
    currents = np.arange(0.25, 0.61, 0.05)
    nominal = step_floor("Numatics-2m", {}, STEPS[task], SUITE, currents_a=currents)
    air = step_floor(
        "Numatics-2m", {"tube_volume_fraction": 1.0}, STEPS[task], SUITE, currents_a=currents
    )
    assert air["rise_steps"] > 1.5 * nominal["rise_steps"]
    assert air["rms_pct"] > 1.3 * nominal["rms_pct"]
