"""The sensors' noise estimated from the recordings (identification/noise.py), reported in
diagnosis.json and given to the fitted rig's env (agents/rig.py).

The test signals are written here (sines, steps, ramps and Gaussian noise of a known
standard deviation), and the virtual rig's noise comes from its own config
(``virtual_rig.noise``), not from the estimator."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from pneumatic_env.identification.checks import read_checked
from pneumatic_env.identification.config import load_config
from pneumatic_env.identification.diagnose import diagnose
from pneumatic_env.identification.noise import noise_std, sensor_noise
from pneumatic_env.identification.report import write_report
from pneumatic_env.studies.virtual_rig import make_recording

SEEDS = (1, 2, 3, 4, 5)


def _pressure_like(rng, n=3000, dt=1e-3) -> np.ndarray:
    """A pressure-like signal (Pa): steps every 0.3 s filtered by a 15 ms lag, plus a
    multisine of 0.5-30 Hz."""
    t = np.arange(n) * dt
    levels = rng.uniform(1.5e5, 6e5, size=n // 300 + 1)[np.arange(n) // 300]
    y = np.empty(n)
    y[0] = levels[0]
    for k in range(1, n):
        y[k] = y[k - 1] + dt / 0.015 * (levels[k] - y[k - 1])
    for f in (0.5, 3.0, 11.0, 30.0):
        y += 2e4 / (1 + f / 5) * np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3))
    return y


@pytest.mark.parametrize("sigma", [300.0, 1000.0, 3000.0])
def test_the_white_noise_of_a_smooth_signal_with_corners_is_found(sigma):
    """Within 10 % of the noise's standard deviation on every seed."""
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        y = _pressure_like(rng) + rng.normal(0.0, sigma, 3000)
        assert noise_std(y) == pytest.approx(sigma, rel=0.10), seed


def test_an_adc_step_counts_as_noise_and_a_noiseless_signal_has_almost_none():
    """Quantised by q: q / sqrt(12) more noise in quadrature (within 10 %). With no noise
    the estimate is the signal's own third derivative: the 30 Hz sine's third difference
    is 2857 Pa (2 pi 30 Hz 1 ms)^3 = 19 Pa peak, about 3 Pa as a standard deviation over
    sqrt(20); under 5 % of a 1 kPa noise (0.1 % of it in quadrature)."""
    q = 250.0
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        clean = _pressure_like(rng)
        noisy = np.round((clean + rng.normal(0.0, 1000.0, clean.size)) / q) * q
        expected = np.hypot(1000.0, q / np.sqrt(12.0))
        assert noise_std(noisy) == pytest.approx(expected, rel=0.10), seed
        assert noise_std(clean) < 50.0, seed


@pytest.mark.parametrize("y", [np.zeros(5), np.zeros((30, 2)), np.r_[np.zeros(30), np.nan]])
def test_a_signal_it_cannot_read_is_refused_by_name(y):
    with pytest.raises(ValueError, match="noise_std: y has"):
        noise_std(y)


def test_the_report_states_the_virtual_rigs_sensor_noise_and_the_fitted_rig_has_it(tmp_path):
    """diagnosis.json's ``sensor_noise`` on a clamped and a spring-rod recording of the
    virtual rig: each channel within 15 % of the rig's noise and quantisation
    (``virtual_rig``), the position from the spring rod alone; ``load_rig`` gives the env
    that noise, and the measured p1 of 256 envs at one state spreads by it."""
    from pneumatic_env.agents.rig import load_rig

    rig_cfg = load_config().raw["virtual_rig"]
    paths = [
        make_recording(tmp_path, name=piston, effect="none", seed=2, piston=piston)
        for piston in ("fixed", "spring")
    ]
    recordings = [read_checked(p) for p in paths]
    found = sensor_noise(recordings)
    assert set(found) == {"p1", "p2", "x", "f"}
    for channel, value in found.items():
        sigma = rig_cfg["noise"][channel]["value"]
        q = rig_cfg["quantisation"][channel]["value"]
        assert value == pytest.approx(np.hypot(sigma, q / np.sqrt(12.0)), rel=0.15), channel

    diag = diagnose(recordings, candidates=["leakage"], max_effects=1)
    data = write_report(diag, tmp_path / "report", plots=False)
    assert data["sensor_noise"] == found
    assert json.loads((tmp_path / "report" / "diagnosis.json").read_text())["sensor_noise"]
    assert f"p1 {found['p1']:.3g}" in (tmp_path / "report" / "report.md").read_text()
    rig = load_rig(tmp_path / "report")
    assert rig.env_options["sensor_noise"] == found
    env = gym.make_vec(rig.env_id, num_envs=256, normalize_observation=False, **rig.env_options)
    obs, _ = env.reset(seed=1)
    assert np.std(obs[:, 0]) == pytest.approx(found["p1"], rel=0.15)
    env.close()
