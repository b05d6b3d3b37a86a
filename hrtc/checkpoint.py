"""Checkpoints: written atomically, read with ``torch.load(weights_only=True)`` (no code runs on load)."""

from __future__ import annotations

import os
import pickle
import tempfile
import warnings
from pathlib import Path
from typing import Any

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
