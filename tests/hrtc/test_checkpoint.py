"""Checkpoints: atomic writes, safe loading, clear errors for anything that is not a whole hrtc checkpoint."""

import os
import pickle

import pytest
import torch

from hrtc.checkpoint import load_checkpoint, save_checkpoint
from hrtc.errors import CheckpointError

STATE = {"policy": {"w": torch.ones(3)}, "optimizer": {}, "obs_rms": {}, "global_step": 7, "meta": {"skills": ["a"]}}


def test_round_trip(tmp_path):
    path = save_checkpoint(tmp_path / "c.pt", STATE)
    loaded = load_checkpoint(path)
    assert loaded["global_step"] == 7 and torch.equal(loaded["policy"]["w"], torch.ones(3))
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]  # no temporary file left behind


def test_truncated_file_is_refused(tmp_path):
    path = save_checkpoint(tmp_path / "c.pt", STATE)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_checkpoint(path)


def test_other_files_are_refused(tmp_path):
    (tmp_path / "text.pt").write_text("hello")
    with pytest.raises(CheckpointError):
        load_checkpoint(tmp_path / "text.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "plain.pt")
    with pytest.raises(CheckpointError, match="not an hrtc checkpoint"):
        load_checkpoint(tmp_path / "plain.pt")
    with pytest.raises(CheckpointError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")


class _Exploit:
    def __reduce__(self):
        return (os.system, ("touch pwned",))


def test_a_pickle_that_runs_code_is_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": "hrtc-checkpoint-v1", "payload": _Exploit()}, path, pickle_protocol=pickle.DEFAULT_PROTOCOL)
    with pytest.raises(CheckpointError, match="refused by the safe loader"):
        load_checkpoint(path)
    assert not (tmp_path / "pwned").exists() and not os.path.exists("pwned")
