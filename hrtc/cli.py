"""Command-line plumbing shared by the scripts: Hydra composition with one-line errors.

Hydra reports a bad override over several lines with a stack-trace hint; a user who typed ``task=cartpol`` wants one
line naming the valid tasks. :func:`check_overrides` composes the config once before ``@hydra.main`` runs and turns
every composition error into ``error: ...`` on stderr and exit status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from importlib import resources

CONFIG_MODULE = "hrtc.conf"
GROUPS = ("task", "algo", "dist")


def group_choices(group: str) -> list[str]:
    """The option names of a config group shipped in ``hrtc/conf/<group>/``."""
    folder = resources.files(CONFIG_MODULE) / group
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def fail(message: str, status: int = 2) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(status)


def check_overrides(args: Sequence[str], config_name: str = "config") -> None:
    """Exit with one clear line if the command-line overrides cannot make a valid config."""
    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    user = _overrides_only(args)
    try:
        parsed = OverridesParser.create().parse_overrides(user)
    except HydraException as error:
        fail(f"malformed override: {_first_line(error)} (overrides look like key=value, e.g. task=cartpole_swingup)")
    for override in parsed:
        key = override.key_or_group
        if key in GROUPS and not override.is_delete():
            value = override.value()
            if not isinstance(value, str) or value not in group_choices(key):
                fail(f"unknown {key} {value!r}; valid {key}s: {', '.join(group_choices(key))}")
    config_overrides = [a for a, o in zip(user, parsed, strict=True) if not o.key_or_group.startswith("hydra")]
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(CONFIG_MODULE, version_base=None):
            compose(config_name, overrides=config_overrides)
    except (HydraException, OmegaConfBaseException) as error:
        fail(f"{_first_line(error)}")
    finally:
        GlobalHydra.instance().clear()


# Hydra's own flags that take a value (``--cfg job``, ``-cn config``...): their values are not overrides.
_VALUE_FLAGS = {"--cfg", "-c", "--package", "-p", "--config-path", "-cp", "--config-name", "-cn", "--config-dir",
                "-cd", "--experimental-rerun", "--info", "-i"}  # fmt: skip


def _overrides_only(args: Sequence[str]) -> list[str]:
    out, skip = [], False
    for arg in args:
        if skip:
            skip = False
            if "=" not in arg:
                continue
        if arg.startswith("-"):
            skip = arg in _VALUE_FLAGS
            continue
        out.append(arg)
    return out


def _first_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    message = "; ".join(lines[:3]) if lines else type(error).__name__
    return message.replace("Could not override", "cannot set").replace("Key ", "key ")


def task_config(name: str) -> dict:
    """The ``task`` block (``name``, ``skills``, ``env_kwargs``, ``solve_threshold``...) of ``conf/task/<name>.yaml``,
    resolved to plain containers. Raises :class:`~hrtc.errors.UnknownNameError` listing the shipped tasks."""
    from omegaconf import OmegaConf

    from hrtc.errors import UnknownNameError

    if name not in group_choices("task"):
        raise UnknownNameError("task", name, tuple(group_choices("task")))
    text = (resources.files(CONFIG_MODULE) / "task" / f"{name}.yaml").read_text()
    cfg = OmegaConf.to_container(OmegaConf.create(text), resolve=True)
    return dict(cfg["task"])  # type: ignore[index]
