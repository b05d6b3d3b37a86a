"""Skill trees: what a composition is made of, printed as text, and each node's effective weight.

A meta-policy is itself a skill (:class:`skills.learned.PolicySkill` of an HRTC checkpoint), so a library may hold
libraries. A node's *effective* weight is the product of the weights on its path from the root: a child weighted
0.5 inside a node the root weights 0.8 contributes ``0.8 * 0.5 = 0.4`` of its proposal to the action (with the
``sum`` action filter, before clipping). Paths are ``/``-joined skill names, e.g. ``swing/swingup``: the same
strings as the config names and the Rerun entity paths under the root's entity.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hrtc.composition import ComposedEnv, SkillLibrary
from hrtc.errors import ConfigError


@dataclass(frozen=True)
class TreeNode:
    """One skill of a tree: its name, a one-line description, and its children (empty for a leaf skill)."""

    name: str
    label: str
    children: tuple[TreeNode, ...] = ()


def skill_tree(library: SkillLibrary, name: str = "meta", label: str = "meta-policy") -> TreeNode:
    """The tree below a skill library; a skill with a ``library`` attribute (an HRTC checkpoint as a skill) is a
    node whose children are that library's skills."""
    children = []
    for slot in library.slots:
        skill = slot.skill
        describe = getattr(skill, "describe", None)
        text = describe() if callable(describe) else type(skill).__name__
        keys = getattr(slot.state_filter, "keys", None)
        if keys is not None and getattr(skill, "library", None) is None:
            text += f" <- [{', '.join(keys)}]"
        if slot.every > 1:
            text += f", re-solved every {slot.every} steps"
        sub = getattr(skill, "library", None)
        if isinstance(sub, SkillLibrary):
            children.append(skill_tree(sub, slot.name, text))
        else:
            children.append(TreeNode(slot.name, text))
    return TreeNode(name, label, tuple(children))


def env_tree(env: Any, name: str = "meta") -> TreeNode:
    """The tree of a :class:`~hrtc.composition.ComposedEnv` (or any wrapper around one), its root labelled with the
    meta-policy's decision rate: what ``scripts/train.py`` prints at start."""
    composed = env
    while not isinstance(composed, ComposedEnv):
        if not hasattr(composed, "env"):
            raise ConfigError(f"{env} composes no skills: it has no skill tree")
        composed = composed.env
    every = composed.decision_every
    label = f"meta-policy, decides every {every} env steps" if every > 1 else "meta-policy, decides every env step"
    if composed.weight_margin > 0:
        m = composed.weight_margin
        label += f", weights sampled in [{-m:g}, {1 + m:g}] and clipped to [0, 1]"
    return skill_tree(composed.library, name, label)


def format_tree(node: TreeNode) -> str:
    """The tree as indented text, one node a line::

    meta: meta-policy
    ├── swing: hrtc-beta policy from cartpole_energy ...
    │   ├── swingup: EnergySwingUp <- [pole_angle, ...]
    │   └── hold: StaticIntent <- []
    └── balance: ...
    """
    lines = [f"{node.name}: {node.label}"]

    def walk(children: Sequence[TreeNode], prefix: str) -> None:
        for i, child in enumerate(children):
            last = i == len(children) - 1
            lines.append(f"{prefix}{'└── ' if last else '├── '}{child.name}: {child.label}")
            walk(child.children, prefix + ("    " if last else "│   "))

    walk(node.children, "")
    return "\n".join(lines)


def tree_paths(node: TreeNode) -> list[str]:
    """Every node's path below the root, depth first in library order (e.g. ``["swing", "swing/swingup", ...]``):
    the names of the effective-weight series."""
    paths: list[str] = []

    def walk(n: TreeNode, prefix: str) -> None:
        for child in n.children:
            path = f"{prefix}{child.name}"
            paths.append(path)
            walk(child, path + "/")

    walk(node, "")
    return paths


def effective_weights(
    names: Sequence[str], weights: np.ndarray, skills_info: Mapping[str, Mapping[str, float]]
) -> dict[str, float]:
    """Effective weight of every node of a tree for one step.

    Args:
        names: the root's skill names, in weight order (``ComposedEnv.skill_names``).
        weights: (K,) the root meta-policy's weights (``info["weights"]``); clipped to [0, 1] as the action filter does.
        skills_info: each root skill's diagnostics (``info["skills"]``); a node's carry ``weight/<child>`` and its
            children's diagnostics as ``<child>/<key>`` (what :class:`skills.learned.PolicySkill` reports).

    Returns ``{path: weight}``, e.g. ``{"swing": 0.8, "swing/swingup": 0.8 * w_swingup, ...}``.
    """
    weights = np.clip(np.asarray(weights, dtype=np.float64).reshape(-1), 0.0, 1.0)
    out: dict[str, float] = {}

    def walk(info: Mapping[str, float], path: str, parent: float) -> None:
        for key, local in info.items():
            if not key.startswith("weight/") or "/" in key[len("weight/") :]:
                continue
            child = key[len("weight/") :]
            child_path, effective = f"{path}/{child}", parent * float(local)
            out[child_path] = effective
            sub = {k[len(child) + 1 :]: v for k, v in info.items() if k.startswith(child + "/")}
            walk(sub, child_path, effective)

    for name, weight in zip(names, weights, strict=True):
        out[name] = float(weight)
        walk(skills_info.get(name, {}), name, float(weight))
    return out


def describe(env: Any, title: str = "") -> tuple[str, list[str]]:
    """Markdown for a recording's ``tree`` entity and the effective-weight series names: the skill tree of a composed
    env (``tree_paths``), or a line saying the policy acts on raw actions (no paths)."""
    try:
        tree = env_tree(env)
    except ConfigError:
        return f"# {title}\n\nplain PPO on the task's raw actions (no skills)", []
    return f"# {title}\n\n```\n{format_tree(tree)}\n```", tree_paths(tree)
