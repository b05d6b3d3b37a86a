"""Where a run's metrics go. Every destination is a :class:`Sink`; the trainer knows only the protocol."""

from __future__ import annotations

from hrtc.logging.sinks import CsvSink, Sink

__all__ = ["CsvSink", "Sink"]
