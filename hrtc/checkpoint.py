"""Checkpoints: written atomically, read with ``torch.load(weights_only=True)`` (no code runs on load).

The one place that reads them back: a whole run's state (:func:`load_checkpoint`), a saved policy ready to act
(:func:`load_policy`, what evaluation and learned skills use), a policy to fine-tune from
(:func:`load_policy_weights`), and the random generators a run saves and restores (:func:`rng_state`).
"""

from __future__ import annotations

import os
import pickle
import random
import tempfile
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from hrtc.errors import CheckpointError

FORMAT = "hrtc-checkpoint-v1"
REQUIRED_KEYS = ("format", "policy", "optimizer", "obs_rms", "global_step", "meta")


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` through a temporary file, fsync and rename: ``path`` is always whole."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {"format": FORMAT, **state}
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            torch.save(state, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and validate a checkpoint. Raises :class:`CheckpointError` with one line for anything else."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        with warnings.catch_warnings():  # torch warns about the pickle protocol of files it then refuses: noise here
            warnings.simplefilter("ignore", UserWarning)
            state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        # torch's message is a paragraph (with advice to load unsafely); its reason follows "WeightsUnpickler error:".
        text = str(error).split("WeightsUnpickler error:", 1)[-1]
        first = next((line.strip() for line in text.splitlines() if line.strip()), "unpickling refused")
        raise CheckpointError(
            f"{path} was refused by the safe loader (not plain tensors and containers): {first}"
        ) from None
    except Exception as error:  # noqa: BLE001  (torch raises KeyError, EOFError, RuntimeError... on garbage)
        reason = f"{type(error).__name__}: {error}".splitlines()[0]
        raise CheckpointError(f"{path} is not a readable checkpoint (truncated or corrupt?): {reason}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not an hrtc checkpoint (format tag missing)")
    missing = [k for k in REQUIRED_KEYS if k not in state]
    if missing:
        raise CheckpointError(f"{path} lacks {missing}")
    return state


REPO_ROOT = Path(__file__).resolve().parents[1]  # a clone's root: task configs name committed checkpoints from it
META_KEYS = ("task", "algo", "dist", "obs_dim", "out_dim", "hidden")


def resolve_checkpoint(path: str | Path) -> Path:
    """``path`` as given if it exists, else relative to the repository root (so task configs may name committed
    checkpoints by a repository path whatever the working directory). Raises :class:`CheckpointError` if neither."""
    path = Path(path).expanduser()
    if path.is_file() or path.is_absolute():
        return path
    candidate = REPO_ROOT / path
    return candidate if candidate.is_file() else path


class LoadedPolicy(NamedTuple):
    """A saved policy ready to act: the network, its observation normaliser (or None) and the checkpoint's meta."""

    policy: Any  # hrtc.policy.ActorCritic
    normalizer: Any  # hrtc.normalize.ObsNormalizer | None
    meta: dict[str, Any]


def load_policy(path: str | Path, which: str = "policy") -> LoadedPolicy:
    """Rebuild the meta-policy and master critic saved in checkpoint ``path`` (weights only; a relative path is also
    looked up from the repository root) in evaluation mode, with its observation normaliser."""
    from hrtc.encoders import build_encoder
    from hrtc.normalize import ObsNormalizer
    from hrtc.policy import ActorCritic

    path = resolve_checkpoint(path)
    state = load_checkpoint(path)
    meta = dict(state["meta"])
    missing = [k for k in META_KEYS if k not in meta]
    if missing:
        raise CheckpointError(f"{path} lacks meta {missing}: it predates checkpoints that can be loaded as policies")
    try:
        obs_dim = int(meta["obs_dim"])
        encoder = build_encoder(meta["encoder"], obs_dim) if meta.get("encoder") is not None else None
        policy = ActorCritic(obs_dim, int(meta["out_dim"]), str(meta["dist"]), tuple(int(h) for h in meta["hidden"]),
                             encoder=encoder, activation=str(meta.get("activation", "tanh")))  # fmt: skip
        policy.load_state_dict(state[which])
    except (KeyError, RuntimeError, ValueError) as error:
        raise CheckpointError(f"{path}: its weights do not fit its own meta ({_first(error)})") from error
    policy.eval()
    normalizer = None
    if state.get("obs_rms"):
        normalizer = ObsNormalizer((int(meta["obs_dim"]),))
        normalizer.rms.load_state_dict(state["obs_rms"])
    return LoadedPolicy(policy, normalizer, meta)


def _first(error: BaseException) -> str:
    return str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__


def load_policy_weights(trainer: Any, path: str | Path) -> dict[str, Any]:
    """Start ``trainer`` (a :class:`hrtc.trainer.Trainer`, before ``train()``; it needs ``cfg``, ``skill_names``,
    ``policy``, ``normalizer`` and ``reward_scaler``) from a checkpoint's policy, for fine-tuning on a changed task.

    Copies the actor-critic weights, the observation normaliser and the reward scaler's statistics (the critic's
    scale); the optimiser, counters and RNGs stay fresh. The checkpoint must have the same algorithm, distribution,
    network sizes and skill names, else :class:`CheckpointError`. Returns the checkpoint's meta."""
    path = resolve_checkpoint(path)
    state = load_checkpoint(path)
    meta = state["meta"]
    cfg = trainer.cfg
    mine = {"algo": cfg.algo, "dist": cfg.dist, "skills": list(trainer.skill_names), "hidden": list(cfg.hidden),
            "obs_dim": trainer.policy.obs_dim, "out_dim": trainer.policy.out_dim}  # fmt: skip
    for key, value in mine.items():
        theirs = meta.get(key)
        if (list(theirs) if isinstance(theirs, list | tuple) else theirs) != value:
            raise CheckpointError(f"cannot fine-tune from {path}: its {key} is {theirs!r}, this run's is {value!r}")
    trainer.policy.load_state_dict(state["policy"])
    if trainer.normalizer is not None and state["obs_rms"]:
        trainer.normalizer.rms.load_state_dict(state["obs_rms"])
    reward_rms = state.get("reward_rms") or (state.get("optimizer") or {}).get("reward_rms")  # older layout first
    if trainer.reward_scaler is not None and reward_rms:
        trainer.reward_scaler.rms.load_state_dict(reward_rms)
    return dict(meta)


# --------------------------------------------------------------------------------------------------- generators
def rng_state(generator: torch.Generator) -> dict[str, Any]:
    """Every random generator a run draws from, whole: torch's global one, the run's own ``generator``, numpy's
    legacy global one (key, position, cached Gaussian) and Python's ``random``, as tensors and plain containers."""
    name, key, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    version, internal, gauss_next = random.getstate()
    numpy = {"key": torch.from_numpy(key.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
             "gauss": float(gauss)}  # fmt: skip
    python = {"version": int(version), "internal": list(internal), "gauss_next": gauss_next}
    return {"torch": torch.get_rng_state(), "generator": generator.get_state(), "numpy": numpy, "python": python}


def set_rng_state(state: Mapping[str, Any], generator: torch.Generator) -> None:
    """Restore exactly what :func:`rng_state` saved (and the layouts of older checkpoints)."""
    torch.set_rng_state(state["torch"])
    generator.set_state(state["generator"])
    numpy = state["numpy"]
    if isinstance(numpy, torch.Tensor):  # older checkpoints saved the key alone
        numpy = {"key": numpy, "pos": 624, "has_gauss": 0, "gauss": 0.0}
    key = numpy["key"].numpy().astype(np.uint32)
    np.random.set_state(("MT19937", key, numpy["pos"], numpy["has_gauss"], numpy["gauss"]))  # noqa: NPY002
    python = state["python"]
    if not isinstance(python, dict):  # older checkpoints saved the internal state alone, without its version
        python = {"version": 3, "internal": list(python), "gauss_next": None}
    random.setstate((python["version"], tuple(int(x) for x in python["internal"]), python["gauss_next"]))


def plain(value: Any) -> Any:
    """``value`` as nested dicts, lists and scalars (what a ``weights_only`` checkpoint may hold)."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
