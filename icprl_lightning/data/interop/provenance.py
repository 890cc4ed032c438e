"""The manifest that travels with an exported dataset, and the byte-for-value check that brings it back.

An export (``hf``, ``parquet``, ``minari``) carries the dataset's whole ``manifest.json`` (schema version,
generator config, seed, info, and per file its shape, dtype and SHA-256) inside the foreign format's own
metadata, as the JSON object ``provenance(dataset)``. Importing an export is ``restore``: every array read
back is cast to the dtype and shape its manifest entry declares and saved as ``.npy`` bytes in memory, and
those bytes must have the SHA-256 the manifest recorded; only then is the dataset written, by
``store.write_dataset`` with the manifest's own config and info. So an import either reproduces the exported
dataset file for file (the same ``.npy`` bytes, the same ``manifest.json``) or is refused, naming the split
and field that changed. An export edited in its foreign form (rows filtered, values rescaled) is therefore
refused: its manifest no longer describes it, and a generated dataset's config must not vouch for other data.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.store import SCHEMA_VERSION, StoredDataset, write_dataset
from icprl_lightning.untrusted import UntrustedFileError, parse_json

KEY = "icprl"  # the metadata key (Parquet, Minari) or JSON object (HF description) that holds the provenance
EXPORT_VERSION = 1


class ExportError(ValueError):
    """An export that cannot be read back: no provenance, a changed or missing array, an unknown layout."""


def provenance(dataset: StoredDataset, tables: Mapping[str, tuple[str, list[str]]] | None = None) -> dict[str, Any]:
    """The JSON object an export carries: its version, the manifest, ``{table: (split, fields)}`` (tables only)."""
    out: dict[str, Any] = {"export_version": EXPORT_VERSION, "source": str(dataset.path),
                           "manifest": dataset.manifest}
    if tables is not None:
        out["tables"] = {name: [split, list(fields)] for name, (split, fields) in tables.items()}
    return out


def parse(text: str | bytes | None, where: str) -> dict[str, Any]:
    """The provenance object of an export from its serialized form; ``ExportError`` naming ``where`` if absent."""
    if text is None or not text:
        raise ExportError(f"{where} carries no icprl provenance (no {KEY!r} metadata): it is not an export of "
                          "`icprl export-data`; import foreign preference rows with --format trl or --format bpref")
    try:
        found = parse_json(text, f"{where}: its {KEY!r} metadata")
    except UntrustedFileError as e:
        raise ExportError(f"{e}; it is corrupt") from None
    if not isinstance(found, dict) or not isinstance(found.get("manifest"), dict):
        raise ExportError(f"{where}: its {KEY!r} metadata has no manifest object; it is not an icprl export")
    if found.get("export_version") != EXPORT_VERSION:
        raise ExportError(f"{where} has export version {found.get('export_version')!r}, this code reads "
                          f"{EXPORT_VERSION}")
    manifest = found["manifest"]
    if manifest.get("schema_version") != SCHEMA_VERSION or not isinstance(manifest.get("files"), dict):
        raise ExportError(f"{where}: its manifest has schema version {manifest.get('schema_version')!r} (this "
                          f"code reads {SCHEMA_VERSION}) or no file list")
    return found


def dumps(found: Mapping[str, Any]) -> str:
    return json.dumps(found, sort_keys=True)


def expected_fields(manifest: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """``{"<split>/<field>": {"shape", "dtype", "sha256"}}`` from the manifest's file list."""
    return {rel.removesuffix(".npy"): meta for rel, meta in manifest["files"].items()}


def _npy_sha256(array: np.ndarray) -> str:
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(array))
    return hashlib.sha256(buffer.getvalue()).hexdigest()


def as_declared(name: str, value: Any, meta: Mapping[str, Any], where: str) -> np.ndarray:
    """``value`` as the dtype and shape the manifest declares for ``name`` ("<split>/<field>"), checked by SHA-256."""
    dtype, shape = np.dtype(meta["dtype"]), tuple(meta["shape"])
    x = np.asarray(value)
    if x.size != int(np.prod(shape, dtype=np.int64)):
        raise ExportError(f"{where}: field {name!r} holds {x.size} values (shape {list(x.shape)}), the manifest "
                          f"declares shape {list(shape)}: the export was changed after `icprl export-data`")
    with np.errstate(all="ignore"):
        x = x.astype(dtype).reshape(shape)
    if _npy_sha256(x) != meta["sha256"]:
        raise ExportError(f"{where}: field {name!r} differs from the exported dataset (its SHA-256 does not match "
                          "the manifest's): the export was changed after `icprl export-data`; export it again")
    return x


def restore(splits: Mapping[str, Mapping[str, Any]], found: Mapping[str, Any], out: str | Path, where: str,
            overwrite: bool = False) -> Path:
    """Write ``{split: {field: values}}`` read from an export as the dataset its provenance describes.

    Every field the manifest lists must be present (and no other); each is checked by ``as_declared``.
    """
    manifest = found["manifest"]
    declared = expected_fields(manifest)
    read = {f"{split}/{field}" for split, fields in splits.items() for field in fields}
    missing, extra = sorted(set(declared) - read), sorted(read - set(declared))
    if missing or extra:
        raise ExportError(f"{where}: fields {missing} are missing and {extra} are not in the exported manifest: the "
                          "export was changed after `icprl export-data`")
    arrays: dict[str, dict[str, np.ndarray]] = {}
    for rel in declared:  # the manifest's order: the rebuilt manifest lists the same files
        split, field = rel.split("/")
        arrays.setdefault(split, {})[field] = as_declared(rel, splits[split][field], declared[rel], where)
    return write_dataset(out, arrays, manifest.get("config", {}), info=manifest.get("info", {}), overwrite=overwrite)


def context_kind(manifest: Mapping[str, Any]) -> str | None:
    """The context kind a dataset holds: a generated one's ``context_kind``, an imported one's ``kind``."""
    config = manifest.get("config", {})
    return config.get("context_kind", config.get("kind"))
