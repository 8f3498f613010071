"""Seeded reference (target force / target position) generators.

Every reference kind is a small frozen dataclass ("spec") that validates its fields on
construction and produces a sample sequence with::

    spec.generate(n_steps, dt_s, rng) -> np.ndarray   # float64, shape (n_steps,)

and one episode per generator with ``spec.generate_rows(n_steps, dt_s, rngs)`` (shape
``(len(rngs), n_steps)``; row ``i`` equals ``generate(n_steps, dt_s, rngs[i])`` bit for
bit, so a vector env's episodes are those of single envs with the same generators).

Sample ``k`` belongs to the time ``t_k = k * dt_s``. The output is a deterministic
function of ``(spec, n_steps, dt_s)`` and the state of ``rng``. Kinds without
randomness (step, sine, chirp, array, multisine with Schroeder phases) draw nothing from
``rng`` and accept ``rng=None``; random kinds (multisine with random phases,
random_step, mixture) require a ``numpy.random.Generator``.

Specs are built directly or from plain dicts (YAML / JSON configs) with
:func:`make_reference`; ``spec.to_dict()`` gives the dict back, so
``make_reference(spec.to_dict()) == spec``.

Kinds (``kind`` key in dicts):

* ``step``        -- :class:`StepReference`
* ``sine``        -- :class:`SineReference`
* ``chirp``       -- :class:`ChirpReference`
* ``multisine``   -- :class:`MultisineReference`
* ``random_step`` -- :class:`RandomStepReference`
* ``array``       -- :class:`ArrayReference`
* ``mixture``     -- :class:`MixtureReference`

Units are whatever the task uses (N for force, m for position); times are in s,
frequencies in Hz. Pure numpy (scipy is used for the chirp when available).
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

try:  # scipy is optional; the closed form below is used without it
    from scipy.signal import chirp as _scipy_chirp
except ImportError:  # pragma: no cover - scipy is installed in the dev env
    _scipy_chirp = None

__all__ = [
    "ReferenceSpec",
    "StepReference",
    "SineReference",
    "ChirpReference",
    "MultisineReference",
    "RandomStepReference",
    "ArrayReference",
    "MixtureReference",
    "REFERENCE_KINDS",
    "make_reference",
    "reference_preview",
]


# --------------------------------------------------------------------------- helpers


def _fail(owner: str, name: str, value: Any, rule: str) -> ValueError:
    return ValueError(f"{owner}.{name} = {value!r} is not allowed: {rule}")


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _real(
    owner: str, name: str, value: Any, *, gt: float | None = None, ge: float | None = None
) -> float:
    """Validate a finite real number (optionally with a lower bound) and return a float."""
    if gt is not None:
        rule = f"must be a finite number > {gt:g}"
    elif ge is not None:
        rule = f"must be a finite number >= {ge:g}"
    else:
        rule = "must be a finite number"
    if not _is_real(value) or not math.isfinite(float(value)):
        raise _fail(owner, name, value, rule)
    x = float(value)
    if (gt is not None and not x > gt) or (ge is not None and not x >= ge):
        raise _fail(owner, name, value, rule)
    return x


def _set(obj: Any, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)  # frozen dataclasses


def _check_generate_args(owner: str, n_steps: Any, dt_s: Any) -> tuple[int, float]:
    if (
        type(n_steps) is int and type(dt_s) is float and n_steps >= 0 and 0.0 < dt_s < math.inf
    ):  # the common case, without the ABC checks below
        return n_steps, dt_s
    if (
        not isinstance(n_steps, numbers.Integral)
        or isinstance(n_steps, (bool, np.bool_))
        or n_steps < 0
    ):
        raise ValueError(
            f"{owner}.generate: n_steps = {n_steps!r} is not allowed: must be an integer >= 0"
        )
    if not _is_real(dt_s) or not math.isfinite(float(dt_s)) or not float(dt_s) > 0:
        raise ValueError(
            f"{owner}.generate: dt_s = {dt_s!r} is not allowed: must be a finite number > 0"
        )
    return int(n_steps), float(dt_s)


def _require_rng(owner: str, rng: Any) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"{owner}.generate needs rng to be a numpy.random.Generator "
            f"(this kind is random), got {type(rng).__name__}"
        )
    return rng


def _time(n_steps: int, dt_s: float) -> np.ndarray:
    return np.arange(n_steps, dtype=np.float64) * dt_s


@functools.lru_cache(maxsize=16)
def _sine_basis(frequencies_hz: tuple, n_steps: int, dt_s: float) -> tuple:
    """sin and cos of 2 pi f t_k (read-only, shape (n_steps, len(frequencies_hz)))."""
    omega_t = 2.0 * np.pi * _time(n_steps, dt_s)[:, None] * np.asarray(frequencies_hz)[None, :]
    basis = np.sin(omega_t), np.cos(omega_t)
    for b in basis:
        b.setflags(write=False)
    return basis


def _plain(value: Any) -> Any:
    """Field value -> plain Python (lists, floats, dicts) for ``to_dict``."""
    if isinstance(value, ReferenceSpec):
        return value.to_dict()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


# --------------------------------------------------------------------------- base


class ReferenceSpec:
    """Base class of all reference specs (frozen dataclasses)."""

    kind: ClassVar[str] = ""
    #: True if ``generate`` draws from the rng.
    is_random: ClassVar[bool] = False

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        raise NotImplementedError

    def generate_rows(self, n_steps: int, dt_s: float, rngs) -> np.ndarray:
        """One episode per generator in ``rngs``: shape ``(len(rngs), n_steps)``, row ``i``
        equal to ``generate(n_steps, dt_s, rngs[i])``. Kinds with a faster batch form
        override it."""
        n_steps, dt_s = _check_generate_args(type(self).__name__, n_steps, dt_s)
        out = np.empty((len(rngs), n_steps))
        if not self.is_random and len(rngs):
            out[:] = self.generate(n_steps, dt_s, None)
            return out
        for i, rng in enumerate(rngs):
            out[i] = self.generate(n_steps, dt_s, rng)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain dict with a ``kind`` key; ``make_reference(spec.to_dict()) == spec``."""
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            out[f.name] = _plain(getattr(self, f.name))
        return out


# --------------------------------------------------------------------------- kinds


@dataclass(frozen=True)
class StepReference(ReferenceSpec):
    """``offset`` before ``step_time_s``, ``offset + amplitude`` from then on.

    ``amplitude`` may be negative (step down). The step happens at the first sample
    with ``t_k >= step_time_s``.
    """

    amplitude: float
    step_time_s: float = 0.0
    offset: float = 0.0

    kind: ClassVar[str] = "step"

    def __post_init__(self) -> None:
        o = type(self).__name__
        _set(self, "amplitude", _real(o, "amplitude", self.amplitude))
        _set(self, "step_time_s", _real(o, "step_time_s", self.step_time_s, ge=0.0))
        _set(self, "offset", _real(o, "offset", self.offset))

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        n, dt = _check_generate_args(type(self).__name__, n_steps, dt_s)
        # index of the step; the tolerance keeps e.g. 0.3 / 0.1 from landing on 3 + eps
        k_step = max(0, math.ceil(self.step_time_s / dt - 1e-9))
        out = np.full(n, self.offset, dtype=np.float64)
        out[k_step:] += self.amplitude
        return out


@dataclass(frozen=True)
class SineReference(ReferenceSpec):
    """``offset + amplitude * sin(2 pi frequency_hz t + phase_rad)``."""

    amplitude: float
    frequency_hz: float
    offset: float = 0.0
    phase_rad: float = 0.0

    kind: ClassVar[str] = "sine"

    def __post_init__(self) -> None:
        o = type(self).__name__
        _set(self, "amplitude", _real(o, "amplitude", self.amplitude, ge=0.0))
        _set(self, "frequency_hz", _real(o, "frequency_hz", self.frequency_hz, gt=0.0))
        _set(self, "offset", _real(o, "offset", self.offset))
        _set(self, "phase_rad", _real(o, "phase_rad", self.phase_rad))

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        n, dt = _check_generate_args(type(self).__name__, n_steps, dt_s)
        t = _time(n, dt)
        return self.offset + self.amplitude * np.sin(
            2.0 * np.pi * self.frequency_hz * t + self.phase_rad
        )


_CHIRP_METHODS = ("logarithmic", "linear")


def _chirp_phase(
    t: np.ndarray | float, f0: float, f1: float, t1: float, method: str
) -> np.ndarray | float:
    """Phase (rad) of a sweep from f0 at t=0 to f1 at t1 (same as scipy.signal.chirp)."""
    if method == "linear":
        return 2.0 * np.pi * (f0 * t + 0.5 * (f1 - f0) / t1 * t * t)
    if f0 == f1:
        return 2.0 * np.pi * f0 * t
    beta = f1 / f0
    return 2.0 * np.pi * f0 * t1 / np.log(beta) * (np.power(beta, t / t1) - 1.0)


@dataclass(frozen=True)
class ChirpReference(ReferenceSpec):
    """Frequency sweep ``offset + amplitude * sin(phase(t))`` from ``f0_hz`` to ``f1_hz``.

    The instantaneous frequency goes from ``f0_hz`` at t = 0 to ``f1_hz`` at
    ``t = duration_s``, linearly or geometrically (``method="logarithmic"``, the
    default). The signal starts at ``offset`` (sine form, i.e. ``scipy.signal.chirp``
    with ``phi=-90``). After ``duration_s`` it continues at the constant frequency
    ``f1_hz`` with a continuous phase. Down-sweeps (``f1_hz < f0_hz``) are allowed.
    """

    amplitude: float
    f0_hz: float
    f1_hz: float
    duration_s: float
    offset: float = 0.0
    method: str = "logarithmic"

    kind: ClassVar[str] = "chirp"

    def __post_init__(self) -> None:
        o = type(self).__name__
        _set(self, "amplitude", _real(o, "amplitude", self.amplitude, ge=0.0))
        _set(self, "f0_hz", _real(o, "f0_hz", self.f0_hz, gt=0.0))
        _set(self, "f1_hz", _real(o, "f1_hz", self.f1_hz, gt=0.0))
        _set(self, "duration_s", _real(o, "duration_s", self.duration_s, gt=0.0))
        _set(self, "offset", _real(o, "offset", self.offset))
        if self.method not in _CHIRP_METHODS:
            raise _fail(o, "method", self.method, f"must be one of {list(_CHIRP_METHODS)}")

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        n, dt = _check_generate_args(type(self).__name__, n_steps, dt_s)
        t = _time(n, dt)
        T = self.duration_s
        unit = np.empty(n, dtype=np.float64)
        inside = t <= T
        if _scipy_chirp is not None:
            unit[inside] = _scipy_chirp(
                t[inside], f0=self.f0_hz, t1=T, f1=self.f1_hz, method=self.method, phi=-90.0
            )
        else:  # pragma: no cover
            unit[inside] = np.sin(_chirp_phase(t[inside], self.f0_hz, self.f1_hz, T, self.method))
        phase_end = float(_chirp_phase(T, self.f0_hz, self.f1_hz, T, self.method))
        after = ~inside
        unit[after] = np.sin(phase_end + 2.0 * np.pi * self.f1_hz * (t[after] - T))
        return self.offset + self.amplitude * unit


_MULTISINE_PHASES = ("random", "schroeder")


@dataclass(frozen=True)
class MultisineReference(ReferenceSpec):
    """Sum of sines at ``frequencies_hz``, scaled so ``max |ref - offset| == amplitude``.

    ``phases="random"`` (default) draws one phase per frequency uniformly in
    [0, 2 pi) from the rng; ``phases="schroeder"`` uses the low-crest-factor Schroeder
    phases ``phi_k = -pi k (k - 1) / K`` (k = 1..K) and draws nothing. The peak is taken
    over the generated samples, so the scale depends on ``n_steps`` and ``dt_s``.
    For a clean spectrum choose frequencies on the FFT grid ``m / (n_steps * dt_s)``
    and below the Nyquist frequency ``0.5 / dt_s``.
    """

    amplitude: float
    frequencies_hz: tuple
    offset: float = 0.0
    phases: str = "random"

    kind: ClassVar[str] = "multisine"

    def __post_init__(self) -> None:
        o = type(self).__name__
        _set(self, "amplitude", _real(o, "amplitude", self.amplitude, ge=0.0))
        freqs = self.frequencies_hz
        if _is_real(freqs):
            freqs = (freqs,)
        if isinstance(freqs, np.ndarray):
            freqs = freqs.tolist()
        rule = "must be a non-empty sequence of distinct finite numbers > 0"
        if not isinstance(freqs, (tuple, list)) or len(freqs) == 0:
            raise _fail(o, "frequencies_hz", self.frequencies_hz, rule)
        out = []
        for i, f in enumerate(freqs):
            if not _is_real(f) or not math.isfinite(float(f)) or not float(f) > 0:
                raise _fail(o, f"frequencies_hz[{i}]", f, "must be a finite number > 0")
            out.append(float(f))
        if len(set(out)) != len(out):
            raise _fail(o, "frequencies_hz", self.frequencies_hz, rule)
        _set(self, "frequencies_hz", tuple(out))
        _set(self, "offset", _real(o, "offset", self.offset))
        if self.phases not in _MULTISINE_PHASES:
            raise _fail(o, "phases", self.phases, f"must be one of {list(_MULTISINE_PHASES)}")

    @property
    def is_random(self) -> bool:  # type: ignore[override]
        return self.phases == "random"

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        return self.generate_rows(n_steps, dt_s, [rng])[0]

    def generate_rows(self, n_steps: int, dt_s: float, rngs) -> np.ndarray:
        owner = type(self).__name__
        n, dt = _check_generate_args(owner, n_steps, dt_s)
        n_f = len(self.frequencies_hz)
        # sin(w t + phi) = sin(w t) cos(phi) + cos(w t) sin(phi): the basis is computed
        # once, an episode costs two matrix-vector products, row by row (BLAS may sum
        # a matrix product's columns in another order); the scaling is elementwise, so
        # done for all rows at once
        sin_wt, cos_wt = _sine_basis(self.frequencies_hz, n, dt)
        if self.phases == "schroeder":
            k = np.arange(1, n_f + 1, dtype=np.float64)
            schroeder = -np.pi * k * (k - 1.0) / n_f
        out = np.empty((len(rngs), n))
        cos_part = np.empty(n)
        for i, rng in enumerate(rngs):
            phi = (
                _require_rng(owner, rng).uniform(0.0, 2.0 * np.pi, size=n_f)
                if self.phases == "random"
                else schroeder
            )
            np.matmul(sin_wt, np.cos(phi), out=out[i])
            out[i] += np.matmul(cos_wt, np.sin(phi), out=cos_part)
        peak = np.max(np.abs(out), axis=1) if n else np.zeros(len(rngs))
        flat = peak == 0.0
        out *= (self.amplitude / np.where(flat, 1.0, peak))[:, None]
        out[flat] = 0.0
        out += self.offset
        return out


@dataclass(frozen=True)
class RandomStepReference(ReferenceSpec):
    """Piecewise constant levels, uniform in ``[offset - amplitude, offset + amplitude]``.

    Each level is held for a whole number of samples drawn uniformly from
    ``[ceil(hold_min_s / dt), floor(hold_max_s / dt)]`` (at least 1 sample), so every
    hold lasts between ``hold_min_s`` and ``hold_max_s`` whenever the sample grid
    allows it. The last hold is cut off by the end of the episode.
    """

    amplitude: float
    hold_min_s: float
    hold_max_s: float
    offset: float = 0.0

    kind: ClassVar[str] = "random_step"
    is_random: ClassVar[bool] = True

    def __post_init__(self) -> None:
        o = type(self).__name__
        _set(self, "amplitude", _real(o, "amplitude", self.amplitude, ge=0.0))
        _set(self, "hold_min_s", _real(o, "hold_min_s", self.hold_min_s, gt=0.0))
        hold_max = _real(o, "hold_max_s", self.hold_max_s, gt=0.0)
        if hold_max < self.hold_min_s:
            raise _fail(
                o, "hold_max_s", self.hold_max_s, f"must be >= hold_min_s = {self.hold_min_s!r}"
            )
        _set(self, "hold_max_s", hold_max)
        _set(self, "offset", _real(o, "offset", self.offset))

    def hold_range_steps(self, dt_s: float) -> tuple[int, int]:
        """Inclusive range of hold lengths in samples for the step ``dt_s``."""
        lo = max(1, math.ceil(self.hold_min_s / dt_s - 1e-9))
        hi = max(lo, math.floor(self.hold_max_s / dt_s + 1e-9))
        return lo, hi

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        owner = type(self).__name__
        n, dt = _check_generate_args(owner, n_steps, dt_s)
        rng = _require_rng(owner, rng)
        lo, hi = self.hold_range_steps(dt)
        n_seg = n // lo + 1  # enough segments to cover n samples even if all are short
        holds = rng.integers(lo, hi + 1, size=n_seg)
        levels = rng.uniform(self.offset - self.amplitude, self.offset + self.amplitude, size=n_seg)
        return np.repeat(levels, holds)[:n].astype(np.float64, copy=False)


@dataclass(frozen=True, eq=False)
class ArrayReference(ReferenceSpec):
    """User-given samples ``values`` spaced ``dt_s`` apart (first sample at t = 0).

    Resampled to the env's step by linear interpolation (exact at coinciding sample
    times) and held at the last value after the end. ``values`` is stored as a
    read-only float64 copy.
    """

    values: np.ndarray
    dt_s: float

    kind: ClassVar[str] = "array"

    def __post_init__(self) -> None:
        o = type(self).__name__
        try:
            arr = np.array(self.values, dtype=np.float64)
        except (TypeError, ValueError):
            raise _fail(
                o, "values", self.values, "must be a non-empty 1-D array of finite numbers"
            ) from None
        if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
            raise _fail(o, "values", self.values, "must be a non-empty 1-D array of finite numbers")
        arr.setflags(write=False)
        _set(self, "values", arr)
        _set(self, "dt_s", _real(o, "dt_s", self.dt_s, gt=0.0))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ArrayReference):
            return NotImplemented
        return self.dt_s == other.dt_s and np.array_equal(self.values, other.values)

    def __hash__(self) -> int:
        return hash((self.values.tobytes(), self.dt_s))

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        n, dt = _check_generate_args(type(self).__name__, n_steps, dt_s)
        # positions in units of source samples; snap near-integers so coinciding
        # sample times reproduce the given values exactly
        pos = np.arange(n, dtype=np.float64) * (dt / self.dt_s)
        nearest = np.rint(pos)
        snap = np.abs(pos - nearest) <= 1e-9 * np.maximum(1.0, nearest)
        pos[snap] = nearest[snap]
        src = np.arange(self.values.size, dtype=np.float64)
        return np.interp(pos, src, self.values)  # holds the last value past the end


@dataclass(frozen=True)
class MixtureReference(ReferenceSpec):
    """Pick one of ``choices`` per episode (``weights`` or uniform), then generate it.

    ``choices`` may hold specs or dicts (built with :func:`make_reference`). Exactly
    one uniform draw selects the choice; the chosen spec then draws what it needs.
    """

    choices: tuple
    weights: tuple | None = None

    kind: ClassVar[str] = "mixture"
    is_random: ClassVar[bool] = True

    def __post_init__(self) -> None:
        o = type(self).__name__
        choices = self.choices
        if isinstance(choices, (ReferenceSpec, Mapping)):
            choices = (choices,)
        if not isinstance(choices, (tuple, list)) or len(choices) == 0:
            raise _fail(
                o,
                "choices",
                self.choices,
                "must be a non-empty sequence of reference specs or dicts",
            )
        built = []
        for i, c in enumerate(choices):
            if not isinstance(c, (ReferenceSpec, Mapping)):
                raise _fail(o, f"choices[{i}]", c, "must be a reference spec or a dict")
            built.append(make_reference(c))
        _set(self, "choices", tuple(built))
        if self.weights is not None:
            w = self.weights
            if isinstance(w, np.ndarray):
                w = w.tolist()
            rule = (
                f"must be None or {len(built)} finite numbers >= 0 "
                "(one per choice) with a positive sum"
            )
            if not isinstance(w, (tuple, list)) or len(w) != len(built):
                raise _fail(o, "weights", self.weights, rule)
            if (
                not all(_is_real(x) and math.isfinite(float(x)) and float(x) >= 0 for x in w)
                or sum(float(x) for x in w) <= 0
            ):
                raise _fail(o, "weights", self.weights, rule)
            _set(self, "weights", tuple(float(x) for x in w))

    def probabilities(self) -> np.ndarray:
        if self.weights is None:
            return np.full(len(self.choices), 1.0 / len(self.choices))
        w = np.asarray(self.weights, dtype=np.float64)
        return w / w.sum()

    def pick(self, rng: np.random.Generator) -> int:
        """Index of the choice for one episode (one uniform draw from ``rng``)."""
        rng = _require_rng(type(self).__name__, rng)
        p, cdf = self._cdf
        idx = bisect.bisect_right(cdf, rng.random() * cdf[-1])
        idx = min(idx, len(self.choices) - 1)
        while p[idx] == 0.0:  # rounding edge case: never pick a zero-weight choice
            idx -= 1
        return idx

    @functools.cached_property
    def _cdf(self) -> tuple:
        """The probabilities and their cumulative sums, as floats (``pick`` runs per episode)."""
        p = self.probabilities()
        return p.tolist(), np.cumsum(p).tolist()

    def generate(
        self, n_steps: int, dt_s: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        return self.generate_rows(n_steps, dt_s, [rng])[0]

    def generate_rows(self, n_steps: int, dt_s: float, rngs) -> np.ndarray:
        """Each generator picks its choice; the rows of one choice are generated together."""
        n, dt = _check_generate_args(type(self).__name__, n_steps, dt_s)
        picks = np.array([self.pick(rng) for rng in rngs], dtype=np.int64)
        out = np.empty((len(rngs), n))
        for idx in np.unique(picks):
            rows = np.flatnonzero(picks == idx)
            out[rows] = self.choices[idx].generate_rows(n, dt, [rngs[r] for r in rows])
        return out


# --------------------------------------------------------------------------- factory

REFERENCE_KINDS: dict[str, type[ReferenceSpec]] = {
    cls.kind: cls
    for cls in (
        StepReference,
        SineReference,
        ChirpReference,
        MultisineReference,
        RandomStepReference,
        ArrayReference,
        MixtureReference,
    )
}


def make_reference(spec_or_dict: ReferenceSpec | Mapping[str, Any]) -> ReferenceSpec:
    """Return a reference spec from a spec (returned as is) or a dict with a ``kind``.

    Example: ``make_reference({"kind": "sine", "amplitude": 20, "frequency_hz": 5})``.
    Unknown kinds and unknown or missing keys raise ``ValueError`` naming them.
    """
    if isinstance(spec_or_dict, ReferenceSpec):
        return spec_or_dict
    known = sorted(REFERENCE_KINDS)
    if not isinstance(spec_or_dict, Mapping):
        raise TypeError(
            "make_reference expects a reference spec or a dict with a 'kind' "
            f"key, got {type(spec_or_dict).__name__}"
        )
    d = dict(spec_or_dict)
    if "kind" not in d:
        raise ValueError(f"reference dict {spec_or_dict!r} has no 'kind' key; known kinds: {known}")
    kind_raw = d.pop("kind")
    kind = str(kind_raw).strip().lower().replace("-", "_")
    if kind not in REFERENCE_KINDS:
        raise ValueError(f"unknown reference kind {kind_raw!r}; known kinds: {known}")
    cls = REFERENCE_KINDS[kind]
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]
    names = [f.name for f in fields]
    unknown = sorted(k for k in d if k not in names)
    if unknown:
        raise ValueError(
            f"unknown key(s) {unknown} for reference kind {kind!r} "
            f"({cls.__name__}); allowed keys: {names}"
        )
    missing = [
        f.name
        for f in fields
        if f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
        and f.name not in d
    ]
    if missing:
        raise ValueError(
            f"missing key(s) {missing} for reference kind {kind!r} "
            f"({cls.__name__}); allowed keys: {names}"
        )
    if kind == "multisine" and isinstance(d.get("frequencies_hz"), list):
        d["frequencies_hz"] = tuple(d["frequencies_hz"])
    if kind == "mixture":
        if isinstance(d.get("choices"), list):
            d["choices"] = tuple(d["choices"])
        if isinstance(d.get("weights"), list):
            d["weights"] = tuple(d["weights"])
    return cls(**d)


# --------------------------------------------------------------------------- preview


def reference_preview(ref: np.ndarray, k: int, horizon: int) -> np.ndarray:
    """The ``horizon`` samples after step ``k``: ``ref[k+1 : k+1+horizon]``.

    Padded at the end with the last value of ``ref`` when it runs out. ``k = -1``
    gives the first ``horizon`` samples. Returns a new float64 array of shape
    ``(horizon,)``.
    """
    ref = np.asarray(ref, dtype=np.float64)
    if ref.ndim != 1 or ref.size == 0:
        raise ValueError(
            f"reference_preview: ref must be a non-empty 1-D array, got shape {ref.shape}"
        )
    if not isinstance(k, numbers.Integral) or isinstance(k, (bool, np.bool_)) or k < -1:
        raise ValueError(f"reference_preview: k = {k!r} is not allowed: must be an integer >= -1")
    if (
        not isinstance(horizon, numbers.Integral)
        or isinstance(horizon, (bool, np.bool_))
        or horizon < 0
    ):
        raise ValueError(
            f"reference_preview: horizon = {horizon!r} is not allowed: must be an integer >= 0"
        )
    start = int(k) + 1
    out = np.full(int(horizon), ref[-1], dtype=np.float64)
    chunk = ref[start : start + int(horizon)]
    out[: chunk.size] = chunk
    return out
