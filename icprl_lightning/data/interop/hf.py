"""Our datasets as Hugging Face ``datasets`` tables: a ``DatasetDict`` saved to disk (Arrow), or Parquet files.

One table per split, one row per context, one column per field (a field's per-row shape becomes its feature:
docs/data_formats.md); a split whose fields disagree in row count (``tasks``) is one table per field,
``<split>.<field>``. The manifest travels as JSON (``provenance.py``): in each Arrow table's
``DatasetInfo.description``, in each Parquet file's key-value metadata under ``icprl`` (``datasets``' own
Parquet reader drops it, so the import reads Parquet with pyarrow). Nothing here touches the Hugging Face cache.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.interop.provenance import KEY, ExportError, dumps, parse, provenance, restore
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.io import staged_directory

PARQUET_SUFFIX = ".parquet"
HF_INDEX = "dataset_dict.json"  # what save_to_disk writes for a DatasetDict


def _datasets():
    import datasets

    datasets.disable_progress_bars()
    return datasets


def feature(name: str, x: np.ndarray):
    """The ``datasets`` feature of one row of ``x`` (``x[0]``), with ``x``'s dtype."""
    datasets = _datasets()
    dtype = "bool" if x.dtype == np.bool_ else x.dtype.name
    row = x.shape[1:]
    arrays = {2: datasets.Array2D, 3: datasets.Array3D, 4: datasets.Array4D, 5: datasets.Array5D}
    if len(row) == 0:
        return datasets.Value(dtype)
    if len(row) == 1:  # a fixed length of 0 is refused by ``datasets``: rows of no values are empty lists
        return datasets.List(datasets.Value(dtype), length=row[0] if row[0] else -1)
    if len(row) in arrays:
        return arrays[len(row)](shape=row, dtype=dtype)
    raise ExportError(f"field {name!r} has shape {list(x.shape)}: a table row holds at most 5 axes")


def tables(dataset: StoredDataset) -> dict[str, tuple[str, list[str]]]:
    """``{table name: (split, fields)}``: one table per split, or per field where a split's row counts differ."""
    out: dict[str, tuple[str, list[str]]] = {}
    for split, fields in dataset.splits.items():
        rows = {x.shape[0] if x.ndim else None for x in fields.values()}
        if len(rows) == 1 and None not in rows:
            out[split] = (split, list(fields))
        else:
            out.update({f"{split}.{field}": (split, [field]) for field in fields})
    return out


def _table_dataset(dataset: StoredDataset, split: str, fields: list[str], description: str):
    datasets = _datasets()
    columns = {f: np.asarray(dataset[split][f]) for f in fields}
    columns = {f: x if x.ndim else x.reshape(1) for f, x in columns.items()}  # a scalar: a table of one row
    features = datasets.Features({f: feature(f"{split}/{f}", x) for f, x in columns.items()})
    columns = {f: [[]] * len(x) if x.shape[1:] == (0,) else x for f, x in columns.items()}
    info = datasets.DatasetInfo(description=description, features=features)
    return datasets.Dataset.from_dict(columns, info=info)


def export_hf(dataset: StoredDataset, out: str | Path) -> Path:
    """Write ``dataset`` as a ``DatasetDict`` saved to disk at ``out`` (a new directory)."""
    datasets = _datasets()
    layout = tables(dataset)
    description = dumps(provenance(dataset, layout))
    parts = {name: _table_dataset(dataset, split, fields, description) for name, (split, fields) in layout.items()}
    with staged_directory(out, marker=HF_INDEX, schema_version=0, what="Hugging Face export") as tmp:
        # one shard per table: an empty table (a val split of none) still gets a file load_from_disk reads
        datasets.DatasetDict(parts).save_to_disk(str(tmp), num_shards=dict.fromkeys(parts, 1))
    return Path(out)


def export_parquet(dataset: StoredDataset, out: str | Path) -> Path:
    """Write ``dataset`` as one ``<table>.parquet`` per table in ``out`` (a new directory)."""
    import pyarrow.parquet as pq

    layout = tables(dataset)
    text = dumps(provenance(dataset, layout)).encode()
    first = f"{next(iter(layout))}{PARQUET_SUFFIX}"
    with staged_directory(out, marker=first, schema_version=0, what="Parquet export") as tmp:
        for name, (split, fields) in layout.items():
            table = _table_dataset(dataset, split, fields, "").data.table
            table = table.replace_schema_metadata({**(table.schema.metadata or {}), KEY.encode(): text})
            pq.write_table(table, tmp / f"{name}{PARQUET_SUFFIX}")
    return Path(out)


def _flat(column) -> np.ndarray:
    """The values of an Arrow column (lists and ``ArrayND`` nested any deep) in row-major order, in their dtype.

    Read from Arrow itself: ``datasets``' numpy formatter would turn ``float64`` lists into ``float32``.
    """
    import pyarrow as pa

    array = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    while True:
        if isinstance(array, pa.ExtensionArray):
            array = array.storage
        elif pa.types.is_list(array.type) or pa.types.is_large_list(array.type) or \
                pa.types.is_fixed_size_list(array.type):
            array = array.flatten()
        else:
            return array.to_numpy(zero_copy_only=False)


def _columns(table) -> dict[str, np.ndarray]:
    """``{column: flat values}`` of an Arrow table (``provenance.restore`` gives them their declared shapes)."""
    return {name: _flat(table.column(name)) for name in table.column_names}


def _split_arrays(found: dict[str, Any], read: dict[str, dict[str, np.ndarray]], where: str
                  ) -> dict[str, dict[str, Any]]:
    layout = found.get("tables")
    if not isinstance(layout, dict):
        raise ExportError(f"{where}: its provenance has no table layout")
    missing = sorted(set(layout) - set(read))
    if missing:
        raise ExportError(f"{where} lacks tables {missing} its provenance lists: the export is incomplete")
    splits: dict[str, dict[str, Any]] = {}
    for name, (split, fields) in layout.items():
        absent = [f for f in fields if f not in read[name]]
        if absent:
            raise ExportError(f"{where}: table {name!r} lacks columns {absent} (split {split!r})")
        splits.setdefault(split, {}).update({f: read[name][f] for f in fields})
    return splits


def import_hf(source: str | Path, out: str | Path, overwrite: bool = False) -> Path:
    """Rebuild the dataset a ``DatasetDict`` export at ``source`` came from (``provenance.restore``)."""
    datasets = _datasets()
    source = Path(source)
    if not (source / HF_INDEX).is_file():
        raise ExportError(f"{source} is not a Hugging Face DatasetDict saved to disk (no {HF_INDEX})")
    parts = datasets.load_from_disk(str(source))
    found = parse(next(iter(parts.values())).info.description if len(parts) else None, str(source))
    for name, part in parts.items():
        if part.info.description != next(iter(parts.values())).info.description:
            raise ExportError(f"{source}: table {name!r} carries another provenance than the others")
    splits = _split_arrays(found, {name: _columns(part.data.table) for name, part in parts.items()}, str(source))
    return restore(splits, found, out, str(source), overwrite)


def import_parquet(source: str | Path, out: str | Path, overwrite: bool = False) -> Path:
    """Rebuild the dataset a Parquet export (a directory of ``<table>.parquet``) came from."""
    import pyarrow.parquet as pq

    source = Path(source)
    files = sorted(source.glob(f"*{PARQUET_SUFFIX}")) if source.is_dir() else []
    if not files:
        raise ExportError(f"{source} holds no {PARQUET_SUFFIX} files (a Parquet export is a directory of them)")
    texts = {f.name: (pq.read_schema(f).metadata or {}).get(KEY.encode()) for f in files}
    found = parse(texts[files[0].name], str(files[0]))
    differ = [name for name, text in texts.items() if text != texts[files[0].name]]
    if differ:
        raise ExportError(f"{source}: {differ} carry another provenance than {files[0].name}")
    read = {f.name.removesuffix(PARQUET_SUFFIX): _columns(pq.read_table(f)) for f in files}
    splits = _split_arrays(found, read, str(source))
    return restore(splits, found, out, str(source), overwrite)
