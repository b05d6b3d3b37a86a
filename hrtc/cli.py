"""Command-line plumbing shared by the scripts: Hydra composition with one-line errors.

Hydra reports a bad override over several lines with a stack-trace hint; a user who typed ``task=cartpol`` wants one
line naming the valid tasks. :func:`check_overrides` composes the config once before ``@hydra.main`` runs and turns
every composition error into ``error: ...`` on stderr and exit status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

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


def parse_options(args: Sequence[str], defaults: dict, usage: str) -> dict:
    """``key=value`` command-line options over ``defaults``, each parsed as its default's type (str, bool, int; YAML
    when the default is None: ``weights=[0.5,0.5]``); unknown keys and malformed values exit with one clear line."""
    import yaml

    options = dict(defaults)
    for arg in args:
        if arg in ("-h", "--help"):
            print(usage)
            raise SystemExit(0)
        key, sep, text = arg.partition("=")
        if not sep or not key:
            fail(f"malformed argument {arg!r}: options look like key=value; valid keys: {', '.join(defaults)}")
        if key not in defaults:
            fail(f"unknown option {key!r}; valid keys: {', '.join(defaults)}")
        default = defaults[key]
        try:
            if isinstance(default, str):
                value = text
            elif isinstance(default, bool):
                value = {"true": True, "false": False}[text.lower()]
            elif isinstance(default, int):
                value = int(text)
            else:
                value = yaml.safe_load(text) if text else None
        except (KeyError, ValueError, yaml.YAMLError):
            kind = "true or false" if isinstance(default, bool) else type(default).__name__
            fail(f"cannot parse {key}={text!r}" + (f" (expected {kind})" if default is not None else ""))
        options[key] = value
    return options


def start_run(cfg: Any, run_dir: str | Path) -> Any:
    """Validate the composed config ``cfg`` and build the run's :class:`~hrtc.trainer.Trainer` in ``run_dir`` (its
    environments and skills, a resumed checkpoint); any problem exits with one line. Writes ``config.yaml``."""
    from omegaconf import OmegaConf

    from hrtc.errors import HRTCError
    from hrtc.trainer import RunConfig, Trainer

    run_dir = Path(run_dir)
    try:
        run_cfg = RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        return Trainer(run_cfg, run_dir, resume=bool(cfg.get("resume", False)))
    except HRTCError as error:
        fail(str(error))


def compose(overrides: Sequence[str], config_name: str = "config") -> Any:
    """The config ``scripts/train.py`` would run with for ``overrides`` (after :func:`check_overrides`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    check_overrides(overrides, config_name)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(CONFIG_MODULE, version_base=None):
            return hydra_compose(config_name, overrides=[o for o in overrides if not o.startswith("hydra")])
    finally:
        GlobalHydra.instance().clear()
