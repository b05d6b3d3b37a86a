"""The Sink protocol and the CSV sink (``train.csv``, ``eval.csv``)."""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Protocol


class Sink(Protocol):
    """Receives rows of scalar metrics keyed by a stream name (``train``, ``eval``) and a step."""

    def write(self, stream: str, step: int, metrics: Mapping[str, float]) -> None: ...
    def close(self) -> None: ...


class CsvSink:
    """One CSV per stream in ``run_dir``, columns fixed by ``columns[stream]``; each row is flushed when written.

    With ``append=True`` existing files are continued (their header is kept), for a resumed run.
    """

    def __init__(self, run_dir: str | Path, columns: Mapping[str, Sequence[str]], append: bool = False) -> None:
        self.run_dir = Path(run_dir)
        self.columns = {stream: ["step", *cols] for stream, cols in columns.items()}
        self._files: dict[str, IO[str]] = {}
        self._writers: dict[str, csv.DictWriter] = {}
        for stream, cols in self.columns.items():
            path = self.run_dir / f"{stream}.csv"
            existing = append and path.exists() and path.stat().st_size > 0
            handle = open(path, "a" if existing else "w", newline="")
            writer = csv.DictWriter(handle, fieldnames=cols, extrasaction="ignore")
            if not existing:
                writer.writeheader()
                handle.flush()
            self._files[stream], self._writers[stream] = handle, writer

    def write(self, stream: str, step: int, metrics: Mapping[str, float]) -> None:
        row = {"step": step}
        for key, value in metrics.items():
            row[key] = "" if isinstance(value, float) and math.isnan(value) else value
        self._writers[stream].writerow(row)
        self._files[stream].flush()

    def close(self) -> None:
        for handle in self._files.values():
            handle.close()
        self._files.clear()
