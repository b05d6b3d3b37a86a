"""The Beta and Normal heads: support, finite log-probabilities at the boundaries, entropy, the evaluation rule."""

import math

import pytest
import torch

from hrtc.distributions import BETA_EPS, BetaDistribution, BetaHead, NormalHead, make_head
from hrtc.errors import UnknownNameError


def test_beta_head_parameters_are_at_least_one():
    head = BetaHead(8, 3)
    with torch.no_grad():
        head.linear.bias.fill_(-50.0)  # softplus -> 0: alpha, beta -> 1 from above
        dist = head(torch.randn(16, 8))
    assert torch.all(dist.alpha >= 1.0) and torch.all(dist.beta >= 1.0)


def test_beta_head_starts_centred():
    dist = BetaHead(4, 5)(torch.zeros(1, 4))
    expected = 1.0 + math.log(2.0)
    assert torch.allclose(dist.alpha, torch.full((1, 5), expected), atol=1e-6)
    assert torch.allclose(dist.mode(), torch.full((1, 5), 0.5))


def test_beta_head_starts_at_the_given_means_with_its_own_concentration_scale():
    head = BetaHead(4, 4)
    head.start_at(torch.tensor([0.5, 0.9, 0.1, 0.75]))
    dist = head(torch.zeros(1, 4))
    c = 1.0 + math.log(2.0)  # the head's starting softplus(0) + 1
    assert torch.allclose(dist.mode(), torch.tensor([[0.5, 0.9, 0.1, 0.75]]), atol=1e-6)
    assert torch.allclose(torch.minimum(dist.alpha, dist.beta), torch.full((1, 4), c), atol=1e-5)
    assert torch.allclose(dist.alpha[0, 1], torch.tensor(9 * c), rtol=1e-5)  # mean 0.9: Beta(9c, c)


def test_beta_samples_lie_strictly_inside_unit_interval():
    torch.manual_seed(0)
    # Very concentrated at the edges: raw float32 samples hit exactly 0.0 and 1.0 here.
    dist = BetaDistribution(
        torch.tensor([[1.0, 300.0]]).expand(20000, 2), torch.tensor([[300.0, 1.0]]).expand(20000, 2)
    )
    u = dist.sample()
    assert torch.all(u > 0.0) and torch.all(u < 1.0)
    assert torch.all(torch.isfinite(dist.log_prob(u)))


@pytest.mark.parametrize("value", [0.0, 1.0])
def test_beta_log_prob_is_finite_at_the_boundaries(value):
    dist = BetaDistribution(torch.tensor([[3.0, 1.5]]), torch.tensor([[2.0, 7.0]]))
    logp = dist.log_prob(torch.full((1, 2), value))
    assert torch.isfinite(logp).all()
    # ... and equals the density at the nearest interior point we keep samples to.
    inner = torch.full((1, 2), BETA_EPS if value == 0 else 1 - BETA_EPS)
    assert torch.allclose(logp, dist.log_prob(inner))


def test_beta_log_prob_sums_over_components():
    alpha, beta = torch.tensor([[2.0, 3.0]]), torch.tensor([[4.0, 1.5]])
    u = torch.tensor([[0.3, 0.8]])
    expected = sum(torch.distributions.Beta(alpha[0, i], beta[0, i]).log_prob(u[0, i]) for i in range(2))
    assert torch.allclose(BetaDistribution(alpha, beta).log_prob(u), expected.reshape(1))


@pytest.mark.parametrize("alpha,beta", [(1.0, 1.0), (1.7, 1.7), (5.0, 2.0), (30.0, 60.0)])
def test_beta_entropy_matches_monte_carlo(alpha, beta):
    torch.manual_seed(1)
    dist = BetaDistribution(torch.full((1, 1), alpha), torch.full((1, 1), beta))
    samples = torch.distributions.Beta(torch.tensor(alpha), torch.tensor(beta)).sample((200_000, 1))
    mc = -dist.log_prob(samples.clamp(BETA_EPS, 1 - BETA_EPS)).mean()
    stderr = dist.log_prob(samples).std() / math.sqrt(200_000)
    assert abs(float(dist.entropy()) - float(mc)) < 5 * float(stderr) + 1e-4


def test_beta_mode_is_the_mean_not_a_sample():
    dist = BetaDistribution(torch.tensor([[2.0, 9.0]]), torch.tensor([[6.0, 1.0]]))
    assert torch.allclose(dist.mode(), torch.tensor([[0.25, 0.9]]))
    assert torch.equal(dist.mode(), dist.mode())
    assert torch.allclose(dist.concentration, torch.tensor([[8.0, 10.0]]))


def test_normal_head_mode_and_entropy():
    head = NormalHead(4, 3, init_mean=0.5, init_log_std=math.log(0.25))
    dist = head(torch.zeros(2, 4))
    assert torch.allclose(dist.mode(), torch.full((2, 3), 0.5))
    expected = 3 * (0.5 * math.log(2 * math.pi * math.e) + math.log(0.25))
    assert torch.allclose(dist.entropy(), torch.full((2,), expected), atol=1e-5)


def test_unknown_head_names_the_choices():
    with pytest.raises(UnknownNameError, match="beta, normal"):
        make_head("gamma", 4, 2)
