"""Reward contexts as Minari datasets: each context row an episode of observations, actions and rewards.

Minari episodes need T + 1 observations, so only reward contexts whose next states chain (rollouts) are
episodes; other kinds are refused, naming the formats that carry them (``hf``, ``parquet``). The layout
(docs/data_formats.md): a namespace ``icprl`` whose metadata holds the provenance and the non-episode splits,
one dataset ``icprl/<split>-v0`` per context split, episode ``i`` = row ``i``, the row's other fields in
``infos`` as ``[T + 1, k]`` (Minari's Arrow storage cannot read 1-D infos back). ``MINARI_DATASETS_PATH``
points at ``--out`` only while writing or reading, never at the user's home.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.interop.provenance import KEY, ExportError, context_kind, parse, provenance, restore
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.io import staged_directory

NAMESPACE = "icprl"
VERSION = "v0"
EPISODE_FIELDS = ("states", "actions", "rewards", "next_states")
MINARI_KINDS = ("reward",)
ROOT_ENV = "MINARI_DATASETS_PATH"
NAMESPACE_METADATA = "namespace_metadata.json"


@contextmanager
def minari_root(path: Path) -> Iterator[None]:
    """``MINARI_DATASETS_PATH`` set to ``path`` inside the block, restored after it."""
    before = os.environ.get(ROOT_ENV)
    os.environ[ROOT_ENV] = str(path)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(ROOT_ENV, None)
        else:
            os.environ[ROOT_ENV] = before


def dataset_id(split: str) -> str:
    return f"{NAMESPACE}/{split}-{VERSION}"


def _episode_splits(dataset: StoredDataset) -> list[str]:
    return [split for split, fields in dataset.splits.items() if set(EPISODE_FIELDS) <= set(fields)]


def _check_episodes(dataset: StoredDataset, splits: list[str]) -> None:
    kind = context_kind(dataset.manifest)
    if kind not in MINARI_KINDS:
        raise ExportError(f"Minari stores episodes (observations, actions, rewards); dataset {dataset.path} holds "
                          f"{kind!r} contexts, which are not episodes: export it with --format hf or --format "
                          f"parquet (Minari takes the kinds {list(MINARI_KINDS)})")
    if not splits:
        raise ExportError(f"dataset {dataset.path} has no split with fields {list(EPISODE_FIELDS)}")
    for split in splits:
        s, s_next = np.asarray(dataset[split]["states"]), np.asarray(dataset[split]["next_states"])
        same = _bytes(s[:, 1:]) == _bytes(s_next[:, :-1])  # bytewise: -0.0 and 0.0 differ, as in the files
        same = same.reshape(len(s), -1).all(1)
        if not same.all():
            row = int(np.argmin(same))
            raise ExportError(f"dataset {dataset.path}, split {split!r}, row {row}: next_states differs from the "
                              "following step's states, so its contexts are independent transitions, not episodes "
                              "Minari can hold; export it with --format hf or --format parquet")


def _spaces(dataset: StoredDataset, splits: list[str]):
    import gymnasium as gym

    first = dataset[splits[0]]
    observation = gym.spaces.Box(-np.inf, np.inf, first["states"].shape[2:], np.float32)
    actions = first["actions"]
    if actions.ndim == 3:
        return observation, gym.spaces.Box(-np.inf, np.inf, actions.shape[2:], np.float32)
    n = max(int(np.max(dataset[split]["actions"], initial=0)) for split in splits) + 1
    return observation, gym.spaces.Discrete(n)


def _bytes(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x).view(np.uint8)


def _per_step(shape: tuple[int, ...] | list[int], t: int) -> bool:
    """Whether a field of ``shape`` ([N, ...]) has one entry per step of contexts of ``t`` steps."""
    return len(shape) > 1 and shape[1] == t


def _pad(x: np.ndarray) -> np.ndarray:
    """A per-step array of T entries as the T + 1 of an episode's ``infos`` (the last one repeated)."""
    return np.concatenate([x, x[-1:]])


def _episodes(fields: dict[str, np.ndarray]):
    from minari.data_collector import EpisodeBuffer

    states, actions, rewards, next_states = (np.asarray(fields[f]) for f in EPISODE_FIELDS)
    extras = {f: np.asarray(x) for f, x in fields.items() if f not in EPISODE_FIELDS}
    t = states.shape[1]
    for i in range(len(states)):
        infos = {f: (_pad(x[i]) if _per_step(x.shape, t) else np.repeat(x[i:i + 1], t + 1, 0)).reshape(t + 1, -1)
                 for f, x in extras.items()}  # at least [T + 1, 1]: Minari's arrow storage cannot decode 1-D infos
        yield EpisodeBuffer(id=i, observations=np.concatenate([states[i], next_states[i, -1:]]),
                            actions=actions[i], rewards=rewards[i], terminations=np.zeros(t, bool),
                            truncations=np.arange(t) == t - 1, infos=infos or None)


def _exact_json(x: np.ndarray) -> dict[str, Any]:
    return {"dtype": x.dtype.str, "shape": list(x.shape), "values": np.asarray(x).tolist()}


def export_minari(dataset: StoredDataset, out: str | Path) -> Path:
    """Write ``dataset`` (reward contexts) as the namespace ``icprl`` of the Minari root ``out`` (a new directory)."""
    import minari
    from minari.namespace import create_namespace

    splits = _episode_splits(dataset)
    _check_episodes(dataset, splits)
    observation_space, action_space = _spaces(dataset, splits)
    others = {split: {f: _exact_json(np.asarray(x)) for f, x in fields.items()}
              for split, fields in dataset.splits.items() if split not in splits}
    marker = f"{NAMESPACE}/{NAMESPACE_METADATA}"
    with (staged_directory(out, marker=marker, schema_version=0, what="Minari export") as tmp, minari_root(tmp),
          warnings.catch_warnings()):
        warnings.simplefilter("ignore", UserWarning)  # Minari's reminders of an author e-mail and env spec
        create_namespace(NAMESPACE, description=f"icprl dataset {dataset.path}, exported by icprl export-data",
                         **{KEY: {**provenance(dataset), "splits": splits, "arrays": others}})
        for split in splits:
            extras = {f: x for f, x in dataset[split].items() if f not in EPISODE_FIELDS}
            per_step = [f for f, x in extras.items() if _per_step(x.shape, dataset[split]["states"].shape[1])]
            minari.create_dataset_from_buffers(
                dataset_id(split), list(_episodes(dict(dataset[split]))), action_space=action_space,
                observation_space=observation_space, algorithm_name="icprl", author="icprl export-data",
                code_permalink="icprl_lightning/data/interop/minari_format.py", data_format="arrow",
                description=(f"split {split!r} of the icprl dataset {dataset.path}: one episode per context row; "
                             f"infos hold {per_step} per step and {sorted(set(extras) - set(per_step))} per row"))
    return Path(out)


def _read_split(split: str, shapes: dict[str, list[int]]) -> dict[str, np.ndarray]:
    """``{field: [N, ...]}`` of one exported split (its fields' manifest shapes ``shapes``), from its episodes."""
    import minari

    dataset = minari.load_dataset(dataset_id(split))
    t = shapes["states"][1]
    columns: dict[str, list[np.ndarray]] = {f: [] for f in shapes}
    for episode in dataset.iterate_episodes():
        obs = np.asarray(episode.observations)
        step = {"states": obs[:-1], "next_states": obs[1:], "actions": np.asarray(episode.actions),
                "rewards": np.asarray(episode.rewards)}
        for f in shapes:
            if f in step:
                columns[f].append(step[f])
            elif f in episode.infos:
                info = np.asarray(episode.infos[f])
                columns[f].append(info[:-1] if _per_step(shapes[f], t) else info[0])
            else:
                raise ExportError(f"Minari dataset {dataset_id(split)}, episode {episode.id}: no info {f!r}")
    return {f: np.stack(v) if v else np.zeros(0) for f, v in columns.items()}


def import_minari(source: str | Path, out: str | Path, overwrite: bool = False) -> Path:
    """Rebuild the dataset a Minari export (the root ``source``, holding the namespace ``icprl``) came from."""
    source = Path(source)
    meta_file = source / NAMESPACE / NAMESPACE_METADATA
    if not meta_file.is_file():
        raise ExportError(f"{source} is not a Minari root exported by `icprl export-data` (no {NAMESPACE}/"
                          f"{NAMESPACE_METADATA}); pass the directory given to --out")
    try:
        meta = json.loads(meta_file.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ExportError(f"{meta_file}: unreadable ({e})") from None
    found = parse(json.dumps(meta.get(KEY)) if isinstance(meta, dict) and KEY in meta else None, str(meta_file))
    shapes = {rel.removesuffix(".npy"): m["shape"] for rel, m in found["manifest"]["files"].items()}
    splits: dict[str, dict[str, Any]] = {}
    with minari_root(source):
        for split in found.get("splits", []):
            splits[split] = _read_split(split, {rel.split("/")[1]: shape for rel, shape in shapes.items()
                                                if rel.split("/")[0] == split})
    for split, fields in found.get("arrays", {}).items():
        splits[split] = {f: np.asarray(a["values"], dtype=np.dtype(a["dtype"])).reshape(a["shape"])
                         for f, a in fields.items()}
    return restore(splits, found, out, str(source), overwrite)
