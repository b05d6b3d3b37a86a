"""Checkpoints as skills: tiny real checkpoints, trained here, act with their distribution's mode on their own
observation; an HRTC checkpoint blends its rebuilt children; a misfit fails at construction with one line."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch.nn import functional as F

import envs
from hrtc.check import check_skill, task_states
from hrtc.checkpoint import load_checkpoint, load_policy_weights
from hrtc.composition import build_library
from hrtc.config import RunConfig
from hrtc.errors import CheckpointError, ConfigError, ShapeError
from hrtc.policy import ActorCritic
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer
from skills.learned import PolicySkill

# Cheap skills (no solver): a child library whose proposals the tests can recompute by hand.
CHILDREN = {
    "swingup": {"skill": {"_target_": "skills.swingup.EnergySwingUp", "model": "cartpole_swingup"}},
    "push": {"skill": {"_target_": "skills.static.StaticIntent", "action": [0.3]}},
}
SHORT = {"time_limit": 0.5}  # 50-step episodes keep the evaluations of these tiny runs short


def tiny_run_config(**kwargs) -> RunConfig:
    """A real training run of a few hundred env steps (one env in this process)."""
    base = dict(task="cartpole_swingup", skills=CHILDREN, algo="hrtc", dist="beta", seed=7, steps=300, num_envs=1,
                vector="sync", eval_every=300, eval_episodes=1, checkpoint_every=300, progress=False,
                env_kwargs=SHORT, decision_every=2,
                ppo=PPOConfig(num_steps=50, num_minibatches=2, update_epochs=2))  # fmt: skip
    return RunConfig(**{**base, **kwargs})


def tiny_checkpoint(run_dir: Path, **kwargs) -> Path:
    """Train a tiny run into ``run_dir``; returns its ``checkpoints/last.pt``."""
    Trainer(tiny_run_config(**kwargs), run_dir).train()
    return run_dir / "checkpoints" / "last.pt"


@pytest.fixture(scope="module")
def hrtc_ckpt(tmp_path_factory) -> Path:
    return tiny_checkpoint(tmp_path_factory.mktemp("hrtc"))


@pytest.fixture(scope="module")
def ppo_ckpt(tmp_path_factory) -> Path:
    return tiny_checkpoint(tmp_path_factory.mktemp("ppo"), algo="ppo", skills={}, task="cartpole_balance")


@pytest.fixture(scope="module")
def states() -> list[dict[str, np.ndarray]]:
    return task_states("cartpole_swingup", n=60, seed=1)


def beta_mean_by_hand(path: Path, observation: np.ndarray) -> np.ndarray:
    """alpha / (alpha + beta) from the saved weights and normaliser, without the distribution classes."""
    state = load_checkpoint(path)
    meta = state["meta"]
    policy = ActorCritic(meta["obs_dim"], meta["out_dim"], meta["dist"], tuple(meta["hidden"]))
    policy.load_state_dict(state["policy"])
    rms = state["obs_rms"]
    x = observation.astype(np.float32)[None]
    x = np.clip((x - rms["mean"].numpy()) / np.sqrt(rms["var"].numpy() + 1e-8), -10, 10).astype(np.float32)
    with torch.no_grad():
        raw = policy.actor_head.linear(policy.actor_body(torch.as_tensor(x)))
    alpha, beta = (F.softplus(raw) + 1.0).chunk(2, dim=-1)
    return (alpha / (alpha + beta)).numpy()[0].astype(np.float64)


def test_ppo_checkpoint_proposes_its_beta_mean_on_its_action_bounds(ppo_ckpt, states):
    skill = PolicySkill(ppo_ckpt, task="cartpole_swingup")  # trained on cartpole_balance, reused in the swing-up
    assert skill.state_keys == ("observation",)
    skill.reset(np.random.default_rng(0))
    for state in states[:20]:
        action = skill.act(state["observation"]).action
        expected = -1.0 + 2.0 * beta_mean_by_hand(ppo_ckpt, state["observation"])  # bounds [-1, 1]
        np.testing.assert_allclose(action, expected, rtol=0, atol=1e-6)
    assert len({float(skill.act(states[0]["observation"]).action[0]) for _ in range(5)}) == 1  # no sampling


def test_hrtc_checkpoint_blends_its_children_with_its_beta_mean_at_its_own_rate(hrtc_ckpt, states):
    skill = PolicySkill(hrtc_ckpt)
    assert skill.decision_every == 2 and skill.library is not None and skill.library.names == ("swingup", "push")
    children = build_library(CHILDREN)  # a second copy, to recompute the node's proposals by hand
    skill.reset(np.random.default_rng(0))
    children.reset(np.random.default_rng(0))
    trace = states[10:16]
    for t, state in enumerate(trace):
        out = skill.act(np.concatenate([np.atleast_1d(state[k]) for k in skill.state_keys]))
        decided = trace[t - t % 2]  # weights chosen every 2 calls, held in between
        weights = beta_mean_by_hand(hrtc_ckpt, decided["observation"])
        proposals, _ = children.propose(state, t, 1)
        expected = np.clip(weights @ proposals, -1.0, 1.0)
        np.testing.assert_allclose(out.action, expected, rtol=0, atol=1e-6)
        assert out.info["weight/swingup"] == pytest.approx(weights[0], abs=1e-6)
        assert out.info["weight/push"] == pytest.approx(weights[1], abs=1e-6)
        assert "swingup/energy" in out.info  # children's diagnostics, prefixed by their names


def test_an_hrtc_checkpoint_trained_with_a_weight_margin_acts_on_that_span(tmp_path, states):
    from hrtc.benchmark.metrics import checkpoint_env

    path = tiny_checkpoint(tmp_path, weight_margin=0.5, steps=100, eval_every=100, checkpoint_every=100)
    meta = load_checkpoint(path)["meta"]
    assert meta["weight_margin"] == 0.5
    assert checkpoint_env(meta).action_space == gym.spaces.Box(-0.5, 1.5, (2,), np.float32)
    skill = PolicySkill(path)
    children = build_library(CHILDREN)
    skill.reset(np.random.default_rng(0))
    children.reset(np.random.default_rng(0))
    state = states[12]
    out = skill.act(np.concatenate([np.atleast_1d(state[k]) for k in skill.state_keys]))
    weights = np.clip(-0.5 + 2.0 * beta_mean_by_hand(path, state["observation"]), 0.0, 1.0)
    proposals, _ = children.propose(state, 0, 1)
    np.testing.assert_allclose(out.action, np.clip(weights @ proposals, -1.0, 1.0), rtol=0, atol=1e-6)
    assert [out.info["weight/swingup"], out.info["weight/push"]] == pytest.approx(weights, abs=1e-6)


@pytest.mark.parametrize("which", ["ppo", "hrtc"])
def test_learned_skills_pass_check_skill(which, ppo_ckpt, hrtc_ckpt, states):
    skill = PolicySkill(ppo_ckpt if which == "ppo" else hrtc_ckpt, task="cartpole_swingup")
    check_skill(skill, states, envs.make("cartpole_swingup").action_space)


def test_a_checkpoint_as_a_skill_by_config(hrtc_ckpt, states):
    library = build_library({"node": {"skill": {"_target_": "skills.learned.PolicySkill", "path": str(hrtc_ckpt),
                                                "task": "cartpole_swingup"}}})  # fmt: skip
    proposals, infos = library.propose(states[0], 0, 1)
    assert proposals.shape == (1, 1) and "weight/swingup" in infos[0]


# --------------------------------------------------------------------------------------------------- misfits
class _TwoActions(gym.Wrapper):
    """The swing-up with a 2-D action (the second ignored): a task a 1-D policy does not fit."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def step(self, action):
        return self.env.step(np.asarray(action, np.float32)[:1])


if "test_two_actions" not in envs.names():
    envs.register("test_two_actions")(lambda **kw: _TwoActions(envs.make("cartpole_swingup", **kw)))


def test_an_observation_that_does_not_fit_fails_at_construction(ppo_ckpt):
    with pytest.raises(ShapeError, match=r"reads observations of 5 values .* give 2"):
        PolicySkill(ppo_ckpt, observation_keys=("cart_position", "pole_angle"), task="cartpole_swingup")


def test_an_action_that_does_not_fit_fails_at_construction(ppo_ckpt, hrtc_ckpt):
    with pytest.raises(ShapeError, match="acts in 1 dimensions .* takes 2"):
        PolicySkill(ppo_ckpt, task="test_two_actions")
    # An HRTC node's children propose 1-D actions: the dry run at construction catches them.
    with pytest.raises(ShapeError, match=r"proposed an action of shape \(1,\); the task's is \(2,\)"):
        PolicySkill(hrtc_ckpt, task="test_two_actions")


def test_unknown_state_names_fail_at_construction(ppo_ckpt):
    with pytest.raises(ConfigError, match="has no state \\['tip_height'\\]"):
        PolicySkill(ppo_ckpt, observation_keys=("tip_height",), task="cartpole_swingup")


def test_missing_and_truncated_checkpoints_are_one_line_errors(hrtc_ckpt, tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint at"):
        PolicySkill(tmp_path / "missing.pt")
    corrupt = tmp_path / "truncated.pt"
    corrupt.write_bytes(hrtc_ckpt.read_bytes()[:5000])
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        PolicySkill(corrupt)
    # Through a task config: the library reports the skill's name and the cause on one line.
    with pytest.raises(ConfigError, match="skill 'balance' could not be built: no checkpoint at") as error:
        build_library({"balance": {"skill": {"_target_": "skills.learned.PolicySkill", "path": str(corrupt) + "x"}}})
    assert "\n" not in str(error.value)


# --------------------------------------------------------------------------------------------------- fine-tuning
def test_load_policy_weights_starts_a_run_from_a_checkpoint(hrtc_ckpt, tmp_path):
    trainer = Trainer(tiny_run_config(), tmp_path)
    saved = load_checkpoint(hrtc_ckpt)
    load_policy_weights(trainer, hrtc_ckpt)
    for name, tensor in trainer.policy.state_dict().items():
        torch.testing.assert_close(tensor, saved["policy"][name])
    np.testing.assert_array_equal(trainer.normalizer.rms.mean, saved["obs_rms"]["mean"].numpy())
    assert trainer.global_step == 0  # counters and optimiser stay fresh: a new run, not a resume


def test_load_policy_weights_refuses_another_skill_set(hrtc_ckpt, tmp_path):
    cfg = replace(tiny_run_config(), skills={"push": CHILDREN["push"]})
    with pytest.raises(CheckpointError, match="cannot fine-tune from .* its skills is \\['swingup', 'push'\\]"):
        load_policy_weights(Trainer(cfg, tmp_path), hrtc_ckpt)
