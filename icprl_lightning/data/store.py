"""On-disk datasets: one directory per dataset, one memory-mappable ``.npy`` per field, a manifest.

Layout::

    <path>/manifest.json            schema version, generator config, seed, sizes, statistics, checksums
    <path>/<split>/<field>.npy      e.g. train/states.npy, eval_low/preferred.npy

A dataset is staged in a hidden sibling directory and renamed into place (``io.staged_directory``), so an
interrupted generation or a full disk leaves nothing that looks like a dataset and an existing one untouched.
Loading checks the schema version, the generator config and each file's size and SHA-256; a manifest that is
not what this module writes (wrong types, paths outside the dataset, an ``.npy`` header that disagrees with
its entry) is a ``DatasetError``; what the arrays hold is checked by ``data/schema.py``. Only a dataset of
this project is ever replaced (``check_replaceable_dataset``, the one check the store, the DataModules and the
importer use); writers of one path take turns (``dataset_lock``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.io import (
    NotReplaceableError,
    check_replaceable,
    path_lock,
    sha256,
    staged_directory,
    storage_error,
)

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
WHAT = "icprl dataset"

__all__ = ["MANIFEST", "SCHEMA_VERSION", "DatasetError", "DatasetNotFoundError", "InvalidDatasetError",
           "MissingFieldError", "NotReplaceableError", "Split", "StoredDataset", "check_replaceable_dataset",
           "dataset_lock", "load_dataset", "write_dataset"]


class DatasetError(RuntimeError):
    """A dataset on disk is missing, corrupt, truncated or was made with another config."""


class DatasetNotFoundError(DatasetError):
    pass


class InvalidDatasetError(DatasetError, ValueError):
    """A dataset's arrays break its schema (dtype, rows, steps, values; ``data/schema.py``); a ``ValueError`` too."""


class MissingFieldError(DatasetError, KeyError):
    """A split or field the manifest does not list (a ``KeyError`` too, for ``except KeyError`` callers)."""

    def __str__(self) -> str:  # not KeyError's quoted repr
        return str(self.args[0]) if self.args else ""


def check_replaceable_dataset(path: str | Path) -> None:
    """Raise ``NotReplaceableError`` unless ``path`` is absent or one of our datasets (may be replaced)."""
    check_replaceable(path, MANIFEST, SCHEMA_VERSION, WHAT)


def dataset_lock(path: str | Path):
    """The writers' lock of the dataset at ``path`` (``<parent>/.<name>.lock``); see ``io.path_lock``."""
    return path_lock(path)


class Split(dict):
    """One split's ``{field: array}``; a field it lacks is a ``MissingFieldError`` naming it and the path."""

    def __init__(self, path: Path, split: str, fields: Mapping[str, np.ndarray] = ()) -> None:
        super().__init__(fields)
        self.path = path
        self.split = split

    def __missing__(self, field: str) -> np.ndarray:
        raise MissingFieldError(f"Dataset {self.path} has no field {field!r} in split {self.split!r} (its manifest "
                                f"lists {sorted(self)}): it was made by another setting or is incomplete")


@dataclass
class StoredDataset:
    path: Path
    manifest: dict[str, Any]
    splits: dict[str, dict[str, np.ndarray]]

    def __getitem__(self, split: str) -> dict[str, np.ndarray]:
        if split not in self.splits:
            raise MissingFieldError(f"dataset {self.path} has no split {split!r}; it has {sorted(self.splits)}")
        return self.splits[split]

    def require(self, fields: Mapping[str, Any], hint: str = "delete the directory and generate it again") -> None:
        """Raise ``MissingFieldError`` naming every ``{split: [field, ...]}`` the manifest does not list."""
        missing = [f"{split}/{field}.npy" for split, names in fields.items() for field in names
                   if field not in self.splits.get(split, {})]
        if missing:
            raise MissingFieldError(f"Dataset {self.path} lacks {', '.join(missing)} (not in its {MANIFEST}), "
                                    f"which this data setting needs: it was made by another setting or is "
                                    f"incomplete. To fix: {hint}.")


def write_dataset(path: str | Path, splits: Mapping[str, Mapping[str, np.ndarray]], config: Mapping[str, Any],
                  info: Mapping[str, Any] | None = None, overwrite: bool = False) -> Path:
    """Write ``splits`` atomically to ``path``; ``config`` is what generated it (compared on load).

    An existing ``path`` is a ``FileExistsError`` unless ``overwrite``, and a ``NotReplaceableError``
    (never deleted) unless it is one of our datasets.
    """
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    check_replaceable_dataset(path)
    try:
        _write_staged(path, splits, config, info, overwrite)
    except FileExistsError:  # refusals of staged_directory, already one line naming the path
        raise
    except OSError as e:  # staged_directory has removed the staged copy; the path holds what it held
        kept = "the dataset already there is unchanged" if path.exists() else "nothing was written"
        raise storage_error(e, path, "writing the dataset", f"the partial copy was removed, {kept}") from None
    return path


def _write_staged(path: Path, splits: Mapping[str, Mapping[str, np.ndarray]], config: Mapping[str, Any],
                  info: Mapping[str, Any] | None, overwrite: bool) -> None:
    with staged_directory(path, marker=MANIFEST, schema_version=SCHEMA_VERSION, what=WHAT,
                          overwrite=overwrite) as tmp:
        files: dict[str, dict[str, Any]] = {}
        sizes: dict[str, dict[str, list[int]]] = {}
        for split, fields in splits.items():
            (tmp / split).mkdir(parents=True)
            sizes[split] = {}
            for name, array in fields.items():
                array = np.ascontiguousarray(array)
                rel = f"{split}/{name}.npy"
                np.save(tmp / rel, array)
                files[rel] = {"sha256": sha256(tmp / rel), "bytes": (tmp / rel).stat().st_size,
                              "shape": list(array.shape), "dtype": str(array.dtype)}
                sizes[split][name] = list(array.shape)
        manifest = {"schema_version": SCHEMA_VERSION, "config": _config_json(dict(config)),
                    "info": _config_json(dict(info or {})), "sizes": sizes, "files": files}
        with open(tmp / MANIFEST, "w") as f:
            json.dump(manifest, f, indent=2, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())


def _config_json(x: Any) -> Any:
    """Configs go through JSON so that the manifest compares equal to a freshly built config."""
    return json.loads(json.dumps(x, default=lambda o: o.item() if hasattr(o, "item") else str(o)))


def _config_diff(found: Mapping[str, Any], expected: Mapping[str, Any]) -> list[str]:
    keys = sorted(set(found) | set(expected))
    return [f"{k}: on disk {found.get(k, '<missing>')!r}, requested {expected.get(k, '<missing>')!r}"
            for k in keys if found.get(k, "<missing>") != expected.get(k, "<missing>")]


def load_dataset(path: str | Path, expected_config: Mapping[str, Any] | None = None, verify: bool = True,
                 regenerate_hint: str = "delete the directory and generate it again") -> StoredDataset:
    """Open a dataset with memory-mapped arrays, after checking it is whole and made by this config.

    Every problem (a missing or unreadable file, a manifest of the wrong shape, a size, checksum, shape or
    dtype that disagrees with the manifest) is one ``DatasetError`` naming the path and the file.
    """
    path = Path(path)
    fix = f"To fix: {regenerate_hint}."
    if not path.is_dir():
        raise DatasetNotFoundError(f"No dataset at {path}. {fix}")
    try:
        manifest = json.loads((path / MANIFEST).read_text())
    except FileNotFoundError:
        raise DatasetError(f"Dataset {path} has no {MANIFEST}: it is incomplete or not a dataset. {fix}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise DatasetError(f"Dataset {path}: {MANIFEST} is corrupt ({_one_line(e)}). {fix}") from None
    except OSError as e:
        raise DatasetError(f"Dataset {path}: cannot read {MANIFEST} ({e.strerror or e}). {fix}") from None
    if not isinstance(manifest, dict):
        raise DatasetError(f"Dataset {path}: {MANIFEST} is corrupt (a JSON {type(manifest).__name__}, not an "
                           f"object). {fix}")
    version = manifest.get("schema_version")
    if version != SCHEMA_VERSION:
        raise DatasetError(f"Dataset {path} has schema version {version!r}, this code reads {SCHEMA_VERSION}. {fix}")
    for key in ("config", "info", "sizes", "files"):
        if not isinstance(manifest.setdefault(key, {}), dict):
            raise DatasetError(f"Dataset {path}: {MANIFEST} is corrupt (its {key!r} is a JSON "
                               f"{type(manifest[key]).__name__}, not an object). {fix}")
    if expected_config is not None:
        diff = _config_diff(manifest["config"], _config_json(dict(expected_config)))
        if diff:
            raise DatasetError(f"Dataset {path} was generated with a different config:\n  "
                               + "\n  ".join(diff) + f"\n{fix}")
    splits: dict[str, dict[str, np.ndarray]] = {}
    for rel, meta in manifest["files"].items():
        parts = rel.split("/")
        if (len(parts) != 2 or not rel.endswith(".npy") or not all(parts) or set(parts) & {".", ".."}
                or "\\" in rel or not isinstance(meta, dict) or not _is_count(meta.get("bytes"))
                or not isinstance(meta.get("sha256"), str)):
            raise DatasetError(f"Dataset {path}: {MANIFEST} is corrupt (bad file entry {rel!r}: {meta!r}; "
                               f"expected \"<split>/<field>.npy\" with bytes and sha256). {fix}")
        array = _open_array(path, rel, meta, verify, fix)
        split, name = parts
        splits.setdefault(split, Split(path, split))[name.removesuffix(".npy")] = array
    return StoredDataset(path=path, manifest=manifest, splits=splits)


def _is_count(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())[:300] or type(e).__name__


def _open_array(path: Path, rel: str, meta: dict[str, Any], verify: bool, fix: str) -> np.ndarray:
    """The memory map of one listed file, after its size, checksum (``verify``), shape and dtype are checked."""
    file = path / rel
    try:
        if not file.is_file():
            raise DatasetError(f"Dataset {path}: file {rel} is missing. {fix}")
        size = file.stat().st_size
        if size != meta["bytes"]:
            raise DatasetError(f"Dataset {path}: {rel} is {size} bytes, the manifest says {meta['bytes']} "
                               f"(truncated or overwritten). {fix}")
        if verify and sha256(file) != meta["sha256"]:
            raise DatasetError(f"Dataset {path}: {rel} fails its SHA-256 checksum (corrupt). {fix}")
        array = np.load(file, mmap_mode="r", allow_pickle=False)
    except OSError as e:
        raise DatasetError(f"Dataset {path}: cannot read {rel} ({e.strerror or _one_line(e)}). {fix}") from None
    except (ValueError, EOFError) as e:  # a header numpy cannot parse, object arrays, more data declared than held
        raise DatasetError(f"Dataset {path}: {rel} is not a readable .npy file ({_one_line(e)}). {fix}") from None
    if not isinstance(array, np.ndarray):  # np.load opened a zip archive (an .npz) as a mapping
        array.close()
        raise DatasetError(f"Dataset {path}: {rel} is not a .npy array file. {fix}")
    declared = (meta.get("shape"), meta.get("dtype"))
    found = (list(array.shape), str(array.dtype))
    if declared[0] is not None and declared[0] != found[0] or declared[1] is not None and declared[1] != found[1]:
        raise DatasetError(f"Dataset {path}: {rel} holds shape {found[0]}, dtype {found[1]}; the manifest says "
                           f"shape {declared[0]}, dtype {declared[1]} (overwritten). {fix}")
    return array
