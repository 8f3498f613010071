"""Bad-data checks that know the physics (issue 20): sub-ambient dips and saturation at
supply or ambient are physical; gauge data, wrong units and a clipped sensor are not.

The recordings come from the virtual rig (synthetic): short, so these tests are fast.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest

from pneumatic_env.identification.checks import (
    BadDataError,
    check_recordings,
    read_checked,
    usable_masks,
)
from pneumatic_env.identification.config import IdentificationConfig, load_config
from pneumatic_env.recording import read_recording, write_recording
from pneumatic_env.studies.virtual_rig import run_rig


def _write(tmp_path, name, result, **changes):
    channels = {c: (changes[c](y) if c in changes else y) for c, y in result.channels.items()}
    return write_recording(tmp_path / name, result.t, channels, result.rig, overwrite=True)


def _read_without_warnings(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any reader warning fails the test
        return read_recording(path)


@pytest.fixture(scope="module")
def sub_ambient():
    """A spring whose rest position is 30 mm off the rod's start: with the valve closed
    both chambers are sealed, the spring pulls the rod and the cap chamber expands
    below ambient (as on a user's rig, issue 20: 44 kPa absolute)."""
    return run_rig(
        "none",
        seed=1,
        duration_s=1.0,
        piston="spring",
        excitation_kind="identification",
        spring_rest_position_m=0.03,
    )


@pytest.fixture(scope="module")
def saturated():
    """Clamped steps without sensor noise (the ADC step stays): each chamber sits
    exactly at the quantised supply or ambient pressure for hundreds of samples."""
    raw = copy.deepcopy(load_config().raw)
    for ch in raw["virtual_rig"]["noise"]:
        raw["virtual_rig"]["noise"][ch]["value"] = 0.0
    cfg = IdentificationConfig(raw, "noise-free")
    return run_rig(
        "none", seed=2, duration_s=1.0, excitation_kind="steps", perturb=False, config=cfg
    )


def test_a_sub_ambient_dip_is_read_without_warning_or_refusal(sub_ambient, tmp_path):
    p1 = sub_ambient.channels["p1"]
    ambient = sub_ambient.rig["ambient_pressure_pa"]
    # below half of ambient: the rule of the previous reader ("gauge") refused this
    assert p1.min() < 0.5 * ambient
    path = _write(tmp_path, "spring", sub_ambient)
    rec = _read_without_warnings(path)
    assert rec.warnings == []
    assert check_recordings([rec]) == []


def test_saturation_at_supply_and_ambient_is_not_clipping(saturated, tmp_path):
    path = _write(tmp_path, "steps", saturated)
    rec = _read_without_warnings(path)
    assert rec.warnings == []
    for ch in ("p1", "p2"):
        y = rec.channels[ch]
        # long flat runs at both extremes: what the clipping rule looks for
        for value in (y.min(), y.max()):
            assert np.sum(y == value) > 0.05 * y.size, (ch, value)
        assert usable_masks(rec, [ch])[ch].all()  # the fit keeps the saturated samples


def test_a_sensor_clipped_below_supply_is_still_caught(saturated, tmp_path):
    top = 0.8 * float(saturated.channels["p1"].max())  # a transducer at its range
    path = _write(tmp_path, "clip", saturated, p1=lambda p: np.minimum(p, top))
    issues = check_recordings([read_checked(path)])
    clipped = [i for i in issues if i.code == "clipped"]
    assert [(i.severity, i.channel) for i in clipped] == [("warning", "p1")]
    assert f"maximum {top:g}" in clipped[0].message.replace(".0 ", " ")
    rec = read_checked(path)
    usable = usable_masks(rec, ["p1", "p2"])
    assert not usable["p1"][np.flatnonzero(rec.channels["p1"] == top)[10]]
    assert usable["p2"].all()


@pytest.mark.parametrize(
    "change, rule",
    [
        (lambda p: p - 101325.0, "values below ambient (min -"),  # gauge: goes negative at rest
        (lambda p: np.abs(p - 101325.0), "within 5066.25 Pa of 0 Pa"),  # gauge, rectified
        (lambda p: p / 1e5, "looks like bar (max "),
        (lambda p: p / 1e3, "looks like kPa (max "),
    ],
)
def test_gauge_and_unit_errors_name_the_channel_value_and_rule(sub_ambient, tmp_path, change, rule):
    path = _write(tmp_path, "bad", sub_ambient, p2=change)
    with pytest.raises(BadDataError) as info:
        check_recordings([read_checked(path)])
    (issue,) = info.value.issues
    assert (issue.severity, issue.code, issue.channel) == ("error", "units", "p2")
    assert rule in issue.message


def test_a_median_far_below_ambient_is_gauge_data(sub_ambient, tmp_path):
    # positive, never near 0 Pa, but an absolute chamber pressure does not spend most of a
    # recording below half of ambient (its median here: about 43 kPa)
    path = _write(tmp_path, "gauge", sub_ambient, p1=lambda p: 0.05 * (p - p.min()) + 2e4)
    with pytest.raises(BadDataError) as info:
        check_recordings([read_checked(path)])
    (issue,) = info.value.issues
    assert (issue.code, issue.channel) == ("units", "p1")
    assert "median" in issue.message and "below 0.5 x ambient (101325 Pa)" in issue.message
