"""A fitted rig as an environment: what ``pneumatic-env identify --report DIR`` found, read
back for training and benchmarking (``train --rig``, ``bench --rig``).

A report directory holds ``diagnosis.json`` and ``fitted_final.yaml``
(``pneumatic_env.identification.report``). The rig itself (cylinder, tube, supply) is what
the recordings' sidecars state (``diagnosis.json["rigs"]``, one per recording); the model
is the package's defaults for that cylinder, then the sidecars' rig values, then the fitted
values. The env is the benchmark's ForceTrack variant of the cylinder with the tube length
nearest the rig's (it has tuned gains and a trainer config), given the rig's parameters
(``params=``, the tube length among them): a tube length the suite does not have is
simulated at its own length. Its sensors carry the noise the recordings show
(``diagnosis.json["sensor_noise"]``).

:func:`rig_randomization` turns the report's uncertainty into the env's
``domain_randomization``: each identified fitted plant parameter over its confidence
interval, and
each plant effect the report could not rule out (not selected, yet a predicted held-out
improvement of at least the report's ``min_predicted_improvement``) over the strengths from
none to its fitted (or screening) value.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from pneumatic_env import ids
from pneumatic_env import params as P
from pneumatic_env.identification.candidates import candidate_table
from pneumatic_env.recording_format import canonical_cylinder

from .suite import load_suite

__all__ = [
    "RIG_KEYS",
    "FittedRig",
    "load_rig",
    "rig_randomization",
    "nearest_env_id",
]

#: sidecar keys that describe the rig (not one experiment's rod mode or load)
RIG_KEYS = (
    "tube_length_m",
    "tube_inner_diameter_m",
    "supply_pressure_pa",
    "ambient_pressure_pa",
    "temperature_k",
)


def _diagnosis(report_dir: Path) -> dict:
    path = report_dir / "diagnosis.json"
    if not path.is_file():
        raise FileNotFoundError(
            f"{report_dir}: no diagnosis.json: give the directory of "
            "`pneumatic-env identify ... --report DIR`"
        )
    return json.loads(path.read_text(encoding="utf-8"))


def _rig_of(report_dir: Path, diagnosis: dict) -> dict:
    """The one rig the recordings' sidecars state (cylinder and ``RIG_KEYS``)."""
    rigs = diagnosis.get("rigs")
    if not rigs:
        raise ValueError(
            f"{report_dir}/diagnosis.json has no 'rigs' (the recordings' sidecars): "
            "re-run `pneumatic-env identify` with this version of the package"
        )
    found: dict = {}
    for name, rig in rigs.items():
        one: dict = {"cylinder": canonical_cylinder(rig["cylinder"])}
        one.update({k: float(rig[k]) for k in RIG_KEYS if k in rig})
        if found and one != found:
            raise ValueError(
                f"{report_dir}: recording {name!r} states the rig {one}, another {found}: "
                "one report, one rig"
            )
        found = one
    return found


@dataclass(frozen=True)
class FittedRig:
    """The rig of a report: its env id and the model parameters the env is given."""

    report_dir: Path
    cylinder: str  # config id
    env_id: str  # the registered ForceTrack id nearest the rig
    stated: dict  # what the sidecars state (``RIG_KEYS``, SI)
    params: dict  # the fitted values over ``stated`` (kernel names, SI)
    #: {channel: std} of the recordings' sensor noise (``diagnosis.json["sensor_noise"]``,
    #: ``pneumatic_env.identification.noise``); empty for a report without it
    sensor_noise: dict = field(default_factory=dict)

    @property
    def variant(self) -> str:
        """``Numatics-2m``: the registered variant nearest the rig."""
        return ids.parse_env_id(self.env_id).variant

    @property
    def env_options(self) -> dict:
        """``gym.make(env_id, **env_options)``: the fitted rig (tube length included), its
        sensors as noisy as the recordings'."""
        out = {"params": dict(self.params), "tube_length_m": self.params["tube_length_m"]}
        if self.sensor_noise:
            out["sensor_noise"] = dict(self.sensor_noise)
        return out

    @property
    def noiseless_env_options(self) -> dict:
        """``env_options`` with exact sensors: the rig the classical gains are searched on
        (``agents.rig_base.retuned_gains``; the grid's chatter penalty,
        ``configs/agents/tuning.yaml: chatter_penalty_pct_per_a``, was set on exact
        sensors, and on noisy ones it picked gains that track worse)."""
        return {k: v for k, v in self.env_options.items() if k != "sensor_noise"}

    def model_parameters(self) -> dict[str, float]:
        """Every kernel parameter of the fitted model (``load_parameters``)."""
        return P.load_parameters(self.cylinder, params=dict(self.params))

    def nominal_parameters(self) -> dict[str, float]:
        """The package's model of the rig before identification: the cylinder's defaults
        with what the sidecars state."""
        return P.load_parameters(self.cylinder, params=dict(self.stated))


def load_rig(report_dir: str | Path) -> FittedRig:
    """The fitted rig of a report directory (``diagnosis.json``, ``fitted_final.yaml``)."""
    report_dir = Path(report_dir)
    diagnosis = _diagnosis(report_dir)
    stated = _rig_of(report_dir, diagnosis)
    final = report_dir / "fitted_final.yaml"
    if not final.is_file():
        raise FileNotFoundError(f"{report_dir}: no fitted_final.yaml")
    cylinder = stated.pop("cylinder")
    stated.setdefault("tube_length_m", P.load_parameters(cylinder)["tube_length_m"])
    fitted = {k: float(v["value"]) for k, v in P.read_yaml(final).items()}
    params = {**stated, **fitted}
    P.load_parameters(cylinder, params=params)  # names and values checked
    env_id = nearest_env_id(cylinder, params["tube_length_m"])
    noise = {k: float(v) for k, v in diagnosis.get("sensor_noise", {}).items()}
    return FittedRig(report_dir, cylinder, env_id, stated, params, noise)


def nearest_env_id(cylinder: str, tube_length_m: float) -> str:
    """The ForceTrack id of the benchmark's variant of ``cylinder`` (those have tuned
    gains and trainer configs) with the tube length nearest ``tube_length_m``."""
    name = ids.cylinder_name(cylinder)
    parts = [ids.split_variant(v) for v in load_suite().variants]
    tubes = [tube for cyl, tube in parts if cyl == name]
    if not tubes:
        raise ValueError(f"cylinder {cylinder!r} has no variant in the benchmark suite")
    key = min(tubes, key=lambda t: abs(ids.TUBE_LENGTHS_M[t] - tube_length_m))
    return ids.env_id(ids.FORCE_TRACK, name, key)


def _valid(cylinder: str, params: dict, name: str, value: float) -> bool:
    try:
        P.load_parameters(cylinder, params={**params, name: value})
    except (ValueError, P.ConfigError):
        return False
    return True


def _interval(rig: FittedRig, name: str, low: float, high: float, value: float):
    """(low, high) with an end that is no valid parameter value replaced by ``value``."""
    ends = [
        v if math.isfinite(v) and _valid(rig.cylinder, rig.params, name, v) else value
        for v in (low, high)
    ]
    return (min(ends), max(ends))


def _unruled_effects(diagnosis: dict) -> dict[str, tuple[float, float]]:
    """Parameter -> (neutral, strength) of each plant effect not selected whose held-out
    improvement (refitted, else the screening's prediction) reaches the report's
    ``min_predicted_improvement``. The neutral value (the effect off) is the candidate
    catalog's (an exhaust discharge ratio of 1, a leak area of 0); a parameter with no
    finite one (a switch, a rigid limit) is not ranged."""
    floor = float(diagnosis["thresholds"]["min_predicted_improvement"])
    catalog = candidate_table()
    out: dict[str, tuple[float, float]] = {}
    for c in diagnosis["candidates"]:
        if c["name"] in diagnosis["selected"] or c["kind"] != "plant":
            continue
        screen = c.get("screening") or {}
        gain = (
            c["relative_improvement"]
            if c["refitted"]
            else screen.get("predicted_heldout_improvement")
        )
        if gain is None or gain < floor:
            continue
        if c["name"] not in catalog:
            raise ValueError(
                f"report candidate {c['name']!r} is not in the candidate catalog "
                f"(configs/identification.yaml); known: {', '.join(sorted(catalog))}"
            )
        neutral = {p.name: p.neutral for p in catalog[c["name"]].parameters}
        if c["refitted"]:
            values = {k: p["value"] for k, p in c["parameters"].items()}
        else:
            values = dict(screen.get("step_values", {}))
        for name, strength in values.items():
            off = neutral.get(name)
            if off is None or not math.isfinite(off) or name not in P.PARAMETER_NAMES:
                continue
            out.setdefault(name, (float(off), float(strength)))
    return out


def rig_randomization(report_dir: str | Path) -> dict[str, tuple[float, float]]:
    """The env's ``domain_randomization`` ({name: (low, high)}, SI) for a report: each
    identified fitted plant parameter over its confidence interval (``final_fit``; one
    the report did not identify keeps its fitted value), each effect not ruled out from
    none to its strength; an end that is no valid value is the fitted one."""
    rig = load_rig(report_dir)
    diagnosis = _diagnosis(rig.report_dir)
    out = {}
    for name, p in diagnosis["final_fit"]["parameters"].items():
        if p.get("kind") != "plant" or name not in rig.params or p["ci"][0] is None:
            continue
        if not p.get("identified", True):  # its interval says nothing (report.md flags)
            continue
        lo, hi = (float(v) for v in p["ci"])
        out[name] = _interval(rig, name, lo, hi, rig.params[name])
    for name, (neutral, strength) in _unruled_effects(diagnosis).items():
        if name not in out:
            out[name] = _interval(rig, name, neutral, strength, neutral)
    return out
