"""Opening checkpoints safely and checking them for damage: the one reader of every ``.ckpt`` this package loads.

A checkpoint is untrusted input, so reading one never runs code from it:

* ``torch.load(weights_only=True)`` only: tensors, containers, numbers and strings unpickle; any other
  global a pickle names (``os.system``, a class's ``__reduce__``) is refused before it is called. Our
  Lightning checkpoints need nothing more (``epoch``, ``state_dict``, ``loops``, ``optimizer_states``,
  ``hyper_parameters``... are all plain), so no ``add_safe_globals`` is used.
* The class to build comes from ``METHODS``, an allow-list of this package's LightningModules, looked up
  by the ``icprl_class_path`` the file names; a name outside it is refused, never imported. The module is
  built here from the file's ``hyper_parameters`` and ``state_dict`` (not ``load_from_checkpoint``, whose
  hyperparameters may name an instantiator to import).
* ``on_save_checkpoint`` stores ``icprl_sha256``: SHA-256 over the class path, the hyperparameters (as
  sorted JSON) and every ``state_dict`` tensor (sorted by name: name, dtype, shape, bytes). Reading
  recomputes it, so a flipped bit in a weight is an error, not a silently different policy.

A file saved before the checksum existed is refused, with the way out in the message: for a file you
trust, ``python -m icprl_lightning.checkpoints stamp PATH`` adds the checksum (it loads the file as safely
as any other read; the stamp only vouches that the file has not changed since).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import inspect
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

import torch
import yaml

CLASS_KEY = "icprl_class_path"
CHECKSUM_KEY = "icprl_sha256"
METHODS = ("icprl_lightning.methods.dpt.DPTModule", "icprl_lightning.methods.dpt.DP2TModule",
           "icprl_lightning.methods.icpo.ICPOModule", "icprl_lightning.methods.reward_gen.RewardGenModule",
           "icprl_lightning.methods.dit.DITModule", "icprl_lightning.methods.icrg.ICRGModule")
LIGHTNING_SPECIAL_PATHS = ("best", "last", "hpc")  # ``ckpt_path`` values the Trainer resolves itself


def class_path(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def method_classes() -> dict[str, type]:
    """The allow-list as classes, imported by the fixed names in ``METHODS`` (never by a name from a file).

    Imported when a checkpoint is built, not at the top: the methods import this module to save, and it
    sits below them (tests/test_layering.py).
    """
    classes = {}
    for name in METHODS:
        module, _, attr = name.rpartition(".")
        classes[name] = getattr(importlib.import_module(module), attr)
    return classes


def checksum(class_name: str, hparams: dict[str, Any], state_dict: dict[str, Any]) -> str:
    """SHA-256 of what rebuilds the module: class path, hyperparameters and state_dict, in a fixed order."""
    h = hashlib.sha256()
    h.update(class_name.encode())
    h.update(json.dumps(hparams, sort_keys=True, default=repr).encode())
    for name in sorted(state_dict):
        value = state_dict[name]
        h.update(b"\0" + name.encode() + b"\0")
        if isinstance(value, torch.Tensor):
            t = value.detach().cpu().contiguous().reshape(-1)
            h.update(f"{t.dtype}{tuple(value.shape)}".encode())
            h.update(t.view(torch.uint8).numpy().tobytes())
        else:  # never in our modules; hashed so that a stray entry is still covered
            h.update(repr(value).encode())
    return h.hexdigest()


def stamp(module: torch.nn.Module, checkpoint: dict[str, Any]) -> None:
    """``on_save_checkpoint`` of every method: the class to rebuild and the checksum of what is saved."""
    checkpoint[CLASS_KEY] = class_path(type(module))
    checkpoint[CHECKSUM_KEY] = checksum(checkpoint[CLASS_KEY], checkpoint.get("hyper_parameters", {}),
                                        checkpoint["state_dict"])


def _unsafe_global(e: BaseException) -> str | None:
    """The global a weights-only load refused (``exec``, ``posix.system``, a class), if torch names one."""
    found = re.search(r"[Uu]nsupported (?:global: )?GLOBAL (\S+)", str(e))
    return found.group(1) if found else None


def _first_line(e: BaseException) -> str:
    """The informative line of an exception, one line and short (torch's messages run to paragraphs)."""
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    operand = next((line for line in lines if line.startswith("Unsupported operand")), None)
    if operand:  # not a zip archive: the weights-only unpickler met bytes it does not parse
        return f"the weights-only unpickler stopped at an {operand.lower()}"
    return f"{type(e).__name__}: {(lines or [''])[0].split('. ')[0][:200]}"


def load_raw(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The file as a dict, unpickled with ``weights_only=True``; errors name the path and the problem."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a directory, not a checkpoint file (pass a .ckpt inside it, e.g. "
                         f"{path}/checkpoints/last.ckpt)")
    if not path.is_file():
        raise FileNotFoundError(f"No checkpoint at {path}")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # torch raises many types for a damaged file
        unsafe = _unsafe_global(e)
        if unsafe:
            raise ValueError(f"{path} was refused: it holds pickled objects other than tensors and plain values "
                             f"(its pickle names {unsafe}), which could run code when loaded; icprl checkpoints "
                             "never do, so this file is damaged or not from icprl_lightning") from None
        raise ValueError(f"{path} is not a readable checkpoint: damaged, truncated or not a torch file "
                         f"({_first_line(e)})") from None
    if not isinstance(ckpt, dict) or CLASS_KEY not in ckpt:
        raise ValueError(f"{path} is not an icprl_lightning checkpoint (no {CLASS_KEY!r} entry)")
    return ckpt


def read_checkpoint(path: str | Path, map_location: str | torch.device = "cpu",
                    expected: type | None = None) -> dict[str, Any]:
    """A verified checkpoint: readable safely, of an allowed class (``expected`` if given), checksum intact."""
    return verify(load_raw(path, map_location), path, expected)


def verify(ckpt: dict[str, Any], path: str | Path, expected: type | None = None) -> dict[str, Any]:
    """``ckpt`` (from ``load_raw``) if its class is allowed and its checksum matches, else a ValueError."""
    name = ckpt[CLASS_KEY]
    allowed = {class_path(expected)} if expected is not None else set(METHODS)
    if not isinstance(name, str) or name not in allowed:
        if expected is not None and name in METHODS:
            raise ValueError(f"{path} is not a {expected.__name__.removesuffix('Module')} checkpoint (it holds "
                             f"{name.rpartition('.')[2]})")
        raise ValueError(f"{path} names class {name!r}, which is not one of icprl_lightning's methods "
                         f"({', '.join(c.rpartition('.')[2] for c in METHODS)}); refusing to import it")
    hparams, state_dict = ckpt.get("hyper_parameters"), ckpt.get("state_dict")
    if not isinstance(hparams, dict) or not isinstance(state_dict, dict):
        raise ValueError(f"{path} is damaged: it has no hyper_parameters or state_dict dict")
    if hparams.get("_class_path", name) != name:  # LightningCLI would import this one, so it must agree
        raise ValueError(f"{path} is damaged: hyper_parameters name class {hparams['_class_path']!r} but the "
                         f"checkpoint names {name!r}")
    bad = [k for k, v in state_dict.items() if not isinstance(v, torch.Tensor)]
    if bad:
        raise ValueError(f"{path} is damaged: state_dict entry {bad[0]!r} is not a tensor")
    if CHECKSUM_KEY not in ckpt:
        raise ValueError(f"{path} has no {CHECKSUM_KEY} checksum (saved by an older icprl_lightning), so its "
                         "weights cannot be checked for damage; if you trust the file, add one with "
                         f"`python -m icprl_lightning.checkpoints stamp {path}`")
    try:
        expected_sum = checksum(name, hparams, state_dict)
    except (TypeError, ValueError, RuntimeError) as e:  # only a crafted file: sparse tensors, mixed-type keys
        raise ValueError(f"{path} is damaged: its contents cannot be checksummed ({_first_line(e)})") from None
    if ckpt[CHECKSUM_KEY] != expected_sum:
        raise ValueError(f"{path} is damaged: its weights or hyperparameters do not match the checksum stored "
                         "when it was saved (a changed bit or an edited file); re-train or restore the file")
    return ckpt


def build_module(ckpt: dict[str, Any], path: str | Path, map_location: str | torch.device = "cpu"):
    """The LightningModule of a checkpoint from ``read_checkpoint``, in eval mode."""
    cls = method_classes()[ckpt[CLASS_KEY]]
    # as load_from_checkpoint does: only the class's own arguments (a base class's save_hyperparameters
    # also records its own, e.g. context_kind, and the CLI adds _class_path / _instantiator)
    accepted = inspect.signature(cls.__init__).parameters
    hparams = {k: v for k, v in ckpt["hyper_parameters"].items() if k in accepted and k != "self"}
    try:
        module = cls(**hparams)
        module.load_state_dict(ckpt["state_dict"], strict=True)
    except (TypeError, ValueError, RuntimeError, KeyError, AssertionError) as e:
        raise ValueError(f"{path} does not fit {cls.__name__} ({_first_line(e)})") from None
    return module.to(map_location).eval()


def load_module(path: str | Path, map_location: str | torch.device = "cpu"):
    """Any icprl method's checkpoint as its LightningModule (eval mode), after every check above."""
    return build_module(read_checkpoint(path, map_location), path, map_location)


def check_cli_checkpoint(args: list[str]) -> str | None:
    """Verify the ``--ckpt_path`` of ``icprl fit/validate/test/predict`` args (after the subcommand).

    The path is the last ``--ckpt_path`` given, on the command line or as a top-level ``ckpt_path`` of a
    ``--config`` file. Lightning's special values (``best``, ``last``, ...) are left to the Trainer.
    ``--weights_only false`` is refused: it would let Lightning unpickle arbitrary objects. Returns the
    verified path (None if there is none to check).
    """
    ckpt_path, weights_only = None, None
    it = iter(args)
    for arg in it:
        key, eq, value = arg.partition("=")
        if key not in ("--ckpt_path", "--config", "--weights_only"):
            continue
        value = value if eq else next(it, "")
        if key == "--ckpt_path":
            ckpt_path = value
        elif key == "--weights_only":
            weights_only = value
        elif Path(value).is_file():
            config = yaml.safe_load(Path(value).read_text())
            if isinstance(config, dict) and config.get("ckpt_path") is not None:
                ckpt_path = str(config["ckpt_path"])
    if weights_only is not None and weights_only.lower() == "false":
        raise ValueError("--weights_only false is refused: icprl checkpoints hold only tensors and plain values")
    if not ckpt_path or ckpt_path.lower() in ("null", "none"):
        return None
    if (ckpt_path in LIGHTNING_SPECIAL_PATHS or ckpt_path.startswith("registry")) and not os.path.exists(ckpt_path):
        return None
    load_module(ckpt_path)  # built once here too: a file that does not rebuild fails here, in one line
    return ckpt_path


def stamp_file(path: str | Path) -> str:
    """Add the checksum to a trusted checkpoint saved before it existed (atomic rewrite); returns it.

    The file is read as safely as any other, must name an allowed class and must rebuild; a checksum it
    already has is checked, never replaced.
    """
    path = Path(path)
    ckpt = load_raw(path)
    stamped = CHECKSUM_KEY in ckpt
    if not stamped:
        try:
            ckpt[CHECKSUM_KEY] = checksum(str(ckpt[CLASS_KEY]), ckpt.get("hyper_parameters"), ckpt.get("state_dict"))
        except (TypeError, ValueError, RuntimeError, AttributeError) as e:
            raise ValueError(f"{path} is damaged: its contents cannot be checksummed ({_first_line(e)})") from None
    build_module(verify(ckpt, path), path)
    if not stamped:
        tmp = path.with_name(f".{path.name}.stamp-{os.getpid()}")
        try:
            torch.save(ckpt, tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    return ckpt[CHECKSUM_KEY]


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m icprl_lightning.checkpoints", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("stamp", help="add the checksum to trusted checkpoints saved before it existed").add_argument(
        "paths", nargs="+")
    sub.add_parser("verify", help="check checkpoints (exit 1 if any fails)").add_argument("paths", nargs="+")
    parsed = parser.parse_args(args)
    failed = False
    for path in parsed.paths:
        try:
            if parsed.command == "stamp":
                print(f"{path}: {CHECKSUM_KEY} {stamp_file(path)}")
            else:
                load_module(path)
                print(f"{path}: ok")
        except (ValueError, FileNotFoundError) as e:
            print(f"error: {e}", file=sys.stderr)
            failed = True
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
