"""The CSV sink: rows under their own header, resumed files continued and widened."""

from __future__ import annotations

import csv
from pathlib import Path

from hrtc.logging.sinks import CsvSink


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_a_resumed_file_gains_a_new_column_and_keeps_its_rows(tmp_path: Path) -> None:
    """A run written before ``true_episode_reward`` existed, resumed by code that writes it: the old rows keep
    their values (the new column empty), the new rows land under the right names."""
    old = CsvSink(tmp_path, {"eval": ("episode_reward", "episodes")})
    old.write("eval", 0, {"episode_reward": 1.5, "episodes": 3})
    old.write("eval", 10, {"episode_reward": 2.5, "episodes": 3})
    old.close()
    new = CsvSink(tmp_path, {"eval": ("episode_reward", "true_episode_reward", "episodes")}, append=True,
                  keep_until=10)  # fmt: skip
    new.write("eval", 20, {"episode_reward": 3.5, "true_episode_reward": -7.0, "episodes": 3})
    new.close()
    rows = _rows(tmp_path / "eval.csv")
    assert [r["step"] for r in rows] == ["0", "10", "20"]
    assert [r["episode_reward"] for r in rows] == ["1.5", "2.5", "3.5"]
    assert [r["true_episode_reward"] for r in rows] == ["", "", "-7.0"]
    assert [r["episodes"] for r in rows] == ["3", "3", "3"]
    assert not (tmp_path / "eval.csv.tmp").exists()


def test_a_resumed_file_with_every_column_is_only_continued(tmp_path: Path) -> None:
    first = CsvSink(tmp_path, {"train": ("a", "b")})
    first.write("train", 1, {"a": 1, "b": 2})
    first.close()
    before = (tmp_path / "train.csv").read_text()
    again = CsvSink(tmp_path, {"train": ("b", "a")}, append=True)  # same columns, another order: the file's is kept
    again.write("train", 2, {"a": 3, "b": 4})
    again.close()
    text = (tmp_path / "train.csv").read_text()
    assert text.startswith(before)
    assert _rows(tmp_path / "train.csv")[-1] == {"step": "2", "a": "3", "b": "4"}
