"""Trained policies without the training stack: export an SB3 actor to ``.npz``, run it in numpy.

``export_policy(model, path, ...)`` writes the deterministic actor of a PPO or SAC model
(its linear layers and activations) plus what the env must look like (id, preview length,
observation normalisation, current scale). ``NumpyPolicy`` evaluates it with numpy only;
``PolicyController`` makes it a :class:`pneumatic_env.agents.base.Controller` for the benchmark.

    python -m pneumatic_env.agents.policy export run/model.zip      # writes run/model.npz

Deterministic actions, as SB3's ``predict(obs, deterministic=True)``: PPO's Gaussian mean
clipped to [-1, 1]; SAC's mean squashed by tanh. Both are then scaled to amperes.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .base import Controller, ControllerContext, ControllerSpec

__all__ = [
    "export_policy",
    "actor_layers",
    "NumpyPolicy",
    "PolicyController",
    "load_policy_spec",
]

_ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "Tanh": np.tanh,
    "ReLU": lambda x: np.maximum(x, 0.0),
    "Identity": lambda x: x,
    "ELU": lambda x: np.where(x > 0, x, np.expm1(x)),
}


def _activation_name(module) -> str | None:
    """The activation a module computes: its class or the first base class we export
    (e.g. a faster ``nn.Tanh`` subclass is a Tanh)."""
    return next((c.__name__ for c in type(module).__mro__ if c.__name__ in _ACTIVATIONS), None)


def actor_layers(modules) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """(W, b, activation after it) for a sequence of torch Linear/activation modules."""
    import torch.nn as nn

    layers: list = []
    for m in modules:
        if isinstance(m, nn.Linear):
            layers.append(
                [
                    m.weight.detach().cpu().numpy().astype(np.float64),
                    m.bias.detach().cpu().numpy().astype(np.float64),
                    "Identity",
                ]
            )
        elif (act := _activation_name(m)) is not None:
            if not layers:
                raise ValueError(f"activation {act} before any Linear layer")
            layers[-1][2] = act
        elif isinstance(m, (nn.Flatten, nn.Sequential)) and not list(m.children()):
            continue
        else:
            raise ValueError(
                f"cannot export layer {m!r}: only Linear and {sorted(_ACTIVATIONS)} are supported"
            )
    return [tuple(layer) for layer in layers]


def _actor(model) -> tuple[list, str]:
    """Layers of the deterministic actor and the output transform ('clip' or 'tanh')."""
    from stable_baselines3 import PPO, SAC

    policy = model.policy
    if isinstance(model, PPO):
        modules = list(policy.mlp_extractor.policy_net) + [policy.action_net]
        return actor_layers(modules), "clip"
    if isinstance(model, SAC):
        modules = list(policy.actor.latent_pi) + [policy.actor.mu]
        return actor_layers(modules), "tanh"
    raise ValueError(f"export_policy supports PPO and SAC models, got {type(model).__name__}")


def export_policy(
    model,
    path: str | Path,
    *,
    env_id: str,
    preview_steps: int,
    normalize_observation: bool,
    action_scale_a: float,
    extra: dict | None = None,
) -> Path:
    """Write the actor of an SB3 PPO/SAC ``model`` to ``path`` (.npz); returns the path.

    The policy must act in [-1, 1] (``pneumatic_env.agents.sb3.SB3VecEnv(normalize_action=True)``);
    ``action_scale_a`` turns that into amperes.
    """
    layers, output = _actor(model)
    meta = {
        "format": "pneumatic_env-mlp-v1",
        "algo": type(model).__name__.lower(),
        "env_id": env_id,
        "preview_steps": int(preview_steps),
        "normalize_observation": bool(normalize_observation),
        "action_scale_a": float(action_scale_a),
        "output": output,
        "activations": [a for _, _, a in layers],
        "obs_dim": int(layers[0][0].shape[1]),
        **(extra or {}),
    }
    arrays = {}
    for i, (w, b, _) in enumerate(layers):
        arrays[f"w{i}"], arrays[f"b{i}"] = w, b
    path = Path(path)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path


class NumpyPolicy:
    """A tiny MLP read from an exported ``.npz``: ``__call__(obs) -> current (A)``."""

    def __init__(self, path: str | Path):
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"policy file {str(path)!r} does not exist")
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data:
                raise ValueError(
                    f"{path}: not an exported policy (no 'meta' entry); write it "
                    "with pneumatic_env.agents.policy.export_policy"
                )
            self.meta = json.loads(str(data["meta"]))
            n = len(self.meta["activations"])
            self.layers = [
                (data[f"w{i}"], data[f"b{i}"], self.meta["activations"][i]) for i in range(n)
            ]
        if self.meta.get("output") not in ("clip", "tanh"):
            raise ValueError(
                f"{path}: output = {self.meta.get('output')!r} is not allowed: 'clip' or 'tanh'"
            )
        repeat = self.meta.get("action_repeat", 1)
        if type(repeat) is not int or repeat < 1:
            raise ValueError(f"{path}: action_repeat = {repeat!r} is not allowed: an integer >= 1")
        self.path = path

    @property
    def obs_dim(self) -> int:
        return int(self.meta["obs_dim"])

    def normalized_action(self, obs) -> np.ndarray:
        """The policy's action in [-1, 1], shape (n, act_dim)."""
        x = np.atleast_2d(np.asarray(obs, dtype=np.float64))
        if x.shape[1] != self.obs_dim:
            raise ValueError(
                f"{self.path}: observation has {x.shape[1]} entries, the policy "
                f"takes {self.obs_dim}"
            )
        for w, b, act in self.layers:
            x = _ACTIVATIONS[act](x @ w.T + b)
        return np.tanh(x) if self.meta["output"] == "tanh" else np.clip(x, -1.0, 1.0)

    def __call__(self, obs) -> np.ndarray:
        return self.normalized_action(obs) * self.meta["action_scale_a"]


class PolicyController(Controller):
    """An exported policy as a benchmark controller (acts on the raw, maybe normalised obs)."""

    name = "policy"

    def __init__(self, context: ControllerContext, policy: NumpyPolicy):
        super().__init__(context)
        if context.obs_dim != policy.obs_dim:
            raise ValueError(
                f"{policy.path}: the policy takes {policy.obs_dim} observation "
                f"entries, the env gives {context.obs_dim} (preview_steps = "
                f"{context.preview_steps})"
            )
        if context.normalize_observation != policy.meta["normalize_observation"]:
            raise ValueError(
                f"{policy.path}: trained with normalize_observation = "
                f"{policy.meta['normalize_observation']}, the env has "
                f"{context.normalize_observation}"
            )
        self.policy = policy
        self.name = policy.path.stem
        self.action_repeat = int(policy.meta.get("action_repeat", 1))
        self._held = np.zeros(0)
        self._age = np.zeros(0, dtype=np.int64)

    def observation_si(self, obs):
        return obs  # the policy takes the observation as the env gives it

    def _allocate(self, n: int) -> None:
        self._held = np.zeros(n)
        self._age = np.zeros(n, dtype=np.int64)

    def _reset_rows(self, rows: np.ndarray) -> None:
        self._age[rows] = 0

    def _act(self, obs):
        if self.action_repeat == 1:
            return self.policy(obs)[:, 0]
        # trained with an action repeat: a new action every action_repeat periods, held
        fresh = self._age % self.action_repeat == 0
        if fresh.any():
            self._held[fresh] = self.policy(obs[fresh])[:, 0]
        self._age += 1
        return self._held.copy()


def load_policy_spec(path: str | Path) -> ControllerSpec:
    """Bench controller spec for ``model.npz`` or ``model.zip`` (uses the sibling ``.npz``)."""
    path = Path(path)
    npz = path if path.suffix == ".npz" else path.with_suffix(".npz")
    if not npz.is_file():
        if path.suffix == ".zip" and path.is_file():
            npz = export_from_zip(path)
        else:
            raise FileNotFoundError(f"no trained policy at {str(path)!r}")
    policy = NumpyPolicy(npz)
    name = f"{policy.meta.get('algo', 'policy')}:{npz.parent.name}/{npz.stem}"
    spec = ControllerSpec(
        name,
        {
            "preview_steps": policy.meta["preview_steps"],
            "normalize_observation": policy.meta["normalize_observation"],
        },
        lambda ctx: PolicyController(ctx, policy),
        str(npz),
    )
    return spec


def export_from_zip(path: str | Path) -> Path:
    """Export ``model.zip`` (PPO or SAC saved by ``pneumatic_env.agents.train``) to
    ``model.npz`` beside it.

    Needs the training stack once (SB3, torch); the env metadata comes from ``train.json``
    written by ``pneumatic-env train`` in the same directory.
    """
    from stable_baselines3 import PPO, SAC

    path = Path(path)
    info_path = path.parent / "train.json"
    if not info_path.is_file():
        raise FileNotFoundError(
            f"{info_path} is missing: it holds the env settings of the "
            f"model; re-run pneumatic-env train or export by hand"
        )
    info = json.loads(info_path.read_text())
    algos: dict[str, type[PPO] | type[SAC]] = {"ppo": PPO, "sac": SAC}
    if info.get("algo") not in algos:
        raise ValueError(
            f"{info_path}: algo = {info.get('algo')!r} is not allowed: use one of {sorted(algos)}"
        )
    model = algos[info["algo"]].load(path, device="cpu")
    return export_policy(model, path.with_suffix(".npz"), **info["policy_env"])


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "export":
        sys.exit("usage: python -m pneumatic_env.agents.policy export path/to/model.zip")
    print(export_from_zip(sys.argv[2]))
