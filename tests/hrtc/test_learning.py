"""The meta-policy learns to trust the one useful skill of two, on a small real task trained by the real Trainer."""

import gymnasium as gym
import numpy as np
import pandas as pd
import torch

import envs
from hrtc.checkpoint import load_checkpoint
from hrtc.config import RunConfig
from hrtc.environments import make_env
from hrtc.normalize import ObsNormalizer
from hrtc.policy import build_policy
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

TASK = "test_point_mass"


class PointMass(gym.Env):
    """A point on a line; reward -|x - goal|. 20 steps an episode; x and the goal are random each episode."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def skill_state(self):
        return {"position": np.array([self.x]), "goal": np.array([self.goal])}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.goal, self.t = self.np_random.uniform(-1, 1, size=2).tolist() + [0]
        return np.array([self.x, self.goal], np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + float(action[0]), -2, 2))
        self.t += 1
        obs = np.array([self.x, self.goal], np.float32)
        return obs, -abs(self.x - self.goal), False, self.t >= 20, {}


class GoTo:
    """Useful: the exact step to the goal (clipped)."""

    state_keys = ("position", "goal")

    def reset(self, rng):
        pass

    def act(self, state):
        from hrtc.skill import SkillOutput

        return SkillOutput(np.clip([state[1] - state[0]], -1, 1), {})


if TASK not in envs.names():
    envs.register(TASK)(PointMass)

SKILLS = {
    "goto": {"skill": {"_target_": "tests.hrtc.test_learning.GoTo"}},
    "drift": {"skill": {"_target_": "skills.static.StaticIntent", "action": [0.8]}},
}


def test_meta_policy_learns_weight_above_0_9_on_the_useful_skill(tmp_path):
    cfg = RunConfig(
        task=TASK, skills=SKILLS, seed=0, steps=24_000, num_envs=2, vector="sync", eval_every=4_000,
        eval_episodes=5, progress=False,
        ppo=PPOConfig(learning_rate=3e-3, anneal_lr=False, num_steps=200, update_epochs=10, num_minibatches=4,
                      gamma=0.9),
    )  # fmt: skip
    Trainer(cfg, tmp_path).train()
    evals = pd.read_csv(tmp_path / "eval.csv")
    state = load_checkpoint(tmp_path / "checkpoints" / "last.pt")
    env = make_env(TASK, "hrtc", SKILLS)
    space = env.action_space
    policy = build_policy(2, space.low, space.high, cfg.dist, cfg.hidden, cfg.beta_init_bias, cfg.encoder)
    policy.load_state_dict(state["policy"])
    normalizer = ObsNormalizer((2,))
    normalizer.rms.load_state_dict(state["obs_rms"])
    obs = np.random.default_rng(1).uniform(-1, 1, size=(256, 2)).astype(np.float32)
    with torch.no_grad():
        weights = policy.distribution(torch.as_tensor(normalizer(obs))).mode().numpy()
    print("mean weights (goto, drift):", weights.mean(0), "eval returns:", list(evals["episode_reward"].round(2)))
    assert weights[:, 0].mean() > 0.9
    assert weights[:, 1].mean() < weights[:, 0].mean() - 0.5
    assert evals["episode_reward"].iloc[-1] > evals["episode_reward"].iloc[0]
