"""Opening checkpoints safely and checking them for damage: the one reader of every ``.ckpt`` this package
loads (docs/reliability.md). A checkpoint is untrusted input, so reading one never runs code from it:

* ``torch.load(weights_only=True)`` only (our Lightning checkpoints are all plain: no ``add_safe_globals``);
  any other global a pickle names (``os.system``, a ``__reduce__``) is refused before it is called.
* The class comes from the method registry (``registry.py``) by the file's ``icprl_class_path``; a name
  outside it is refused, never imported. The module is built here from ``hyper_parameters`` and
  ``state_dict``, not ``load_from_checkpoint`` (whose hyperparameters may name an instantiator to import).
* ``icprl_sha256`` (``stamp``): SHA-256 over class path, hyperparameters (sorted JSON) and every
  ``state_dict`` tensor, recomputed on reading, so a flipped bit is an error, not a different policy.
* ``icprl_seal``: one SHA-256 per top-level entry (optimizer, loops, callbacks, RNG states, ...), the last
  step of Lightning's ``dump_checkpoint``, so what a resume restores is covered and a damaged part named.
* Every floating tensor of the weights and optimizer state must be finite (a NaN moment resumes all-NaN).

``hyperparameters`` gathers the flat keys earlier versions saved into the groups every method now takes
(``models/config.py``): the sizes (also inside ICRG's ``reward_gen_hparams`` / ``cross_fit_hparams``) into
``backbone``, ``lr``, ``weight_decay``, ``lr_schedule``, ``warmup_steps`` into ``optimizer``, in a new dict; the
file's entries, which the checksum and seal cover, never change. ``checkpoint_for_lightning`` is the CLI's one door
to Lightning's ``ckpt_path``: Lightning loads a private copy of exactly the verified contents. A file saved before
the checksum existed is refused; for a file you trust, ``icprl checkpoint stamp PATH`` adds it.
"""

from __future__ import annotations

import atexit
import hashlib
import inspect
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch

from icprl_lightning.registry import class_path, method_class, method_names, short_names
from icprl_lightning.untrusted import check_argument_types, check_torch_archive

CLASS_KEY = "icprl_class_path"
CHECKSUM_KEY = "icprl_sha256"
SEAL_KEY = "icprl_seal"
LIGHTNING_SPECIAL_PATHS = ("best", "last", "hpc")  # ``ckpt_path`` values the Trainer resolves itself
# each group's keys, as earlier versions saved them flat among the other hyperparameters
FLAT_GROUPS = {"backbone": ("n_layer", "n_embd", "n_head", "dropout"),
               "optimizer": ("lr", "weight_decay", "lr_schedule", "warmup_steps")}


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


def _digest(value: Any, h: Any) -> None:
    """Feed ``value`` to ``h`` in a canonical form: containers by type and (sorted) keys, tensors by dtype,
    shape and bytes, scalars by type and repr. The same contents always give the same bytes."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu()
        if t.layout != torch.strided:
            raise TypeError(f"a {t.layout} tensor")
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.contiguous().reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(value, dict):
        h.update(f"D{len(value)}".encode())
        for key in sorted(value, key=lambda k: (type(k).__name__, repr(k))):
            _digest(key, h)
            _digest(value[key], h)
    elif isinstance(value, (list, tuple)):
        h.update(f"{type(value).__name__[0]}{len(value)}".encode())
        for item in value:
            _digest(item, h)
    elif value is None or isinstance(value, (bool, int, float, str, bytes)):
        h.update(f"S{type(value).__name__}:{value!r};".encode())
    else:  # never in a checkpoint read with weights_only; hashed so that a stray entry is still covered
        h.update(f"O{type(value).__name__}:{value!r};".encode())


def seal(checkpoint: dict[str, Any]) -> dict[str, str]:
    """One SHA-256 per top-level entry of ``checkpoint`` (all but the seal itself)."""
    digests = {}
    for key, value in checkpoint.items():
        if key == SEAL_KEY:
            continue
        h = hashlib.sha256()
        _digest(value, h)
        digests[str(key)] = h.hexdigest()
    return digests


def stamp(module: torch.nn.Module, checkpoint: dict[str, Any]) -> None:
    """``on_save_checkpoint`` of every method: the class to rebuild, the checksum of the module and the seal
    of the whole checkpoint. Lightning calls the module's hook last in ``dump_checkpoint``, so the seal covers
    every entry that is saved."""
    checkpoint[CLASS_KEY] = class_path(type(module))
    checkpoint[CHECKSUM_KEY] = checksum(checkpoint[CLASS_KEY], checkpoint.get("hyper_parameters", {}),
                                        checkpoint["state_dict"])
    checkpoint[SEAL_KEY] = seal(checkpoint)


def _check_seal(ckpt: dict[str, Any], path: str | Path) -> None:
    """Every entry matches the digest stored when it was saved; the first one that does not is named."""
    stored = ckpt[SEAL_KEY]
    if not isinstance(stored, dict) or not all(isinstance(v, str) for v in stored.values()):
        raise ValueError(f"{path} is damaged: its {SEAL_KEY} entry is not a table of digests")
    try:
        found = seal(ckpt)
    except (TypeError, ValueError, RuntimeError) as e:
        raise ValueError(f"{path} is damaged: its contents cannot be checksummed ({_first_line(e)})") from None
    for key in sorted(set(stored) | set(found)):
        if key not in found:
            raise ValueError(f"{path} is damaged: its {key!r} entry is missing (it was saved with one)")
        if key not in stored:
            raise ValueError(f"{path} is damaged: it has a {key!r} entry that was not there when it was saved")
        if stored[key] != found[key]:
            raise ValueError(f"{path} is damaged: its {key!r} entry does not match the checksum stored when it "
                             "was saved (a changed bit or an edited file); re-train or restore the file")


def _non_finite(value: Any, where: str) -> str | None:
    """The first place in ``value`` (nested containers) holding a NaN or an infinite float, or None."""
    if isinstance(value, torch.Tensor):
        return where if value.is_floating_point() and not bool(torch.isfinite(value).all()) else None
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    for key, item in items:
        found = _non_finite(item, f"{where}.{key}" if where else str(key))
        if found:
            return found
    return None


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
    check_torch_archive(path)  # nothing inflated or read beyond the file's size
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


def verify(ckpt: dict[str, Any], path: str | Path, expected: type | None = None,
           require_seal: bool = False) -> dict[str, Any]:
    """``ckpt`` (from ``load_raw``) if its class is allowed and its checksum and seal match, else a ValueError.

    ``require_seal`` (a resume) refuses a file without the seal: its optimizer, loop and RNG states would be
    restored unchecked."""
    name = ckpt[CLASS_KEY]
    registered = method_names()
    allowed = {class_path(expected)} if expected is not None else set(registered)
    if not isinstance(name, str) or name not in allowed:
        if expected is not None and name in registered:
            raise ValueError(f"{path} is not a {expected.__name__.removesuffix('Module')} checkpoint (it holds "
                             f"{name.rpartition('.')[2]})")
        raise ValueError(f"{path} names class {name!r}, which is not a registered method "
                         f"({short_names(registered)}); refusing to import it")
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
                         f"`icprl checkpoint stamp {path}`")
    try:
        expected_sum = checksum(name, hparams, state_dict)
    except (TypeError, ValueError, RuntimeError) as e:  # only a crafted file: sparse tensors, mixed-type keys
        raise ValueError(f"{path} is damaged: its contents cannot be checksummed ({_first_line(e)})") from None
    if ckpt[CHECKSUM_KEY] != expected_sum:
        raise ValueError(f"{path} is damaged: its weights or hyperparameters do not match the checksum stored "
                         "when it was saved (a changed bit or an edited file); re-train or restore the file")
    if SEAL_KEY in ckpt:
        _check_seal(ckpt, path)
    elif require_seal:
        raise ValueError(f"{path} has no {SEAL_KEY} (saved by an older icprl_lightning), so the optimizer, loop and "
                         "RNG states a resume restores cannot be checked; start a new fit from its weights instead, or "
                         f"if you trust the file add one with `icprl checkpoint stamp {path}`")
    for part in ("state_dict", "optimizer_states", "lr_schedulers"):
        where = _non_finite(ckpt.get(part, ()), part)
        if where:
            raise ValueError(f"{path} is unusable: {where} holds NaN or infinite values (the run that saved it "
                             "diverged); resume from an earlier checkpoint")
    return ckpt


def _gather_groups(hparams: Any) -> Any:
    """``hparams`` with each group's flat keys (``FLAT_GROUPS``) gathered into its dict (a new dict); anything
    else as it is."""
    if not isinstance(hparams, dict):
        return hparams
    out = dict(hparams)
    for group, keys in FLAT_GROUPS.items():
        if group not in out and any(k in out for k in keys):
            out[group] = {k: out.pop(k) for k in keys if k in out}
    return out


def hyperparameters(ckpt: dict[str, Any]) -> dict[str, Any]:
    """A verified checkpoint's hyperparameters as this version's constructors take them (a new dict): flat keys
    gathered into their groups, also in the RewardGen architectures an ICRG checkpoint holds."""
    hparams = _gather_groups(dict(ckpt["hyper_parameters"]))
    if "reward_gen_hparams" in hparams:
        hparams["reward_gen_hparams"] = _gather_groups(hparams["reward_gen_hparams"])
    if isinstance(hparams.get("cross_fit_hparams"), list):
        hparams["cross_fit_hparams"] = [_gather_groups(h) for h in hparams["cross_fit_hparams"]]
    return hparams


def build_module(ckpt: dict[str, Any], path: str | Path, map_location: str | torch.device = "cpu"):
    """The LightningModule of a checkpoint from ``read_checkpoint``, in eval mode."""
    cls = method_class(ckpt[CLASS_KEY])
    # as load_from_checkpoint does: only the class's own arguments (a base class's save_hyperparameters
    # also records its own, e.g. context_kind, and the CLI adds _class_path / _instantiator)
    accepted = inspect.signature(cls.__init__).parameters
    hparams = {k: v for k, v in hyperparameters(ckpt).items() if k in accepted and k != "self"}
    check_argument_types(cls, hparams, str(path))
    try:
        module = cls(**hparams)
        module.load_state_dict(ckpt["state_dict"], strict=True)
    except (TypeError, ValueError, RuntimeError, KeyError, AssertionError) as e:
        raise ValueError(f"{path} does not fit {cls.__name__} ({_first_line(e)})") from None
    return module.to(map_location).eval()


def load_module(path: str | Path, map_location: str | torch.device = "cpu"):
    """Any icprl method's checkpoint as its LightningModule (eval mode), after every check above."""
    return build_module(read_checkpoint(path, map_location), path, map_location)


_VERIFIED_DIR: list[str] = []  # the private directory of verified copies, made once per process


def _private_copy(ckpt: dict[str, Any], name: str) -> str:
    """``ckpt`` saved into a private temporary directory (mode 0700, removed at exit); its path."""
    if not _VERIFIED_DIR:
        _VERIFIED_DIR.append(tempfile.mkdtemp(prefix="icprl-verified-"))
        atexit.register(shutil.rmtree, _VERIFIED_DIR[0], ignore_errors=True)
    out = os.path.join(_VERIFIED_DIR[0], f"{len(os.listdir(_VERIFIED_DIR[0]))}-{name}")
    torch.save(ckpt, out)
    return out


def checkpoint_for_lightning(ckpt_path: Any, subcommand: str) -> str:
    """The parsed ``ckpt_path`` of ``icprl fit/validate/test/predict`` (however it was spelled), verified; the
    path of a private copy of its verified contents, which Lightning then loads. Only a local file: remote
    paths (Lightning would fetch and unpickle them) and Lightning's special values (``best``, ``last``, ``hpc``,
    ``registry``) are refused. ``fit`` resumes everything, so it needs the seal; the other subcommands get a
    copy holding just the verified module. The module is built once, so a file that does not rebuild fails here.
    """
    if not isinstance(ckpt_path, (str, os.PathLike)):
        raise ValueError(f"ckpt_path must be a path to a .ckpt file, got {ckpt_path!r}")
    text = os.fspath(ckpt_path)
    if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", text) or text.startswith(("registry", "hf:")):
        raise ValueError(f"ckpt_path {text!r} is refused: only a local checkpoint file is loaded (download it "
                         "yourself, then pass its path)")
    if text in LIGHTNING_SPECIAL_PATHS and not os.path.exists(text):
        raise ValueError(f"ckpt_path {text!r} is refused: pass the checkpoint file's path (each fit has its own "
                         "run directory, which prints `last checkpoint: PATH` when it ends)")
    path = Path(text).expanduser().resolve()
    ckpt = verify(load_raw(path), path, require_seal=subcommand == "fit")
    build_module(ckpt, path)
    if subcommand != "fit":  # the weights and what rebuilds them; nothing unverified reaches Lightning
        import lightning

        ckpt = {k: ckpt[k] for k in (CLASS_KEY, CHECKSUM_KEY, "state_dict", "hyper_parameters")}
        ckpt["pytorch-lightning_version"] = lightning.__version__
    return _private_copy(ckpt, path.name)


def stamp_file(path: str | Path) -> str:
    """Add the checksum and seal to a trusted checkpoint saved before they existed (atomic rewrite); returns
    the checksum. Read as safely as any other; it must rebuild; a checksum or seal it has is checked, never replaced."""
    path = Path(path)
    ckpt = load_raw(path)
    changed = CHECKSUM_KEY not in ckpt or SEAL_KEY not in ckpt
    if CHECKSUM_KEY not in ckpt:
        try:
            ckpt[CHECKSUM_KEY] = checksum(str(ckpt[CLASS_KEY]), ckpt.get("hyper_parameters"), ckpt.get("state_dict"))
        except (TypeError, ValueError, RuntimeError, AttributeError) as e:
            raise ValueError(f"{path} is damaged: its contents cannot be checksummed ({_first_line(e)})") from None
    build_module(verify(ckpt, path), path)  # the checksum (and a seal it has) checked before anything is added
    if changed:
        ckpt[SEAL_KEY] = seal(ckpt)
        tmp = path.with_name(f".{path.name}.stamp-{os.getpid()}")
        try:
            torch.save(ckpt, tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    return ckpt[CHECKSUM_KEY]
