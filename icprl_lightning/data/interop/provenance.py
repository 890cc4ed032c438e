"""The manifest that travels with an exported dataset, and the byte-for-value check that brings it back.

An export carries the dataset's whole ``manifest.json`` in the foreign format's metadata (``provenance``).
``restore`` casts every array read back to its manifest entry's dtype and shape and requires the SHA-256 the
manifest recorded before writing anything: an import reproduces the exported dataset file for file or is
refused, naming the split and field. An export edited in its foreign form is therefore refused: a generated
dataset's config must not vouch for other data.
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
    _check_fields(found, where)
    return found


def _check_fields(found: Mapping[str, Any], where: str) -> None:
    """Every entry a reader of the provenance indexes has the type it expects; else one ``ExportError`` naming the
    field (a forged export would otherwise fail with a raw ``KeyError`` or ``TypeError``)."""
    def fail(field: str, expected: str, value: Any) -> None:
        raise ExportError(f"{where}: its {KEY!r} metadata's {field} must be {expected}, got {value!r}"[:400])

    manifest = found["manifest"]
    for key in ("config", "info"):
        if not isinstance(manifest.get(key, {}), dict):
            fail(f"manifest.{key}", "a mapping", manifest[key])
    for rel, meta in manifest["files"].items():
        field = f"manifest.files[{rel!r}]"
        if not isinstance(rel, str) or not rel.endswith(".npy") or rel.count("/") != 1:
            fail(field, "named <split>/<field>.npy", rel)
        if not isinstance(meta, dict) or not isinstance(meta.get("sha256"), str):
            fail(field, "a mapping with a sha256 string", meta)
        shape = meta.get("shape")
        if not isinstance(shape, list) or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0
                                                  for n in shape):
            fail(f"{field}.shape", "a list of sizes", shape)
        try:
            numeric = np.dtype(meta.get("dtype")).kind in "biuf"
        except (TypeError, ValueError):
            numeric = False
        if not numeric or not isinstance(meta.get("dtype"), str):
            fail(f"{field}.dtype", "a numeric dtype name", meta.get("dtype"))
    for name, layout in (found.get("tables") or {}).items() if isinstance(found.get("tables"), dict) else ():
        if not (isinstance(layout, list) and len(layout) == 2 and isinstance(layout[0], str)
                and isinstance(layout[1], list) and all(isinstance(f, str) for f in layout[1])):
            fail(f"tables[{name!r}]", "[split, [field, ...]]", layout)


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
