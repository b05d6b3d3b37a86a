"""Skill trees: a meta-policy inside a meta-policy acts as the hand-computed nested blend, prints as a tree, and
reports every node's effective weight (child weight times parent weight)."""

from __future__ import annotations

import numpy as np
import pytest

import envs
from hrtc.composition import ComposedEnv, SkillLibrary, build_library
from hrtc.errors import ConfigError
from hrtc.tree import TreeNode, effective_weights, env_tree, format_tree, skill_tree, tree_paths
from tests.skills.test_learned import CHILDREN, beta_mean_by_hand, tiny_checkpoint


@pytest.fixture(scope="module")
def node_ckpt(tmp_path_factory):
    return tiny_checkpoint(tmp_path_factory.mktemp("node"))


def _two_level(path) -> SkillLibrary:
    """root -> {node: an HRTC checkpoint -> {swingup, push}, back: StaticIntent(-0.5)}."""
    return build_library({
        "node": {"skill": {"_target_": "skills.learned.PolicySkill", "path": str(path), "task": "cartpole_swingup"}},
        "back": {"skill": {"_target_": "skills.static.StaticIntent", "action": [-0.5]}},
    })  # fmt: skip


def test_nested_tree_action_is_the_hand_computed_blend_and_effective_weights_multiply(node_ckpt):
    env = ComposedEnv(envs.make("cartpole_swingup"), _two_level(node_ckpt), decision_every=1)
    children = build_library(CHILDREN)  # the node's children, recomputed by hand
    env.reset(seed=3)
    children.reset(np.random.default_rng(0))
    root_weights = np.array([0.7, 0.4])
    node_weights = None
    for t in range(6):
        state = env.unwrapped.skill_state()
        if t % 2 == 0:  # the node (trained with decision_every=2) decides every 2 of its steps
            node_weights = beta_mean_by_hand(node_ckpt, state["observation"])
        proposals, _ = children.propose(state, t, 1)
        node_action = np.clip(node_weights @ proposals, -1.0, 1.0)
        expected = np.clip(0.7 * node_action + 0.4 * -0.5, -1.0, 1.0)
        _, _, _, _, info = env.step(root_weights)
        np.testing.assert_allclose(info["action"], expected, rtol=0, atol=1e-6)
        eff = effective_weights(env.skill_names, info["weights"], info["skills"])
        assert list(eff) == ["node", "node/swingup", "node/push", "back"]
        assert eff["node"] == pytest.approx(0.7) and eff["back"] == pytest.approx(0.4)
        np.testing.assert_allclose([eff["node/swingup"], eff["node/push"]], 0.7 * node_weights, atol=1e-6)


def test_tree_prints_every_level_and_lists_its_paths(node_ckpt):
    root = skill_tree(_two_level(node_ckpt), "meta", "meta-policy")
    text = format_tree(root)
    lines = text.splitlines()
    assert lines[0] == "meta: meta-policy"
    assert lines[1].startswith("├── node: hrtc-beta policy from cartpole_swingup, decides every 2 steps")
    assert lines[2].startswith("│   ├── swingup: EnergySwingUp <- [pole_angle")
    assert lines[3].startswith("│   └── push: StaticIntent")
    assert lines[4].startswith("└── back: StaticIntent")
    assert tree_paths(root) == ["node", "node/swingup", "node/push", "back"]


def test_effective_weights_of_three_levels():
    info = {"top": {"weight/mid": 0.5, "mid/weight/leaf": 0.4, "mid/weight/other": 1.0, "mid/leaf/cost": 3.0,
                    "weight/solo": 0.25}}  # fmt: skip
    eff = effective_weights(["top", "flat"], np.array([0.8, 1.5]), {**info, "flat": {"status": 0.0}})
    assert eff == pytest.approx(
        {"top": 0.8, "top/mid": 0.4, "top/mid/leaf": 0.16, "top/mid/other": 0.4, "top/solo": 0.2, "flat": 1.0}
    )  # fmt: skip  (root weights clipped to [0, 1])


def test_tree_paths_depth_first():
    root = TreeNode("r", "", (TreeNode("a", "", (TreeNode("b", ""),)), TreeNode("c", "")))
    assert tree_paths(root) == ["a", "a/b", "c"]


def test_env_tree_labels_the_root_with_its_decision_rate(node_ckpt):
    env = ComposedEnv(envs.make("cartpole_swingup"), _two_level(node_ckpt), decision_every=5)
    assert format_tree(env_tree(env)).splitlines()[0] == "meta: meta-policy, decides every 5 env steps"
    wide = ComposedEnv(envs.make("cartpole_swingup"), _two_level(node_ckpt), decision_every=5, weight_margin=0.25)
    assert format_tree(env_tree(wide)).splitlines()[0] == (
        "meta: meta-policy, decides every 5 env steps, weights sampled in [-0.25, 1.25] and clipped to [0, 1]"
    )
    with pytest.raises(ConfigError, match="composes no skills"):
        env_tree(envs.make("cartpole_swingup"))


def test_each_level_keeps_its_own_rate_and_rewards_sum_over_a_decision(node_ckpt):
    """The root decides every 3 env steps, the node every 2 of its steps, the leaf skills act at every step: one
    root decision returns the sum of the 3 raw rewards of the hand-computed nested actions."""
    env = ComposedEnv(envs.make("cartpole_swingup"), _two_level(node_ckpt), decision_every=3)
    raw = envs.make("cartpole_swingup")
    children = build_library(CHILDREN)
    env.reset(seed=5)
    raw.reset(seed=5)
    children.reset(np.random.default_rng(0))
    node_weights = None
    for decision in range(3):
        expected, actions = 0.0, []
        for j in range(3):
            t = 3 * decision + j
            state = raw.unwrapped.skill_state()
            if t % 2 == 0:
                node_weights = beta_mean_by_hand(node_ckpt, state["observation"])
            proposals, _ = children.propose(state, t, 1)
            action = np.clip(0.7 * np.clip(node_weights @ proposals, -1.0, 1.0) - 0.4 * 0.5, -1.0, 1.0)
            actions.append(float(action[0]))
            expected += raw.step(action.astype(np.float32))[1]
        _, total, _, _, info = env.step(np.array([0.7, 0.4]))
        assert total == pytest.approx(expected, abs=1e-9) and info["env_steps"] == 3 * (decision + 1)
        assert len(set(actions)) == 3  # the skills acted at every env step under one held root decision
