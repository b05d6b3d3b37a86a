"""The off-policy learner's pieces in isolation, and a meta-policy that learns a state-dependent switch with it."""

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import torch

import envs
from hrtc.checkpoint import load_policy
from hrtc.config import RunConfig
from hrtc.distributions import BetaDistribution, NormalDistribution
from hrtc.learner import Step
from hrtc.policy import ActorCritic
from hrtc.sac import (
    ActionMap,
    NStepAccumulator,
    ReplayBatch,
    ReplayBuffer,
    SACConfig,
    SACLearner,
    TwinQ,
    sac_losses,
    soft_q_target,
    soft_update,
    temperature_loss,
)
from hrtc.trainer import Trainer


# --------------------------------------------------------------------------------------------------- Beta rsample
@pytest.mark.parametrize(("a", "b"), [(1.5, 1.5), (3.0, 1.2), (1.1, 6.0)])
def test_beta_rsample_gradient_matches_finite_differences_of_the_mean(a, b):
    """d E[w] / d(alpha, beta) from reparameterised samples equals the finite-difference derivative of the exact mean
    alpha / (alpha + beta)."""
    torch.manual_seed(0)
    alpha = torch.tensor([a], dtype=torch.float64, requires_grad=True)
    beta = torch.tensor([b], dtype=torch.float64, requires_grad=True)
    w = BetaDistribution(alpha.expand(400_000, 1), beta.expand(400_000, 1)).rsample()
    w.mean().backward()

    def mean(x: float, y: float) -> float:
        return x / (x + y)

    h = 1e-5
    fd_alpha = (mean(a + h, b) - mean(a - h, b)) / (2 * h)
    fd_beta = (mean(a, b + h) - mean(a, b - h)) / (2 * h)
    assert alpha.grad.item() == pytest.approx(fd_alpha, abs=3e-3)
    assert beta.grad.item() == pytest.approx(fd_beta, abs=3e-3)


def test_beta_rsample_second_moment_gradient_matches_finite_differences():
    """The same for E[w^2] = alpha (alpha + 1) / ((alpha + beta)(alpha + beta + 1)): not only the mean is right."""
    torch.manual_seed(1)
    a, b = 2.0, 3.0
    alpha = torch.tensor([a], dtype=torch.float64, requires_grad=True)
    w = BetaDistribution(alpha.expand(400_000, 1), torch.full((400_000, 1), b, dtype=torch.float64)).rsample()
    (w**2).mean().backward()

    def second(x: float) -> float:
        return x * (x + 1) / ((x + b) * (x + b + 1))

    h = 1e-5
    assert alpha.grad.item() == pytest.approx((second(a + h) - second(a - h)) / (2 * h), abs=2e-3)


# --------------------------------------------------------------------------------------------------- the math
def test_soft_q_target_by_hand():
    rewards = torch.tensor([1.0, 2.0, 0.5])
    terminated = torch.tensor([0.0, 1.0, 0.0])
    q1, q2 = torch.tensor([10.0, 10.0, -1.0]), torch.tensor([8.0, 12.0, -3.0])
    logp = torch.tensor([-1.0, 0.5, 2.0])
    target = soft_q_target(rewards, terminated, q1, q2, logp, temperature=0.2, gamma=0.9)
    expected = [1.0 + 0.9 * (8.0 + 0.2), 2.0, 0.5 + 0.9 * (-3.0 - 0.4)]
    np.testing.assert_allclose(target.numpy(), expected, rtol=1e-6)


def test_temperature_rises_below_the_target_entropy_and_falls_above():
    for logp, direction in ((torch.full((64,), 3.0), 1), (torch.full((64,), -3.0), -1)):  # entropy -3, then +3
        log_t = torch.tensor(0.0, requires_grad=True)
        optimizer = torch.optim.SGD([log_t], lr=0.1)
        for _ in range(5):
            optimizer.zero_grad()
            temperature_loss(log_t, logp, target_entropy=-1.0).backward()
            optimizer.step()
        assert direction * log_t.item() > 0.5


def test_soft_update_is_polyak_averaging():
    source, target = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    before = target.weight.detach().clone()
    soft_update(target, source, tau=0.25)
    np.testing.assert_allclose(target.weight.detach().numpy(), (0.75 * before + 0.25 * source.weight).detach().numpy())
    soft_update(target, source, tau=1.0)
    assert torch.equal(target.weight, source.weight)


def test_twin_critics_are_independent_networks():
    q = TwinQ(5, 3, (16, 16))
    out = q(torch.randn(7, 5), torch.rand(7, 3))
    assert out.shape == (2, 7)
    assert not torch.allclose(out[0], out[1])


def test_the_actor_loss_never_moves_the_critics():
    torch.manual_seed(0)
    policy, critics = ActorCritic(4, 3, "beta", (16,)), TwinQ(4, 3, (16,))
    target = TwinQ(4, 3, (16,))
    buffer = ReplayBuffer(100, 4, 3)
    rng = np.random.default_rng(0)
    buffer.add(rng.normal(size=(50, 4)), rng.random((50, 3)), rng.random(50), rng.normal(size=(50, 4)), np.zeros(50),
               np.full(50, 0.9))  # fmt: skip
    losses = sac_losses(policy, critics, target, buffer.sample(32, torch.Generator().manual_seed(0)), 0.1)
    (losses["actor"] + losses["value"]).backward(inputs=list(policy.parameters()))
    assert all(p.grad is None for p in critics.parameters())
    assert all(p.grad is not None for p in policy.actor_head.parameters())


def test_an_ensemble_target_takes_the_min_of_its_pair_and_the_actor_the_min_or_the_mean():
    """With N critics, the critics' target is the soft target of the chosen pair of target critics only, and the
    actor's Q is the min (SAC's) or the mean (REDQ's) over all N (checked against each critic evaluated by hand)."""
    torch.manual_seed(0)
    policy, critics, target = ActorCritic(4, 3, "beta", (16,)), TwinQ(4, 3, (16,), n=4), TwinQ(4, 3, (16,), n=4)
    buffer = ReplayBuffer(100, 4, 3)
    rng = np.random.default_rng(0)
    buffer.add(rng.normal(size=(50, 4)), rng.random((50, 3)), rng.random(50), rng.normal(size=(50, 4)), np.zeros(50),
               np.full(50, 0.9))  # fmt: skip
    batch = buffer.sample(32, torch.Generator().manual_seed(0))
    out = {}
    for pair, actor_q in (((2, 3), "min"), ((0, 2), "mean")):
        torch.manual_seed(1)  # the same rsampled weights in both calls and below
        out[actor_q] = sac_losses(policy, critics, target, batch, 0.1, target_pair=pair, actor_q=actor_q)
        torch.manual_seed(1)
        with torch.no_grad():
            next_w = policy.distribution(batch.next_obs).rsample()
            next_logp = policy.distribution(batch.next_obs).log_prob(next_w)
            next_q = torch.stack([target.critics[i](torch.cat([batch.next_obs, next_w], -1)).squeeze(-1) for i in pair])
        expected = batch.rewards + batch.discount * (next_q.min(0).values - 0.1 * next_logp)
        torch.testing.assert_close(out[actor_q]["target"], expected)
    assert not torch.allclose(out["min"]["target"], out["mean"]["target"])
    assert (out["min"]["q_pi"] < out["mean"]["q_pi"]).all()  # the same rsampled weights: the min of 4 lies below


def _terminal_batch(obs: np.ndarray, samples: np.ndarray, rewards: np.ndarray):
    """Transitions that all end an episode: the critics' target is the reward itself (a plain regression)."""
    n = len(rewards)
    buffer = ReplayBuffer(n, obs.shape[1], samples.shape[1])
    buffer.add(obs, samples, rewards, obs, np.ones(n), np.full(n, 0.9))
    state = buffer.state_dict()
    return ReplayBatch(*(state[k] for k in ("obs", "samples", "rewards", "next_obs", "terminated", "discount")))


def test_the_critics_gradient_penalty_is_the_squared_slope_in_the_weights():
    """The critics' loss with ``grad_penalty`` = lambda is the plain loss plus lambda * E ||d(Q_1 + Q_2) / dw||^2,
    the slope checked against central finite differences of the critics in each weight."""
    torch.manual_seed(0)
    policy, critics, target = ActorCritic(3, 2, "beta", (8,)), TwinQ(3, 2, (16,)), TwinQ(3, 2, (16,))
    rng = np.random.default_rng(0)
    batch = _terminal_batch(rng.normal(size=(40, 3)), rng.random((40, 2)), rng.random(40))
    plain = sac_losses(policy, critics, target, batch, 0.1)["q"]
    penalised = sac_losses(policy, critics, target, batch, 0.1, grad_penalty=0.5)["q"]
    h, slopes = 1e-3, []
    with torch.no_grad():
        for k in range(2):
            step = torch.zeros(2)
            step[k] = h
            up, down = critics(batch.obs, batch.samples + step), critics(batch.obs, batch.samples - step)
            slopes.append((up - down).sum(0) / (2 * h))
    expected = 0.5 * (torch.stack(slopes, -1) ** 2).sum(-1).mean()
    assert (penalised - plain).item() == pytest.approx(expected.item(), rel=1e-2)
    assert torch.equal(sac_losses(policy, critics, target, batch, 0.1, grad_penalty=0.0)["q"], plain)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("n_critics", 1, "sac.n_critics must be at least 2"),
        ("actor_q", "max", "sac.actor_q must be 'min' or 'mean'"),
        ("critic_grad_penalty", -0.1, "sac.critic_grad_penalty must be >= 0"),
        ("critic_grad_penalty_start", -1, "sac.critic_grad_penalty_start must be a non-negative integer"),
    ],
)
def test_bad_ensemble_and_penalty_settings_are_one_config_error(key, value, message):
    from hrtc.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        SACConfig(**{key: value})


# --------------------------------------------------------------------------------------------------- replay buffer
def test_n_step_transitions_sum_discounted_rewards_and_stop_at_an_episode_end():
    """Two envs, n = 3, gamma 0.5: env 0 runs on (its 3rd decision completes its 1st transition); env 1 ends its
    episode (terminated) at its 2nd decision, which flushes both of its pending decisions with what they summed."""
    acc = NStepAccumulator(3, 0.5)
    obs = lambda t: np.array([[t, 0.0], [t, 1.0]], np.float32)  # noqa: E731  (obs = (decision, env))
    w = np.zeros((2, 1), np.float32)
    no = np.zeros(2, bool)
    assert acc.push(obs(0), w, np.array([1.0, 10.0]), obs(1), no, no) is None
    out = acc.push(obs(1), w, np.array([2.0, 20.0]), obs(2), np.array([False, True]), no)
    o, _, ret, nxt, term, disc = out  # env 1's two decisions: 10 + 0.5 * 20, and 20
    np.testing.assert_allclose(o[:, 0], [0, 1]) and np.testing.assert_allclose(o[:, 1], [1, 1])
    np.testing.assert_allclose(ret, [20.0, 20.0])
    np.testing.assert_allclose(nxt, [[2, 1], [2, 1]])
    np.testing.assert_allclose(term, [1, 1]) and np.testing.assert_allclose(disc, [0.25, 0.5])
    o, _, ret, nxt, term, disc = acc.push(obs(2), w, np.array([4.0, 0.0]), obs(3), no, no)
    np.testing.assert_allclose(o, [[0, 0]])  # env 0: 1 + 0.5 * 2 + 0.25 * 4, bootstrapped from decision 3
    np.testing.assert_allclose(ret, [3.0]) and np.testing.assert_allclose(nxt, [[3, 0]])
    np.testing.assert_allclose(term, [0]) and np.testing.assert_allclose(disc, [0.125])
    restored = NStepAccumulator(3, 0.5)
    restored.load_state_dict(acc.state_dict())  # what is pending survives a checkpoint
    assert [len(q) for q in restored.pending] == [2, 1]
    np.testing.assert_allclose(restored.pending[0][0][0], [1, 0])


def test_one_step_transitions_are_the_decisions_themselves():
    acc = NStepAccumulator(1, 0.9)
    o, w, r, nxt, term, disc = acc.push(np.ones((2, 3)), np.ones((2, 2)), np.array([1.0, 2.0]), np.zeros((2, 3)),
                                        np.array([False, True]), np.array([True, False]))  # fmt: skip
    np.testing.assert_allclose(r, [1, 2]) and np.testing.assert_allclose(term, [0, 1])
    np.testing.assert_allclose(disc, [0.9, 0.9])


def test_replay_buffer_wraps_around_and_keeps_the_newest():
    buffer = ReplayBuffer(5, 1, 1)
    for i in range(7):  # 7 single transitions into 5 places: 0 and 1 are overwritten
        buffer.add(np.full((1, 1), i), np.full((1, 1), i), np.array([i]), np.full((1, 1), i + 1), np.array([0.0]),
                   np.array([0.9]))  # fmt: skip
    assert len(buffer) == 5 and buffer.position == 2
    assert sorted(buffer.rewards.tolist()) == [2, 3, 4, 5, 6]
    state = buffer.state_dict()
    assert state["rewards"].tolist() == [2, 3, 4, 5, 6]  # oldest first
    other = ReplayBuffer(3, 1, 1)
    other.load_state_dict(state)  # a smaller buffer keeps the newest
    assert sorted(other.rewards.tolist()) == [4, 5, 6]


def test_replay_buffer_samples_whole_transitions_uniformly():
    buffer = ReplayBuffer(10, 2, 1)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 2)).astype(np.float32)
    buffer.add(obs, obs[:, :1], obs[:, 0], obs + 1, np.array([0, 1, 0, 1]), np.full(4, 0.9))
    batch = buffer.sample(4000, torch.Generator().manual_seed(0))
    np.testing.assert_array_equal(batch.next_obs.numpy(), batch.obs.numpy() + 1)  # rows stay together
    np.testing.assert_array_equal(batch.rewards.numpy(), batch.obs[:, 0].numpy())
    counts = np.unique(batch.rewards.numpy(), return_counts=True)[1]
    assert len(counts) == 4 and counts.min() > 850  # only what was added, about 1000 each


def test_sac_config_validation():
    with pytest.raises(Exception, match="sac.batch_size"):
        SACConfig(batch_size=0)
    with pytest.raises(Exception, match="sac.updates_per_decision"):
        SACConfig(updates_per_decision=0)


def test_learner_takes_updates_per_decision_gradient_steps_after_learning_starts():
    policy = ActorCritic(2, 2, "beta", (8,))
    learner = SACLearner(policy, SACConfig(batch_size=4, learning_starts=8, updates_per_decision=0.5, q_hidden=(8,),
                                           log_every=1000), 0.9, torch.Generator().manual_seed(0))  # fmt: skip
    obs = np.zeros((2, 2), np.float32)
    step = Step(obs, np.full((2, 2), 0.5, np.float32), np.ones(2), obs, np.zeros(2, bool), np.zeros(2, bool))
    for _ in range(4):  # 8 decisions: learning starts with the 4th step
        learner.observe(step)
        learner.update()
    assert learner.gradient_steps == 1  # 2 decisions x 0.5
    for _ in range(6):
        learner.observe(step)
        learner.update()
    assert learner.gradient_steps == 7


def _critics_after(cfg: SACConfig, n_steps: int) -> list[torch.Tensor]:
    """The critics' parameters after ``n_steps`` observed steps of 2 envs (varied states, rewards and weights)."""
    torch.manual_seed(0)
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    for _ in range(n_steps):
        obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
        learner.update()
    return [p.detach().clone() for p in learner.critics.parameters()]


def test_the_critics_penalty_applies_only_from_its_start():
    """Before ``critic_grad_penalty_start`` decisions a penalised learner trains exactly as an unpenalised one; from
    then on its critics move differently."""
    base = dict(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000)
    plain = _critics_after(SACConfig(**base), 10)
    late = _critics_after(SACConfig(**base, critic_grad_penalty=1.0, critic_grad_penalty_start=21), 10)
    early = _critics_after(SACConfig(**base, critic_grad_penalty=1.0, critic_grad_penalty_start=10), 10)
    # 10 steps of 2 envs: 20 decisions, short of the late start (21); the early one applies from the 5th step on
    assert all(torch.equal(a, b) for a, b in zip(plain, late, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(plain, early, strict=True))


# --------------------------------------------------------------------------------------------------- learning
SWITCH_TASK = "test_switch_line"


class SwitchLine(gym.Env):
    """A point on a line, reward -|x| per step, 25 steps from a random start in [-1, 1]: the right move depends on
    the side, so a meta-policy over a left and a right skill must switch with the state."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def skill_state(self):
        return {"position": np.array([self.x])}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = float(self.np_random.uniform(-1, 1)), 0
        return np.array([self.x], np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + 0.2 * float(action[0]), -2, 2))
        self.t += 1
        return np.array([self.x], np.float32), -abs(self.x), False, self.t >= 25, {}


if SWITCH_TASK not in envs.names():
    envs.register(SWITCH_TASK)(SwitchLine)

SWITCH_SKILLS = {
    "left": {"skill": {"_target_": "skills.static.StaticIntent", "action": [-1.0]}},
    "right": {"skill": {"_target_": "skills.static.StaticIntent", "action": [1.0]}},
}


def test_sac_meta_policy_learns_a_state_dependent_switch(tmp_path):
    """Trained by the real Trainer with learner=sac, the Beta means put the right skill up left of 0 and the left
    skill up right of it (a constant weighting cannot do both), and the evaluation return improves."""
    cfg = RunConfig(
        task=SWITCH_TASK, skills=SWITCH_SKILLS, learner="sac", seed=0, steps=5_000, num_envs=2, vector="sync",
        eval_every=2_500, eval_episodes=10, progress=False, hidden=(32, 32),
        sac=SACConfig(q_hidden=(64, 64), batch_size=64, learning_starts=200, gamma=0.9, learning_rate=1e-3),
    )  # fmt: skip
    Trainer(cfg, tmp_path).train()
    evals = pd.read_csv(tmp_path / "eval.csv")
    loaded = load_policy(tmp_path / "checkpoints" / "last.pt")
    with torch.no_grad():
        left_side = loaded.policy.distribution(torch.full((64, 1), -0.6)).mode().mean(0).numpy()
        right_side = loaded.policy.distribution(torch.full((64, 1), 0.6)).mode().mean(0).numpy()
    print("weights (left, right) at x=-0.6:", left_side, "at x=0.6:", right_side, list(evals["episode_reward"]))
    assert left_side[1] - left_side[0] > 0.4  # push right when left of the goal
    assert right_side[0] - right_side[1] > 0.4  # push left when right of it
    assert evals["episode_reward"].iloc[-1] > evals["episode_reward"].iloc[0] + 1.0
    train = pd.read_csv(tmp_path / "train.csv")
    assert {"losses/q_loss", "losses/temperature", "losses/entropy"} <= set(train.columns)
    assert train["losses/gradient_steps"].sum() > 0


# ------------------------------------------------------------------------------------------ critics on the action
class Homing:
    """Proposes ``-gain * position``: a state-dependent proposal (a skill's state filter reads ``position``)."""

    state_keys = ("position",)

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = float(gain)

    def reset(self, rng):
        pass

    def act(self, state):
        from hrtc.skill import SkillOutput

        return SkillOutput(np.array([-self.gain * float(state[0])]), {"status": 0.0})


ACTION_SKILLS = {
    **SWITCH_SKILLS,
    "home": {"skill": {"_target_": "tests.hrtc.test_sac.Homing", "gain": 3.0}},
    "hold": {"skill": {"_target_": "skills.static.StaticIntent", "action": [0.0]}},
}


@pytest.mark.parametrize(("mode", "margin"), [("sum", 0.25), ("sum", 0.0), ("convex", 0.25)])
def test_the_action_map_is_the_action_the_composed_env_applies(mode, margin):
    """For random Beta samples, ``ActionMap`` on the reset's ``next_proposals`` equals the action the real composed
    env applies at the decision's first step (weights mapped onto [-m, 1 + m], clipped, blended, clipped to the
    bounds), scaled from the bounds to [-1, 1]; and each step's ``next_proposals`` are what the next step blends."""
    from hrtc.environments import make_env
    from hrtc.policy import to_action

    env = make_env(SWITCH_TASK, "hrtc", ACTION_SKILLS, mode, decision_every=1, weight_margin=margin)
    action_map = ActionMap.of(env, "beta")
    rng = np.random.default_rng(0)
    for episode in range(20):
        _, info = env.reset(seed=episode)
        proposals = info["next_proposals"]
        for _ in range(3):
            u = rng.random(4)
            _, _, _, _, step_info = env.step(to_action(u, env.action_space.low, env.action_space.high, "beta"))
            np.testing.assert_array_equal(step_info["proposals"], proposals)
            mapped = action_map(torch.as_tensor(u[None]), torch.as_tensor(proposals[None]))
            np.testing.assert_allclose(mapped.numpy()[0], step_info["action"], atol=1e-12)  # bounds [-1, 1]: scale 1
            proposals = step_info["next_proposals"]


def test_through_the_action_a_weight_moves_the_critic_by_its_skills_proposal_and_an_idle_skill_not_at_all():
    """d(action)/d(sample_k) = (high - low) * a_k / half-range (finite differences agree inside the bounds; the same
    straight through beyond them), so the critic's gradient in the weight of a skill proposing 0 is exactly 0."""
    action_map = ActionMap(np.full(3, -0.25), np.full(3, 1.25), np.array([-2.0]), np.array([2.0]))
    proposals = torch.tensor([[[0.5], [-1.5], [0.0]]], dtype=torch.float64)
    u = torch.tensor([[0.3, 0.4, 0.9]], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(action_map(u, proposals).sum(), u)
    np.testing.assert_allclose(grad.numpy()[0], 1.5 * proposals[0, :, 0].numpy() / 2.0)
    h = 1e-6
    for k in range(2):
        step = torch.zeros_like(u)
        step[0, k] = h
        fd = (action_map(u + step, proposals) - action_map(u - step, proposals)).item() / (2 * h)
        assert fd == pytest.approx(grad[0, k].item(), rel=1e-6)
    saturated = torch.tensor([[0.99, 0.01, 0.5]], dtype=torch.float64, requires_grad=True)  # w past [0, 1]
    (grad_beyond,) = torch.autograd.grad(action_map(saturated, proposals).sum(), saturated)
    torch.testing.assert_close(grad_beyond, grad)
    critics = TwinQ(2, 1, (16,)).double()
    q = critics(torch.randn(1, 2, dtype=torch.float64), action_map(u, proposals)).sum()
    (q_grad,) = torch.autograd.grad(q, u)
    assert q_grad[0, 2].item() == 0.0 and q_grad[0, :2].abs().min().item() > 0.0


def test_a_buffer_with_proposals_keeps_them_with_their_transitions_and_through_n_steps():
    """The n-step accumulator hands on the first decision's proposals and the bootstrap state's; the buffer samples
    whole rows, survives its state dict, and a buffer saved without proposals is one clear error."""
    from hrtc.errors import CheckpointError

    acc = NStepAccumulator(2, 0.5)
    obs = lambda t: np.array([[t], [t + 100]], np.float32)  # noqa: E731
    props = lambda t: np.array([[[t], [-t]], [[t + 100], [-t - 100]]], np.float32)  # noqa: E731  (N, K=2, A=1)
    no, w = np.zeros(2, bool), np.zeros((2, 2), np.float32)
    assert acc.push(obs(0), w, np.ones(2), obs(1), no, no, props(0), props(1)) is None
    out = acc.push(obs(1), w, np.ones(2), obs(2), no, no, props(1), props(2))
    assert len(out) == 8
    np.testing.assert_array_equal(out[6], props(0)) and np.testing.assert_array_equal(out[7], props(2))
    buffer = ReplayBuffer(3, 1, 2, (2, 1))
    buffer.add(*out)
    buffer.add(*acc.push(obs(2), w, np.ones(2), obs(3), no, np.ones(2, bool), props(2), props(3)))  # wraps around
    batch = buffer.sample(500, torch.Generator().manual_seed(0))
    torch.testing.assert_close(batch.proposals[:, 0, 0], batch.obs[:, 0])  # rows stay together
    torch.testing.assert_close(batch.next_proposals[:, 1, 0], -batch.next_obs[:, 0])
    restored = ReplayBuffer(3, 1, 2, (2, 1))
    restored.load_state_dict(buffer.state_dict())
    np.testing.assert_array_equal(np.sort(restored.proposals[:, 0, 0]), np.sort(buffer.proposals[:, 0, 0]))
    with pytest.raises(CheckpointError, match="another sac.critic_input"):
        ReplayBuffer(3, 1, 2, (2, 1)).load_state_dict(ReplayBuffer(3, 1, 2).state_dict())


def test_critics_on_the_action_need_skills_and_a_known_input():
    from hrtc.errors import ConfigError

    with pytest.raises(ConfigError, match="sac.critic_input must be 'weights' or 'action'"):
        SACConfig(critic_input="blend")
    with pytest.raises(ConfigError, match="sac.critic_input=action needs skills"):
        SACLearner(ActorCritic(2, 2, "beta", (8,)), SACConfig(critic_input="action"), 0.9, torch.Generator())


@pytest.mark.slow
def test_sac_with_critics_on_the_action_learns_the_switch_from_the_real_trainer(tmp_path):
    """``sac.critic_input=action`` through the real Trainer: the Beta means learn the state-dependent switch."""
    cfg = RunConfig(
        task=SWITCH_TASK, skills=SWITCH_SKILLS, learner="sac", seed=0, steps=5_000, num_envs=2, vector="sync",
        eval_every=2_500, eval_episodes=10, progress=False, hidden=(32, 32),
        sac=SACConfig(q_hidden=(64, 64), batch_size=64, learning_starts=200, gamma=0.9, learning_rate=1e-3,
                      critic_input="action"),
    )  # fmt: skip
    trainer = Trainer(cfg, tmp_path)
    trainer.train()
    loaded = load_policy(tmp_path / "checkpoints" / "last.pt")
    with torch.no_grad():
        left_side = loaded.policy.distribution(torch.full((64, 1), -0.6)).mode().mean(0).numpy()
        right_side = loaded.policy.distribution(torch.full((64, 1), 0.6)).mode().mean(0).numpy()
    assert left_side[1] - left_side[0] > 0.4 and right_side[0] - right_side[1] > 0.4
    evals = pd.read_csv(tmp_path / "eval.csv")
    assert evals["episode_reward"].iloc[-1] > evals["episode_reward"].iloc[0] + 1.0


def test_the_real_trainer_stores_each_decisions_proposals_for_its_two_states(tmp_path):
    """With ``sac.critic_input=action`` (two envs, episodes ending on time limits), every stored transition holds the
    skills' own proposals at its state and at the state it bootstraps from (the homing skill's is ``-3 x``)."""
    sac = SACConfig(q_hidden=(8,), batch_size=16, learning_starts=50, critic_input="action")
    home = RunConfig(task=SWITCH_TASK, skills=ACTION_SKILLS, learner="sac", seed=0, steps=1_000, num_envs=2,
                     vector="sync", eval_every=10_000, progress=False, hidden=(8,), sac=sac)  # fmt: skip
    trainer = Trainer(home, tmp_path)
    trainer.train()
    buffer = trainer.learner.buffer
    n = len(buffer)
    assert n >= 150
    np.testing.assert_allclose(buffer.proposals[:n, 2, 0], -3 * buffer.obs[:n, 0], atol=1e-5)
    np.testing.assert_allclose(buffer.next_proposals[:n, 2, 0], -3 * buffer.next_obs[:n, 0], atol=1e-5)
    np.testing.assert_array_equal(buffer.proposals[:n, :2, 0], np.tile([-1.0, 1.0], (n, 1)))


# --------------------------------------------------------------------------------------------------- colored noise
@pytest.mark.parametrize("length", [200, 201])
def test_powerlaw_noise_is_standard_normal_per_point_with_the_asked_spectrum(length):
    """Each point has unit variance for every exponent; white noise is uncorrelated in time, pink (1) and red (2)
    increasingly correlated; the averaged periodogram falls with the asked slope in log-log."""
    from hrtc.sac import powerlaw_noise

    rng = np.random.default_rng(0)
    lag1 = {}
    for exponent in (0.0, 1.0, 2.0):
        x = powerlaw_noise(exponent, (4000,), length, rng)
        assert x.shape == (4000, length)
        assert x.std(axis=0).mean() == pytest.approx(1.0, abs=0.03)
        lag1[exponent] = np.corrcoef(x[:, :-1].ravel(), x[:, 1:].ravel())[0, 1]
        power = (np.abs(np.fft.rfft(x, axis=-1)) ** 2).mean(0)[1:-1]
        f = np.fft.rfftfreq(length)[1:-1]
        slope = np.polyfit(np.log(f), np.log(power), 1)[0]
        assert slope == pytest.approx(-exponent, abs=0.1)
    assert abs(lag1[0.0]) < 0.01 and 0.6 < lag1[1.0] < 0.8 and lag1[2.0] > 0.95


def test_colored_exploration_keeps_the_policys_marginal_and_correlates_successive_decisions():
    """``quantile`` of the colored uniforms is distributed as the Beta itself (Kolmogorov-Smirnov against its CDF)
    while successive decisions of one env are correlated; an ended episode restarts its env's sequence, and the
    noise resumes exactly from the learner's state dict."""
    from scipy import stats

    from hrtc.sac import ColoredNoise

    alpha, beta = torch.full((1, 2), 2.0), torch.full((1, 2), 5.0)
    dist = BetaDistribution(alpha.expand(3, 2), beta.expand(3, 2))
    noise = ColoredNoise(1.0, 2, 50, np.random.default_rng(0))
    draws = np.stack([dist.quantile(noise.next(3)) for _ in range(2000)])  # (T, 3 envs, 2)
    assert stats.kstest(draws.ravel(), stats.beta(2.0, 5.0).cdf).pvalue > 0.01
    assert np.corrcoef(draws[:-1, 0, 0], draws[1:, 0, 0])[0, 1] > 0.5
    u = np.random.default_rng(1).random((3, 2))
    np.testing.assert_allclose(stats.beta(2.0, 5.0).cdf(dist.quantile(u)), u, rtol=1e-5)
    normal = NormalDistribution(torch.zeros(3, 2), torch.full((3, 2), 2.0))
    np.testing.assert_allclose(normal.quantile(np.full((3, 2), 0.975)), 2.0 * 1.959964, rtol=1e-5)
    for _ in range(3):
        noise.next(3)
    before = noise.sequences.copy()
    noise.restart(np.array([False, True, False]))
    noise.next(3)
    assert noise.position.tolist() == [4, 1, 4]  # env 1 starts a fresh sequence, the others go on
    assert np.array_equal(noise.sequences[[0, 2]], before[[0, 2]]) and not np.allclose(noise.sequences[1], before[1])
    policy = ActorCritic(2, 2, "beta", (8,))
    cfg = SACConfig(noise_color=1.0, noise_length=20, q_hidden=(8,))
    learner = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0))
    obs = np.zeros((2, 2), np.float32)
    for _ in range(7):
        learner.act(obs)
    twin = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(5))
    twin.load_state_dict(learner.state_dict())
    np.testing.assert_array_equal(twin.act(obs)[0], learner.act(obs)[0])


def test_white_exploration_draws_nothing_extra():
    """``noise_color=0`` (the default) builds no noise process and leaves the learner's generator untouched."""
    generator = torch.Generator().manual_seed(3)
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), SACConfig(q_hidden=(8,)), 0.9, generator)
    assert learner.noise is None
    assert torch.equal(generator.get_state(), torch.Generator().manual_seed(3).get_state())
