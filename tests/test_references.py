"""Tests of pneumatic_env.references (seeded reference generators)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_error_names
from pneumatic_env.references import (
    REFERENCE_KINDS,
    ArrayReference,
    ChirpReference,
    MixtureReference,
    MultisineReference,
    RandomStepReference,
    SineReference,
    StepReference,
    make_reference,
    reference_preview,
)

DT = 1e-3


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _zero_crossings(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linearly interpolated times of sign changes of y."""
    s = np.signbit(y)
    idx = np.nonzero(s[:-1] != s[1:])[0]
    y0, y1 = y[idx], y[idx + 1]
    return t[idx] + (t[idx + 1] - t[idx]) * y0 / (y0 - y1)


def _freq_in_window(t, y, t_lo, t_hi):
    m = (t >= t_lo) & (t <= t_hi)
    z = _zero_crossings(t[m], y[m])
    assert z.size >= 3
    return 1.0 / (2.0 * np.median(np.diff(z)))


# --------------------------------------------------------------------------- kinds


def test_step():
    ref = StepReference(amplitude=10.0, step_time_s=0.3, offset=2.0).generate(10, 0.1)
    assert ref.dtype == np.float64 and ref.shape == (10,)
    np.testing.assert_array_equal(ref[:3], 2.0)
    np.testing.assert_array_equal(ref[3:], 12.0)
    ref0 = StepReference(amplitude=-5.0).generate(4, DT)
    np.testing.assert_array_equal(ref0, -5.0)


def test_sine_closed_form():
    spec = SineReference(amplitude=20.0, frequency_hz=5.0, offset=3.0, phase_rad=0.4)
    ref = spec.generate(1000, DT, _rng())
    for k in (0, 1, 17, 50, 333, 999):
        t = k * DT
        assert ref[k] == pytest.approx(3.0 + 20.0 * np.sin(2 * np.pi * 5.0 * t + 0.4), abs=1e-12)
    # quarter period (50 ms at 5 Hz) without phase: peak
    ref2 = SineReference(amplitude=20.0, frequency_hz=5.0).generate(100, DT)
    assert ref2[0] == 0.0
    assert ref2[50] == pytest.approx(20.0, abs=1e-12)


@pytest.mark.parametrize("method", ["logarithmic", "linear"])
@pytest.mark.parametrize("f0,f1", [(20.0, 200.0), (150.0, 30.0)])
def test_chirp_instantaneous_frequency(method, f0, f1):
    dt, T = 2e-4, 20.0  # slow sweep: the frequency barely moves within a window
    spec = ChirpReference(amplitude=1.0, f0_hz=f0, f1_hz=f1, duration_s=T, method=method)
    n = int(round(T / dt)) + 1
    y = spec.generate(n, dt)
    t = np.arange(n) * dt
    assert y[0] == pytest.approx(0.0, abs=1e-12)  # sine form: starts at the offset
    assert np.max(np.abs(y)) <= 1.0 + 1e-12
    f_start = _freq_in_window(t, y, 0.0, 0.15)
    f_end = _freq_in_window(t, y, T - 0.1, T)
    assert f_start == pytest.approx(f0, rel=0.05)
    assert f_end == pytest.approx(f1, rel=0.05)


def test_chirp_continues_at_f1_after_duration():
    dt, T = 1e-4, 1.0
    spec = ChirpReference(amplitude=2.0, f0_hz=5.0, f1_hz=40.0, duration_s=T, offset=1.0)
    n = int(round(3 * T / dt))
    y = spec.generate(n, dt)
    t = np.arange(n) * dt
    assert _freq_in_window(t, y - 1.0, T + 0.5, 3 * T) == pytest.approx(40.0, rel=1e-3)
    # phase-continuous across the end of the sweep: no jump bigger than a normal step
    k = int(round(T / dt))
    max_step = 2.0 * 2 * np.pi * 40.0 * dt
    assert np.all(np.abs(np.diff(y[k - 5 : k + 5])) <= max_step * 1.01)


@pytest.mark.parametrize("phases", ["random", "schroeder"])
def test_multisine_peak_and_spectrum(phases):
    n, dt = 1000, DT  # FFT grid: 1 Hz
    freqs = (3.0, 7.0, 20.0, 51.0)
    spec = MultisineReference(amplitude=15.0, frequencies_hz=freqs, offset=4.0, phases=phases)
    y = spec.generate(n, dt, _rng(3))
    assert np.max(np.abs(y - 4.0)) == pytest.approx(15.0, rel=1e-12)
    power = np.abs(np.fft.rfft(y - 4.0)) ** 2
    bins = [int(f) for f in freqs]
    others = np.delete(power, bins)
    assert np.all(power[bins] > 1e-3 * power.sum())
    assert others.sum() < 1e-20 * power.sum() + 1e-18
    # equal amplitudes at the requested bins
    np.testing.assert_allclose(power[bins], power[bins][0], rtol=1e-9)


def test_multisine_is_the_sum_of_sines_with_the_drawn_phases():
    """The generated signal is offset + amplitude / peak * sum_k sin(2 pi f_k t + phi_k),
    phi_k the uniform draws of the rng (written out here term by term)."""
    freqs, n = (0.5, 2.0, 5.0), 2011
    y = MultisineReference(amplitude=0.5, frequencies_hz=freqs, offset=0.1).generate(n, DT, _rng(4))
    phases = _rng(4).uniform(0.0, 2.0 * np.pi, size=len(freqs))
    t = np.arange(n) * DT
    x = sum(np.sin(2.0 * np.pi * f * t + phi) for f, phi in zip(freqs, phases))
    np.testing.assert_allclose(y, 0.1 + 0.5 * x / np.abs(x).max(), rtol=0, atol=1e-13)


def test_multisine_phases_random_vs_schroeder():
    spec = MultisineReference(amplitude=1.0, frequencies_hz=(1.0, 2.0, 3.0))
    a = spec.generate(500, DT, _rng(1))
    b = spec.generate(500, DT, _rng(1))
    c = spec.generate(500, DT, _rng(2))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    schroeder = MultisineReference(
        amplitude=1.0, frequencies_hz=(1.0, 2.0, 3.0), phases="schroeder"
    )
    np.testing.assert_array_equal(
        schroeder.generate(500, DT, _rng(1)), schroeder.generate(500, DT, _rng(2))
    )
    with pytest.raises(TypeError) as exc:
        spec.generate(10, DT, None)
    assert_error_names(exc, ("MultisineReference.generate", "rng"), rule="numpy.random.Generator")


def _segments(y):
    change = np.nonzero(np.diff(y) != 0)[0] + 1
    edges = np.concatenate(([0], change, [y.size]))
    return np.diff(edges)


def test_random_step_bounds_holds_and_seeding():
    spec = RandomStepReference(amplitude=30.0, hold_min_s=0.05, hold_max_s=0.2, offset=10.0)
    y = spec.generate(20000, DT, _rng(7))
    assert y.shape == (20000,) and y.dtype == np.float64
    assert np.all(y >= -20.0) and np.all(y <= 40.0)
    holds = _segments(y)[:-1] * DT  # the last hold is cut by the episode end
    assert holds.size > 50
    assert np.all(holds >= 0.05 - 1e-12) and np.all(holds <= 0.2 + 1e-12)
    assert holds.min() < 0.08 and holds.max() > 0.17  # spread over the range
    assert y.min() < -10.0 and y.max() > 30.0  # levels spread over the range
    np.testing.assert_array_equal(y, spec.generate(20000, DT, _rng(7)))
    assert not np.array_equal(y, spec.generate(20000, DT, _rng(8)))


def test_random_step_fixed_hold():
    spec = RandomStepReference(amplitude=1.0, hold_min_s=0.1, hold_max_s=0.1)
    y = spec.generate(1000, DT, _rng(0))
    np.testing.assert_array_equal(_segments(y), 100)


def test_array_resampling():
    values = np.array([0.0, 1.0, 4.0, 9.0, 16.0])
    spec = ArrayReference(values=values, dt_s=0.01)
    # same dt: exact copy, then hold
    y = spec.generate(8, 0.01)
    np.testing.assert_array_equal(y, [0.0, 1.0, 4.0, 9.0, 16.0, 16.0, 16.0, 16.0])
    # finer dt: exact at the sample points, linear in between, held after the end
    y = spec.generate(30, 0.002)
    np.testing.assert_array_equal(y[::5][:5], values)
    assert y[1] == pytest.approx(0.2)
    assert y[12] == pytest.approx(4.0 + 0.4 * 5.0)
    np.testing.assert_array_equal(y[20:], 16.0)
    # coarser dt: every other sample
    np.testing.assert_array_equal(spec.generate(4, 0.02), [0.0, 4.0, 16.0, 16.0])
    # stored copy is read-only and independent of the caller's array
    values[0] = 99.0
    assert spec.values[0] == 0.0
    with pytest.raises(ValueError):
        spec.values[0] = 1.0


def test_mixture_picks_one_per_episode():
    a = StepReference(amplitude=1.0)
    b = StepReference(amplitude=2.0)
    spec = MixtureReference(choices=(a, b), weights=(1.0, 3.0))
    rng = _rng(0)
    picks = [spec.generate(5, DT, rng)[0] for _ in range(4000)]
    frac_b = np.mean(np.array(picks) == 2.0)
    assert frac_b == pytest.approx(0.75, abs=0.03)
    only_a = MixtureReference(choices=(a, b), weights=(1.0, 0.0))
    assert all(only_a.generate(3, DT, rng)[0] == 1.0 for _ in range(200))
    r1 = MixtureReference(
        choices=(
            {"kind": "random_step", "amplitude": 1.0, "hold_min_s": 0.01, "hold_max_s": 0.02},
            {"kind": "sine", "amplitude": 1.0, "frequency_hz": 2.0},
        )
    )
    np.testing.assert_array_equal(r1.generate(300, DT, _rng(5)), r1.generate(300, DT, _rng(5)))


def test_deterministic_kinds_do_not_consume_rng():
    specs = [
        StepReference(amplitude=1.0, step_time_s=0.01),
        SineReference(amplitude=1.0, frequency_hz=2.0),
        ChirpReference(amplitude=1.0, f0_hz=1.0, f1_hz=10.0, duration_s=0.5),
        MultisineReference(amplitude=1.0, frequencies_hz=(1.0, 2.0), phases="schroeder"),
        ArrayReference(values=np.arange(5.0), dt_s=0.01),
    ]
    for spec in specs:
        rng = _rng(11)
        state = rng.bit_generator.state
        spec.generate(100, DT, rng)
        assert rng.bit_generator.state == state, spec
        assert spec.generate(100, DT, None).shape == (100,)


@pytest.mark.parametrize("kind", sorted(REFERENCE_KINDS))
def test_zero_steps(kind):
    spec = make_reference(_EXAMPLES[kind])
    y = spec.generate(0, DT, _rng())
    assert y.shape == (0,) and y.dtype == np.float64


# --------------------------------------------------------------------------- preview


def test_reference_preview():
    ref = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(reference_preview(ref, 0, 3), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(reference_preview(ref, 2, 4), [3.0, 4.0, 4.0, 4.0])
    np.testing.assert_array_equal(reference_preview(ref, 4, 2), [4.0, 4.0])
    np.testing.assert_array_equal(reference_preview(ref, 10, 2), [4.0, 4.0])
    np.testing.assert_array_equal(reference_preview(ref, -1, 2), [0.0, 1.0])
    assert reference_preview(ref, 1, 0).shape == (0,)
    out = reference_preview(ref, 0, 2)
    out[0] = 99.0
    assert ref[1] == 1.0  # a copy
    with pytest.raises(ValueError) as exc:
        reference_preview(ref, 0, -1)
    assert_error_names(exc, "horizon", -1, "integer >= 0")
    with pytest.raises(ValueError) as exc:
        reference_preview(np.array([]), 0, 2)
    assert_error_names(exc, ("ref", "(0,)"), rule="non-empty 1-D array")


# --------------------------------------------------------------------------- errors


POSITIVE = "finite number > 0"
NON_NEGATIVE = "finite number >= 0"


@pytest.mark.parametrize(
    "make,field,value,rule",
    [
        (
            lambda: SineReference(amplitude=1.0, frequency_hz=-1.0),
            "SineReference.frequency_hz",
            -1.0,
            POSITIVE,
        ),
        (
            lambda: SineReference(amplitude=-2.0, frequency_hz=1.0),
            "SineReference.amplitude",
            -2.0,
            NON_NEGATIVE,
        ),
        (
            lambda: SineReference(amplitude=float("nan"), frequency_hz=1.0),
            "SineReference.amplitude",
            float("nan"),
            NON_NEGATIVE,
        ),
        (
            lambda: StepReference(amplitude=1.0, step_time_s=-0.5),
            "StepReference.step_time_s",
            -0.5,
            NON_NEGATIVE,
        ),
        (lambda: ChirpReference(1.0, 1.0, 10.0, 0.0), "ChirpReference.duration_s", 0.0, POSITIVE),
        (lambda: ChirpReference(1.0, 0.0, 10.0, 1.0), "ChirpReference.f0_hz", 0.0, POSITIVE),
        (
            lambda: ChirpReference(1.0, 1.0, 10.0, 1.0, method="cubic"),
            "ChirpReference.method",
            "cubic",
            ("'logarithmic'", "'linear'"),
        ),
        (
            lambda: MultisineReference(1.0, ()),
            "MultisineReference.frequencies_hz",
            (),
            ("non-empty", "distinct", "finite numbers > 0"),
        ),
        (
            lambda: MultisineReference(1.0, (1.0, -3.0)),
            "MultisineReference.frequencies_hz[1]",
            -3.0,
            POSITIVE,
        ),
        (
            lambda: MultisineReference(1.0, (1.0,), phases="zero"),
            "MultisineReference.phases",
            "zero",
            ("'random'", "'schroeder'"),
        ),
        (
            lambda: RandomStepReference(1.0, 0.2, 0.1),
            "RandomStepReference.hold_max_s",
            0.1,
            "hold_min_s = 0.2",
        ),
        (
            lambda: RandomStepReference(1.0, 0.0, 0.1),
            "RandomStepReference.hold_min_s",
            0.0,
            POSITIVE,
        ),
        (
            lambda: ArrayReference(np.array([]), 0.01),
            "ArrayReference.values",
            np.array([]),
            ("non-empty", "1-D", "finite"),
        ),
        (lambda: ArrayReference(np.ones(3), -1.0), "ArrayReference.dt_s", -1.0, POSITIVE),
        (lambda: MixtureReference(()), "MixtureReference.choices", (), "non-empty"),
        (
            lambda: MixtureReference((StepReference(1.0),), weights=(1.0, 2.0)),
            "MixtureReference.weights",
            (1.0, 2.0),
            ("1 finite numbers >= 0", "one per choice"),
        ),
        (
            lambda: MixtureReference((StepReference(1.0),), weights=(0.0,)),
            "MixtureReference.weights",
            (0.0,),
            "positive sum",
        ),
    ],
)
def test_bad_fields(make, field, value, rule):
    with pytest.raises(ValueError) as exc:
        make()
    assert_error_names(exc, field, value, rule)


def test_error_message_format():
    """A guard of the wording: the whole sentence, shared by every reference spec."""
    with pytest.raises(ValueError) as exc:
        SineReference(amplitude=1.0, frequency_hz=-1.0)
    assert str(exc.value) == (
        "SineReference.frequency_hz = -1.0 is not allowed: must be a finite number > 0"
    )


def test_bad_generate_args():
    spec = SineReference(amplitude=1.0, frequency_hz=1.0)
    with pytest.raises(ValueError) as exc:
        spec.generate(-1, DT)
    assert_error_names(exc, ("SineReference.generate", "n_steps"), -1, "integer >= 0")
    with pytest.raises(ValueError) as exc:
        spec.generate(10, 0.0)
    assert_error_names(exc, ("SineReference.generate", "dt_s"), 0.0, POSITIVE)


def test_make_reference_errors():
    with pytest.raises(ValueError) as exc:
        make_reference({"kind": "square", "amplitude": 1.0})
    assert_error_names(exc, "kind", "square", [repr(kind) for kind in REFERENCE_KINDS])
    with pytest.raises(ValueError) as exc:
        make_reference({"amplitude": 1.0})
    assert_error_names(exc, "'kind'", {"amplitude": 1.0}, [repr(kind) for kind in REFERENCE_KINDS])
    with pytest.raises(ValueError) as exc:
        make_reference({"kind": "sine", "amplitude": 1.0, "freq": 5.0})
    assert_error_names(
        exc,
        ("unknown key", "'sine'"),
        ["freq"],
        "['amplitude', 'frequency_hz', 'offset', 'phase_rad']",
    )
    with pytest.raises(ValueError) as exc:
        make_reference({"kind": "sine", "amplitude": 1.0})
    assert_error_names(
        exc,
        ("missing key", "'sine'"),
        ["frequency_hz"],
        "['amplitude', 'frequency_hz', 'offset', 'phase_rad']",
    )
    with pytest.raises(ValueError) as exc:
        make_reference({"kind": "sine", "amplitude": 1.0, "frequency_hz": -1})
    assert_error_names(exc, "SineReference.frequency_hz", -1, POSITIVE)
    with pytest.raises(TypeError):
        make_reference(["sine"])


# --------------------------------------------------------------------------- round trip

_EXAMPLES = {
    "step": {"kind": "step", "amplitude": 50, "step_time_s": 0.1, "offset": 5},
    "sine": {"kind": "sine", "amplitude": 20, "frequency_hz": 5},
    "chirp": {
        "kind": "chirp",
        "amplitude": 10,
        "f0_hz": 1,
        "f1_hz": 30,
        "duration_s": 2,
        "method": "linear",
    },
    "multisine": {
        "kind": "multisine",
        "amplitude": 10,
        "frequencies_hz": [1, 2.5, 7],
        "phases": "schroeder",
    },
    "random_step": {
        "kind": "random_step",
        "amplitude": 40,
        "hold_min_s": 0.1,
        "hold_max_s": 0.5,
        "offset": 60,
    },
    "array": {"kind": "array", "values": [0.0, 1.0, 0.5], "dt_s": 0.1},
    "mixture": {
        "kind": "mixture",
        "weights": [2, 1],
        "choices": [
            {"kind": "sine", "amplitude": 20, "frequency_hz": 5},
            {"kind": "array", "values": [1.0, 2.0], "dt_s": 0.01},
        ],
    },
}


def test_examples_cover_all_kinds():
    assert set(_EXAMPLES) == set(REFERENCE_KINDS)


@pytest.mark.parametrize("kind", sorted(_EXAMPLES))
def test_make_reference_round_trip(kind):
    spec = make_reference(_EXAMPLES[kind])
    assert isinstance(spec, REFERENCE_KINDS[kind])
    assert spec.kind == kind
    d = spec.to_dict()
    assert d["kind"] == kind
    again = make_reference(d)
    assert again == spec
    assert hash(again) == hash(spec)
    assert make_reference(spec) is spec
    np.testing.assert_array_equal(spec.generate(700, DT, _rng(4)), again.generate(700, DT, _rng(4)))
    # the dict holds plain Python values (YAML / JSON friendly)
    import json

    assert json.loads(json.dumps(d)) == d


def test_make_reference_sine_values():
    spec = make_reference({"kind": "sine", "amplitude": 20, "frequency_hz": 5})
    assert spec == SineReference(amplitude=20.0, frequency_hz=5.0)
    assert isinstance(spec.amplitude, float)
    assert (
        make_reference(
            {"kind": "Random-Step", "amplitude": 1, "hold_min_s": 0.1, "hold_max_s": 0.2}
        ).kind
        == "random_step"
    )


_RANDOM_MIXTURE = {
    "kind": "mixture",
    "weights": [2, 1, 1],
    "choices": [
        {"kind": "multisine", "amplitude": 3, "frequencies_hz": [1, 4, 9]},
        {"kind": "random_step", "amplitude": 2, "hold_min_s": 0.05, "hold_max_s": 0.2},
        {"kind": "multisine", "amplitude": 1, "frequencies_hz": [2, 5], "phases": "schroeder"},
    ],
}


@pytest.mark.parametrize("kind", sorted(_EXAMPLES) + ["random mixture"])
def test_generate_rows_equals_one_generate_per_generator(kind):
    """Row i of a batch is the episode ``generate`` draws from generator i, bit for bit, and
    each generator is left where ``generate`` leaves it (vector env = single envs)."""
    spec = make_reference(_RANDOM_MIXTURE if kind == "random mixture" else _EXAMPLES[kind])
    seeds = range(40)
    batch_rngs = [_rng(s) for s in seeds]
    rows = spec.generate_rows(1201, DT, batch_rngs)
    assert rows.shape == (40, 1201)
    for s, rng in zip(seeds, batch_rngs):
        one = _rng(s)
        np.testing.assert_array_equal(rows[s], spec.generate(1201, DT, one))
        assert rng.random() == one.random()
    if kind == "random mixture":  # every choice was picked
        assert {spec.pick(_rng(s)) for s in seeds} == {0, 1, 2}
    assert spec.generate_rows(1201, DT, []).shape == (0, 1201)
