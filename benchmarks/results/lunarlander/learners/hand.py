"""The hand blend that ``hrtc/conf/task/lunarlander.yaml`` declares as the task's reference (centring + descent +
touchdown at 1), for the diagnosis scripts here and in ``../learners_mirror``: one definition, the task's."""

from __future__ import annotations

from collections.abc import Sequence

from hrtc.cli import task_config
from hrtc.references import reference_rules


def declared_hand_blend(skills: Sequence[str]) -> tuple[str, object]:
    """(name, rule) of the task's declared hand blend over ``skills`` (a checkpoint's ``meta["skills"]``)."""
    rules = reference_rules(list(skills), task_config("lunarlander")["references"])
    return next((name, rule) for name, rule in rules.items() if name.startswith("hand blend"))
