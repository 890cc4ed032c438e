"""How long the ``icprl`` commands take to answer, beside their floor: ``python -c "import lightning.pytorch"``.

    python benchmarks/cli_latency.py [--repeats 3]

Prints JSON: per command the median wall-clock seconds of ``--repeats`` runs and its ratio to the Lightning
import's median, all timed in one interleaved loop on this machine (a busy machine slows every one alike).
``icprl fit --help`` and a one-line config error (a mistyped key) must parse a LightningCLI, so their floor is
that import; ``icprl --help``, the subcommands that neither train nor deploy (``report``, ``import``,
``export-data``, ``label``, ``checkpoint verify``) and a missing config never import Lightning.
Run from the repository's root (the config error reads configs/smoke.yaml, verify a test fixture).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

FLOOR = "import lightning.pytorch"
COMMANDS = {
    FLOOR: [sys.executable, "-c", "import lightning.pytorch"],
    "icprl --help": [sys.executable, "-m", "icprl_lightning", "--help"],
    **{f"icprl {name} --help": [sys.executable, "-m", "icprl_lightning", name, "--help"]
       for name in ("report", "import", "export-data", "label")},
    "icprl checkpoint verify <ckpt>": [sys.executable, "-m", "icprl_lightning", "checkpoint", "verify",
                                       "tests/fixtures/legacy/icpo_1x8.ckpt"],
    "icprl fit --config <missing>": [sys.executable, "-m", "icprl_lightning", "fit", "--config",
                                     "configs/smok.yaml"],
    "icprl fit --help": [sys.executable, "-m", "icprl_lightning", "fit", "--help"],
    "icprl fit <mistyped key>": [sys.executable, "-m", "icprl_lightning", "fit", "--config", "configs/smoke.yaml",
                                 "--trainer.max_epoch", "2"],
}


def timed(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False,
                   env={**os.environ, "OMP_NUM_THREADS": "1"})
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    seconds: dict[str, list[float]] = {name: [] for name in COMMANDS}
    timed(COMMANDS[FLOOR])  # warm the file cache once, unmeasured
    for _ in range(args.repeats):
        for name, argv in COMMANDS.items():
            seconds[name].append(timed(argv))
    floor = statistics.median(seconds[FLOOR])
    print(json.dumps({
        "command": "python benchmarks/cli_latency.py --repeats " + str(args.repeats),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "seconds": {name: round(statistics.median(values), 2) for name, values in seconds.items()},
        "ratio_to_import": {name: round(statistics.median(values) / floor, 2) for name, values in seconds.items()},
        "runs": {name: [round(v, 2) for v in values] for name, values in seconds.items()},
    }, indent=2))


if __name__ == "__main__":
    main()
