"""``pneumatic-env``: the command-line entry point.

A small registry names each subcommand's module, which provides ``add_arguments(parser)``
and ``run(args) -> int``. Only the module of the command that runs is imported, so a core
install runs ``simulate`` and ``identify`` without the training or plotting extras.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NamedTuple


class Command(NamedTuple):
    module: str
    help: str
    extra: str = ""  # the optional dependency group the command needs, if any


COMMANDS: dict[str, Command] = {
    "simulate": Command("pneumatic_env.replay", "drive the model with a recording's coil current"),
    "identify": Command(
        "pneumatic_env.identification.cli", "calibrate on recordings and diagnose the residual"
    ),
    "bench": Command(
        "pneumatic_env.agents.bench", "run the force-tracking benchmark for a controller", "plots"
    ),
    "train": Command("pneumatic_env.agents.train", "train a learning agent", "train"),
    "tune": Command(
        "pneumatic_env.agents.tune",
        "search the fast trainer's hyperparameters (Optuna, or Ray Tune)",
        "train",
    ),
    "paper": Command(
        "pneumatic_env.studies.paper_report",
        "reproduce the paper's experiments (figures + table)",
        "plots",
    ),
    "speed": Command("pneumatic_env.studies.speed", "measure simulation speed against yardsticks"),
    "rig": Command(
        "pneumatic_env.studies.rig_campaign", "write synthetic recordings from the virtual rig"
    ),
    "clear-cache": Command(
        "pneumatic_env.numba_cache", "delete Numba's cached code where the sources changed"
    ),
}


def _chosen(argv: list[str]) -> str | None:
    """The subcommand in ``argv`` (the first word that names one), or None."""
    return next((word for word in argv if word in COMMANDS), None)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog="pneumatic-env",
        description="Simulate, benchmark, train and identify a pneumatic "
        "force actuator (pneumatic_env).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parsers = {
        name: sub.add_parser(name, help=c.help, description=c.help) for name, c in COMMANDS.items()
    }
    name = _chosen(argv)
    module = None
    if name is not None:
        command = COMMANDS[name]
        try:
            module = importlib.import_module(command.module)
        except ModuleNotFoundError as exc:
            if (exc.name or "").startswith("pneumatic_env"):
                raise
            torch = "torch==2.13.0 " if command.extra == "train" else ""
            parser.error(
                f"'{name}' needs {exc.name!r}, which is not installed: install the "
                f"'{command.extra or 'all'}' extra (pip install {torch}"
                f"'pneumatic_env[{command.extra or 'all'}]')"
            )
        module.add_arguments(parsers[name])
    args = parser.parse_args(argv)
    assert module is not None  # parse_args exits unless a command was named
    return int(module.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
