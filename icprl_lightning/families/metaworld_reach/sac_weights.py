"""The SAC oracle as plain weights: a small, versioned, checksummed directory that loads without pickle.

A trained SAC oracle (``sac.py``) is a directory of Stable-Baselines3 zips, which ``SAC.load`` reads by
unpickling: not something to load from an untrusted place. ``export_sac_oracle`` reads from each zip only the
``policy.pth`` member, with ``torch.load(weights_only=True)``, and from the run only its ``summary.json``, so
exporting an untrusted run never runs code from it. It keeps what data generation needs (appendix "Pretraining
Data Generation"): the actor of each behavior checkpoint (chosen by its return normalized between uniform
actions and the final policy) and of the final policy π, and the final twin critic, whose minimum Q̂ gives
A*(s, a) ≈ Q̂(s, a) − E_{a'~π} Q̂(s, a'); plus ``oracle.json`` and ``SHA256SUMS``. ``ExportedSAC`` verifies every
checksum and loads the tensors into ``SACActor`` / ``SACCritic`` (SB3's ``MlpPolicy`` layers; tested against
SB3's own networks on the same weights); Q̂ is divided by the run's ``reward_scale`` (latent-return units).

    icprl oracle export runs/sac_oracle/A --out icprl_lightning/families/metaworld_reach/sac_oracle_v1
"""

from __future__ import annotations

import io
import json
import re
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from icprl_lightning.families.metaworld_reach.env import ACTION_DIM, OBS_DIM
from icprl_lightning.io import sha256, staged_directory
from icprl_lightning.untrusted import check_torch_archive, read_json

MANIFEST = "oracle.json"
CHECKSUMS = "SHA256SUMS"
FORMAT_VERSION = 1
WHAT = "exported SAC oracle directory"
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SB3's clamp of the actor's log-std
HIDDEN = 256
FINAL = 1.0  # the level of the final (converged) policy
DEFAULT_TARGETS = (0.2, 0.4, 0.5, 0.8)  # I-PRL's 20/80% pair, the 40% medium contexts, T-PRL's 50%
MAX_POLICY_BYTES = 256 << 20  # a policy.pth inflated (Reach's SAC: ~3 MB)
POLICY_MEMBER = "policy.pth"  # the SB3 zip member holding the policy's state dict (actor, critic, target critic)


def _mlp(inputs: int, outputs: int | None) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Linear(inputs, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU()]
    if outputs is not None:
        layers.append(nn.Linear(HIDDEN, outputs))
    return nn.Sequential(*layers)


class SACActor(nn.Module):
    """SB3's SAC actor for goal-visible Reach observations [B, 39] -> squashed-Gaussian parameters [B, 4]."""

    def __init__(self) -> None:
        super().__init__()
        self.latent_pi = _mlp(OBS_DIM, None)
        self.mu = nn.Linear(HIDDEN, ACTION_DIM)
        self.log_std = nn.Linear(HIDDEN, ACTION_DIM)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        latent = self.latent_pi(obs)
        return self.mu(latent), self.log_std(latent).clamp(LOG_STD_MIN, LOG_STD_MAX)


class SACCritic(nn.Module):
    """SB3's twin critic: Q_0, Q_1 of (obs [B, 39], action [B, 4]); ``forward`` gives their minimum [B]."""

    def __init__(self) -> None:
        super().__init__()
        self.qf0 = _mlp(OBS_DIM + ACTION_DIM, 1)
        self.qf1 = _mlp(OBS_DIM + ACTION_DIM, 1)

    def forward(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        x = torch.cat([obs, actions], dim=-1)
        return torch.minimum(self.qf0(x), self.qf1(x)).squeeze(-1)


def _level_name(level: float) -> str:
    return f"{round(100 * level):03d}"


def sb3_policy_tensors(path: str | Path) -> dict[str, torch.Tensor]:
    """The state dict in an SB3 zip's ``policy.pth`` member, read with ``weights_only=True``; the rest of the zip
    (``data``'s cloudpickled objects, optimizer states) is never read. Anything else is a ``ValueError`` naming
    the file."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            if POLICY_MEMBER not in archive.namelist():
                raise ValueError(f"{path} is not a Stable-Baselines3 checkpoint: no {POLICY_MEMBER} member")
            with archive.open(POLICY_MEMBER) as member:  # inflated up to the bound, never beyond it
                raw = member.read(MAX_POLICY_BYTES + 1)
    except (OSError, zipfile.BadZipFile, zlib.error, EOFError) as e:
        raise ValueError(f"{path} is not a readable Stable-Baselines3 zip ({type(e).__name__}: {e})") from None
    if len(raw) > MAX_POLICY_BYTES:
        raise ValueError(f"{path}: its {POLICY_MEMBER} inflates beyond {MAX_POLICY_BYTES:,} bytes; a Reach SAC "
                         "policy is a few MB, so this file is forged or not an oracle checkpoint")
    return _tensors(raw, f"{path}: its {POLICY_MEMBER}")


def _tensors(source: Path | bytes, where: str) -> dict[str, torch.Tensor]:
    """A ``torch.save`` file (a path or its bytes), bounded (``check_torch_archive``) and read with
    ``weights_only=True``: a state dict of tensors, else a ``ValueError`` naming ``where``."""
    check_torch_archive(source, where)
    try:
        state = torch.load(io.BytesIO(source) if isinstance(source, bytes) else source, map_location="cpu",
                           weights_only=True)
    except Exception as e:  # an UnpicklingError for a pickle naming a disallowed global; others for a damaged file
        named = re.search(r"GLOBAL (\S+)", str(e))
        why = f"its pickle names {named.group(1)}" if named else f"{type(e).__name__}: {str(e)[:200]}"
        raise ValueError(f"{where} was refused: it holds more than tensors (pickled objects, which could run "
                         f"code) or is damaged ({' '.join(why.split())})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{where} is not a state dict of tensors")
    return state


def _load_part(state: Mapping[str, torch.Tensor], prefix: str, module: nn.Module, where: str) -> nn.Module:
    """``module`` with the entries of ``state`` under ``prefix`` (``actor.``, ``critic.``; all of them: ""), keys
    and shapes strict; a ``ValueError`` naming ``where`` otherwise."""
    part = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
    try:
        module.load_state_dict(part, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise ValueError(f"{where} does not fit {type(module).__name__}, SB3's 256-256 MlpPolicy for Reach "
                         f"({first})") from None
    return module.eval()


def _run_summary(run_dir: Path) -> dict[str, Any]:
    """A training run's ``summary.json`` (plain JSON), checked for the schema ``sac.py`` writes."""
    from icprl_lightning.families.metaworld_reach.sac import SCHEMA_VERSION, SUMMARY

    path = run_dir / SUMMARY
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: train a run with `icprl oracle train`")
    summary = read_json(path, "SAC run summary")
    if not isinstance(summary, dict) or summary.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(f"{path} is not a SAC oracle summary of schema {SCHEMA_VERSION}")
    return summary


def _checkpoint_in(run_dir: Path, relative: str) -> Path:
    """``run_dir / relative``, refused if the summary points outside the run directory."""
    path = (run_dir / relative).resolve()
    if not path.is_relative_to(run_dir.resolve()):
        raise ValueError(f"{run_dir}: the summary names checkpoint {relative!r}, outside the run directory")
    return path


def export_sac_oracle(run_dir: str | Path, out: str | Path, targets: Sequence[float] = DEFAULT_TARGETS,
                      overwrite: bool = False) -> Path:
    """Write the weights-only oracle of a training run (``sac.py``'s directory) to ``out``; see the docstring.

    For each target, the checkpoint whose sampled-action evaluation return, normalized between uniform (0)
    and the final checkpoint (1), is closest (ties: the earlier one); the final policy is level 1.0. The
    zips are read by ``sb3_policy_tensors`` only: nothing of the run is unpickled.
    """
    from icprl_lightning.families.metaworld_reach.sac import calibrate_checkpoints
    from icprl_lightning.sb3 import EvalRecord

    run_dir = Path(run_dir)
    summary = _run_summary(run_dir)
    for t in targets:
        if not 0.0 < t < 1.0:
            raise ValueError(f"targets must lie strictly between 0 and 1, got {t}")
    records = [EvalRecord(**r) for r in summary["checkpoints"]]
    chosen = calibrate_checkpoints(records, summary["uniform_return"], summary["expert_return"],
                                   {_level_name(t): t for t in targets})
    out = Path(out)
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise FileExistsError(f"{out} exists; delete it or pass overwrite=True (--overwrite)")
    levels = {**chosen, _level_name(FINAL): {"target": FINAL, "path": summary["final"]["path"],
                                             "step": summary["final"]["step"], "return": summary["final"]["return"],
                                             "success": summary["final"]["success"], "achieved": 1.0}}
    # every zip read (and refused) before anything is written
    actors = {}
    for name, c in levels.items():
        zip_path = _checkpoint_in(run_dir, c["path"])
        actors[name] = _load_part(sb3_policy_tensors(zip_path), "actor.", SACActor(), f"{zip_path}: its actor")
    final = _checkpoint_in(run_dir, summary["final"]["path"])
    critic = _load_part(sb3_policy_tensors(final), "critic.", SACCritic(), f"{final}: its critic")
    with staged_directory(out, marker=MANIFEST, schema_version=FORMAT_VERSION, what=WHAT,
                          overwrite=overwrite) as tmp:
        policies = {}
        for name, c in levels.items():
            torch.save(actors[name].state_dict(), tmp / f"actor_{name}.pt")
            policies[name] = {"level": c["target"], "file": f"actor_{name}.pt", "step": c["step"],
                              "eval_return": c["return"], "eval_success": c["success"],
                              "normalized_return": c["achieved"]}
        torch.save(critic.state_dict(), tmp / "critic_final.pt")
        manifest = {"schema_version": FORMAT_VERSION, "policies": policies, "critic": "critic_final.pt",
                    "reward_scale": summary.get("reward_scale", 1.0),
                    "normalization": "sampled-action evaluation return, (R - R_uniform) / (R_final - R_uniform)",
                    "training": {k: summary.get(k) for k in
                                 ("algorithm", "command", "goals", "timesteps", "n_envs", "sac_kwargs", "seed",
                                  "uniform_return", "expert_return", "final", "final_by_split", "train_seconds",
                                  "eval_episodes", "checkpoint_every")},
                    "curve": [[r.step, r.mean_return, r.success] for r in records]}
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2))
        files = sorted(p.name for p in tmp.iterdir() if p.name != CHECKSUMS)
        (tmp / CHECKSUMS).write_text("".join(f"{sha256(tmp / f)}  {f}\n" for f in files))
    return out


class ExportedSAC:
    """An exported SAC oracle directory, checksums verified, tensors loaded without unpickling objects.

    ``levels`` are the exported policies' normalized returns (1.0: the final policy π).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not (self.path / MANIFEST).is_file() or not (self.path / CHECKSUMS).is_file():
            raise FileNotFoundError(f"{self.path} is not an exported SAC oracle (no {MANIFEST} / {CHECKSUMS}); "
                                    "export one with `icprl oracle export`")
        self._listed = self._verify()
        self.manifest = read_json(self.path / MANIFEST, "SAC oracle manifest")
        if not isinstance(self.manifest, dict) or self.manifest.get("schema_version") != FORMAT_VERSION:
            found = self.manifest.get("schema_version") if isinstance(self.manifest, dict) else None
            raise ValueError(f"{self.path / MANIFEST}: schema {found}, expected {FORMAT_VERSION}")
        policies, critic = self.manifest.get("policies"), self.manifest.get("critic")
        if not isinstance(policies, dict) or not all(isinstance(e, dict) for e in policies.values()):
            raise ValueError(f"{self.path / MANIFEST}: 'policies' must map names to entries, got {policies!r}")
        try:
            self.reward_scale = float(self.manifest["reward_scale"])
            levels = [float(e["level"]) for e in policies.values()]
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{self.path / MANIFEST}: a level or the reward_scale is missing or not a number "
                             f"({type(e).__name__}: {e})") from None
        self._actors = {level: self._load(SACActor(), entry.get("file"))
                        for level, entry in zip(levels, policies.values(), strict=True)}
        self.critic = self._load(SACCritic(), critic)

    def _verify(self) -> set[str]:
        """Every file of ``SHA256SUMS`` checked; the names it lists (plain names inside the directory)."""
        listed = {}
        text = (self.path / CHECKSUMS).read_text(errors="replace")
        for line in text.splitlines():
            digest, _, name = line.partition("  ")
            listed[name] = digest
        for name, digest in listed.items():
            if "/" in name or name.startswith(".") or not (self.path / name).is_file():
                raise ValueError(f"{self.path / CHECKSUMS}: bad or missing entry {name!r}")
            if sha256(self.path / name) != digest:
                raise ValueError(f"{self.path / name}: checksum mismatch (expected {digest}); the oracle is "
                                 "corrupt or was edited: re-export it")
        if MANIFEST not in listed:
            raise ValueError(f"{self.path / CHECKSUMS} does not cover {MANIFEST}")
        return set(listed)

    def _load(self, module: nn.Module, file: Any) -> nn.Module:
        """``module`` with the weights of ``file``: a plain name in the directory, listed (and so verified) in
        ``SHA256SUMS``, a bounded torch archive holding tensors only; anything else a ValueError naming it."""
        if not isinstance(file, str) or file not in self._listed or file == MANIFEST:
            raise ValueError(f"{self.path / MANIFEST} names weight file {file!r}, which is not a file of the oracle "
                             f"directory listed in {CHECKSUMS}; refusing to load it")
        path = self.path / file
        return _load_part(_tensors(path, str(path)), "", module, str(path))

    @property
    def levels(self) -> tuple[float, ...]:
        return tuple(sorted(self._actors))

    def policy_info(self, level: float) -> Mapping[str, Any]:
        return next(e for e in self.manifest["policies"].values() if float(e["level"]) == self.resolve_level(level))

    def resolve_level(self, level: float) -> float:
        """The exported level equal to ``level`` (to 1e-9); KeyError naming the levels there are."""
        for known in self._actors:
            if abs(known - float(level)) < 1e-9:
                return known
        raise KeyError(f"the SAC oracle at {self.path} has no policy at level {level}; it has {list(self.levels)}")

    @staticmethod
    def _obs(obs: np.ndarray) -> torch.Tensor:
        obs = np.asarray(obs, dtype=np.float32)
        if obs.ndim != 2 or obs.shape[1] != OBS_DIM:
            raise ValueError(f"obs must be goal-visible observations of shape [B, {OBS_DIM}], got {list(obs.shape)}")
        return torch.from_numpy(obs)

    def mean_actions(self, obs: np.ndarray, level: float = FINAL) -> np.ndarray:
        """tanh(μ(s)) [B, 4] of the policy at ``level`` (the final policy's is DPT/DP²T's label)."""
        with torch.no_grad():
            mean, _ = self._actors[self.resolve_level(level)](self._obs(obs))
            return torch.tanh(mean).numpy()

    def sample_actions(self, obs: np.ndarray, level: float, noise: np.ndarray) -> np.ndarray:
        """tanh(μ(s) + σ(s) ε) [B, 4] with the given standard-normal ``noise`` ε [B, 4]."""
        with torch.no_grad():
            mean, log_std = self._actors[self.resolve_level(level)](self._obs(obs))
            eps = torch.as_tensor(np.asarray(noise, dtype=np.float32)).reshape(mean.shape)
            return torch.tanh(mean + log_std.exp() * eps).numpy()

    def q_values(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Q̂(s, a) [..., B] for actions [..., B, 4] (leading candidate axes allowed), latent-return units."""
        o = self._obs(obs)
        a = torch.as_tensor(np.asarray(actions, dtype=np.float32))
        if a.shape[-2:] != (len(o), ACTION_DIM):
            raise ValueError(f"actions must have shape [..., {len(o)}, {ACTION_DIM}], got {list(a.shape)}")
        with torch.no_grad():
            q = self.critic(o.expand(*a.shape[:-1], OBS_DIM), a.clamp(-1.0, 1.0))
        return q.numpy().astype(np.float64) / self.reward_scale
