"""The machine a speed run measured: CPU, cores, Numba threads, library versions."""

from __future__ import annotations

import os
import platform
import subprocess

import numpy as np


def machine_description() -> dict:
    """The CPU, its cores and threads, and the versions the speed report states."""
    import gymnasium
    import numba
    import scipy

    model = platform.processor() or platform.machine()
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in text.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "gymnasium": gymnasium.__version__,
        "scipy": scipy.__version__,
        "os": platform.platform(),
    }
