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

    With ``append=True`` existing files are continued, for a resumed run; with ``keep_until`` their rows of a later
    step (and a last line cut short by a crash) are dropped first. A file written before a column was added gains it
    (empty in its old rows; :func:`widen_header`), so every row stays under its own header.
    """

    def __init__(self, run_dir: str | Path, columns: Mapping[str, Sequence[str]], append: bool = False,
                 keep_until: int | None = None) -> None:  # fmt: skip
        self.run_dir = Path(run_dir)
        self.columns = {stream: ["step", *cols] for stream, cols in columns.items()}
        self._files: dict[str, IO[str]] = {}
        self._writers: dict[str, csv.DictWriter] = {}
        for stream, cols in self.columns.items():
            path = self.run_dir / f"{stream}.csv"
            if append and keep_until is not None and path.exists():
                truncate_rows(path, keep_until)
            existing = append and path.exists() and path.stat().st_size > 0
            fields = widen_header(path, cols) if existing else cols
            handle = open(path, "a" if existing else "w", newline="")
            writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore")
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


def widen_header(path: Path, columns: Sequence[str]) -> list[str]:
    """The header of CSV ``path`` once it holds every one of ``columns``: the file is rewritten (atomically) with
    the missing ones added after its own, empty in its rows; a header that has them all is left as it is."""
    import os

    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    header = rows[0] if rows else []
    missing = [c for c in columns if c not in header]
    if not missing:
        return header
    widened = header + missing
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(widened)
        writer.writerows(row + [""] * len(missing) for row in rows[1:])
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    return widened


def truncate_rows(path: Path, keep_until: int) -> int:
    """Rewrite CSV ``path`` (first column ``step``) without rows after step ``keep_until`` or an unfinished last
    line, atomically. Returns the number of lines dropped."""
    import os

    lines = path.read_text().splitlines(keepends=True)
    complete = [line for line in lines if line.endswith("\n")]  # only the last line can be cut short by a crash
    header, rows = complete[:1], complete[1:]
    kept = [row for row in rows if _step(row) is not None and _step(row) <= keep_until]  # type: ignore[operator]
    dropped = len(lines) - len(header) - len(kept)
    if dropped:
        tmp = path.with_suffix(".csv.tmp")
        with open(tmp, "w") as handle:
            handle.writelines(header + kept)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    return dropped


def _step(row: str) -> float | None:
    try:
        return float(row.split(",", 1)[0])
    except ValueError:
        return None
