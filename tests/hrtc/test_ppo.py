"""GAE against hand-computed closed forms, and the PPO update's basic behaviour."""

import numpy as np
import pytest
import torch

from hrtc.policy import ActorCritic
from hrtc.ppo import Batch, PPOConfig, compute_gae, explained_variance, ppo_update


def test_gae_lambda_one_is_discounted_return_minus_value():
    rng = np.random.default_rng(0)
    rewards, values = rng.normal(size=(6, 1)), rng.normal(size=(6, 1))
    next_value, gamma = np.array([0.7]), 0.9
    adv, ret = compute_gae(rewards, values, np.zeros((6, 1)), next_value, gamma, lam=1.0)
    expected = [sum(gamma**k * rewards[t + k, 0] for k in range(6 - t)) + gamma ** (6 - t) * 0.7 for t in range(6)]
    np.testing.assert_allclose(ret[:, 0], expected)
    np.testing.assert_allclose(adv, ret - values)


def test_gae_lambda_zero_is_the_td_error():
    rewards = np.array([[1.0], [2.0], [3.0]])
    values = np.array([[0.5], [0.25], [1.0]])
    adv, _ = compute_gae(rewards, values, np.zeros((3, 1)), np.array([2.0]), 0.5, lam=0.0)
    np.testing.assert_allclose(adv[:, 0], [1 + 0.5 * 0.25 - 0.5, 2 + 0.5 * 1.0 - 0.25, 3 + 0.5 * 2.0 - 1.0])


def test_gae_hand_computed_with_an_episode_end():
    # Two steps, episode ends after step 0: step 0 must not see step 1's value or reward.
    rewards, values = np.array([[1.0], [1.0]]), np.array([[0.0], [0.0]])
    dones = np.array([[1.0], [0.0]])
    adv, _ = compute_gae(rewards, values, dones, np.array([10.0]), gamma=0.9, lam=0.8)
    np.testing.assert_allclose(adv[:, 0], [1.0, 1.0 + 0.9 * 10.0])


def test_gae_is_independent_across_envs():
    rng = np.random.default_rng(3)
    r, v, d = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), (rng.random((5, 3)) < 0.3).astype(float)
    nv = rng.normal(size=3)
    adv, _ = compute_gae(r, v, d, nv, 0.99, 0.95)
    for i in range(3):
        single, _ = compute_gae(r[:, i : i + 1], v[:, i : i + 1], d[:, i : i + 1], nv[i : i + 1], 0.99, 0.95)
        np.testing.assert_allclose(adv[:, i : i + 1], single)


def test_explained_variance():
    y = np.arange(10.0)
    assert explained_variance(y, y) == pytest.approx(1.0)
    assert explained_variance(np.full(10, y.mean()), y) == pytest.approx(0.0)


@pytest.mark.parametrize("dist", ["beta", "normal"])
def test_ppo_update_raises_the_probability_of_advantaged_samples(dist):
    torch.manual_seed(0)
    policy = ActorCritic(3, 2, dist, (16,), 0.5, -1.0)
    obs = torch.randn(256, 3)
    with torch.no_grad():
        d = policy.distribution(obs)
        u = d.sample()
        logp = d.log_prob(u)
        values = policy.value(obs)
    advantages = (u[:, 0] - u[:, 0].mean()) * 10  # reward the first component being high
    batch = Batch(obs, u, logp, advantages, values + advantages, values)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-3)
    with torch.no_grad():
        before = float(policy.distribution(obs).mode()[:, 0].mean())
    stats = ppo_update(policy, opt, batch, PPOConfig(update_epochs=4, num_minibatches=4), torch.Generator())
    with torch.no_grad():
        after = float(policy.distribution(obs).mode()[:, 0].mean())
    assert after > before
    for key in ("losses/approx_kl", "losses/clipfrac", "losses/explained_variance", "losses/value_loss"):
        assert np.isfinite(stats[key])
    assert stats["losses/skipped"] == 0
