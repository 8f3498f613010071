"""``pneumatic-env``: the command-line entry point. Each subcommand lives in its own module,
which provides ``add_arguments(parser)`` and ``run(args) -> int``."""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = {
    "simulate": ("pneumatic_env.replay", "drive the model with a recording's coil current"),
    "paper": ("pneumatic_env.paper", "reproduce the paper's experiments (figures + table)"),
    "speed": ("pneumatic_env.speed", "measure simulation speed against yardsticks"),
    "bench": ("agents.bench", "run the force-tracking benchmark for a controller"),
    "train": ("agents.train", "train a Stable-Baselines3 agent"),
    "identify": ("pneumatic_env.identification.cli", "calibrate on recordings and diagnose the residual"),
    "rig": ("pneumatic_env.identification.virtual_rig", "write synthetic recordings from the virtual rig"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="pneumatic-env", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if not module_name.startswith(exc.name or "\0"):
                raise
            p.set_defaults(_module=None, _missing=module_name)
            continue
        module.add_arguments(p)
        p.set_defaults(_module=module)
    args = parser.parse_args(argv)
    if args._module is None:
        parser.error(f"'{args.command}' is not available in this installation ({args._missing})")
    return int(args._module.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
