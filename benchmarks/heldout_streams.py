"""Record (``--write``) and time the held-out-only data of configs (``PreferenceDataModule.prepare_heldout``).

    python benchmarks/heldout_streams.py configs/icpo_darkroom.yaml configs/icpo_metaworld.yaml [--write]

For each config, in fresh scratch directories: the whole dataset is generated (timed), the generator's state
after its training splits (``MDPSetting.heldout_stream``) and the checksums of the files made after it are its
entry of ``icprl_lightning/data/heldout_streams.json`` (written with ``--write``), then only the held-out
splits are generated from that entry (timed) and their bytes compared with the whole dataset's. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.data.datamodule import HELDOUT_STREAMS


def entry(config: str, root: str) -> tuple[str, dict, float]:
    """The dataset's directory name, its recorded entry and the seconds its whole generation took."""
    dm = datamodule_from_config(*config.split("+"), root_dir=root, progress=False)
    start = time.perf_counter()
    dm.prepare_data()
    seconds = time.perf_counter() - start
    files = {k: v["sha256"] for k, v in dm.load().manifest["files"].items() if not k.startswith(("train/", "val/"))}
    return dm.path.name, {"stream": dm.setting.heldout_stream, "files": files}, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("configs", nargs="+", help="config files (a base and its overlays joined by '+')")
    parser.add_argument("--write", action="store_true", help=f"add the entries to {HELDOUT_STREAMS}")
    args = parser.parse_args()
    table, out = json.loads(HELDOUT_STREAMS.read_text()), {}
    for config in args.configs:
        with tempfile.TemporaryDirectory() as whole:
            name, recorded, seconds = entry(config, whole)
        if args.write:
            table[name] = recorded
            HELDOUT_STREAMS.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
        out[config] = {"dataset": name, "whole_seconds": round(seconds, 1)}
        if name in table:
            with tempfile.TemporaryDirectory() as heldout:
                dm = datamodule_from_config(*config.split("+"), root_dir=heldout, progress=False)
                start = time.perf_counter()
                dm.prepare_heldout()  # raises if a byte differs from the recorded whole generation's
                seconds = time.perf_counter() - start
                found = {k: v["sha256"] for k, v in dm.load().manifest["files"].items()}
                out[config].update(heldout_seconds=round(seconds, 1), files=len(found),
                                   same_bytes_as_whole=found == recorded["files"])
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
