"""Checkpoint files that are always complete: written to a temporary file beside the target, then renamed.

Lightning's ``TorchCheckpointIO`` serializes to memory and writes through an fsspec transaction, whose
temporary file lives in ``$TMPDIR``; when the run directory is on another file system the final move is a
copy into the target, so a kill or a full disk during it leaves a truncated ``last.ckpt`` and the previous
good one is gone. Here the temporary file is created in the target's own directory, flushed to disk and
``os.replace``-d over the target, a rename within one file system and so atomic: a reader sees the old
file or the new one, never a part. If the target is a symlink (``ModelCheckpoint(save_last="link")``)
the link itself is replaced by the file. On any failure the temporary file is removed and the error
raised; the previous file is untouched. Remote (non-local) paths keep Lightning's own IO. ``AsyncCheckpointIO``
saves through this writer in its thread; any other checkpoint IO is refused (``use_atomic_saves``).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from typing import Any

import lightning as L
import torch
from lightning.fabric.utilities.cloud_io import _is_local_file_protocol
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.plugins.io.wrapper import _WrappingCheckpointIO


class AtomicCheckpointIO(TorchCheckpointIO):
    """``TorchCheckpointIO`` whose local saves are a write to ``.<name>.<hex>.tmp`` in the same directory,
    an fsync, and a rename over ``path``."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None) -> None:
        if storage_options is not None or not _is_local_file_protocol(path):
            super().save_checkpoint(checkpoint, path, storage_options=storage_options)
            return
        path = os.path.abspath(os.fspath(path))
        directory, name = os.path.split(path)
        os.makedirs(directory, exist_ok=True)
        temporary = os.path.join(directory, f".{name}.{secrets.token_hex(4)}.tmp")
        # O_EXCL: never write into a file someone else made; mode 0o666 minus the umask, as open() would
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with os.fdopen(fd, "wb") as file:
                torch.save(checkpoint, file)
                file.flush()
                os.fsync(file.fileno())  # the bytes are on disk before the name points at them
            os.replace(temporary, path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)
            raise
        _fsync_directory(directory)


def _fsync_directory(directory: str) -> None:
    """Make the rename itself durable (best effort: some file systems refuse to open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def use_atomic_saves(trainer: L.Trainer) -> None:
    """Make every checkpoint ``trainer`` saves atomic, whatever the callback that saves it.

    Lightning's default IO is replaced; a wrapper such as ``AsyncCheckpointIO`` (saves in a thread) keeps
    wrapping, around the atomic writer instead of the plain one. Any other IO (a user's, a remote one) is
    refused with a ``ValueError`` naming it, before anything is saved: it could leave a partial ``last.ckpt``.
    Set on the strategy rather than passed as a Trainer plugin so that a config's own ``trainer.plugins``
    cannot silently drop it.
    """
    io = trainer.strategy.checkpoint_io
    if type(io) is TorchCheckpointIO:
        trainer.strategy.checkpoint_io = AtomicCheckpointIO()
        return
    wrapper = None
    while isinstance(io, _WrappingCheckpointIO):
        wrapper, io = io, io.checkpoint_io
    if wrapper is not None and (io is None or type(io) is TorchCheckpointIO):
        wrapper._checkpoint_io = AtomicCheckpointIO()  # the setter keeps a configured base; this one is Lightning's
    elif not isinstance(io, AtomicCheckpointIO):
        raise ValueError(f"trainer.plugins: {type(io).__name__} writes checkpoints its own way, which can leave a "
                         "partial last.ckpt; icprl_lightning writes every checkpoint atomically (AtomicCheckpointIO, "
                         "callbacks/atomic_io.py): drop the plugin, or pass AsyncCheckpointIO without a checkpoint_io "
                         "(it then saves through the atomic writer)")
