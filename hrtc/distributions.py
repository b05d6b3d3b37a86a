"""Weight and action distributions, kept apart from the networks that parameterise them.

A *head* maps features to a distribution over a ``dim``-vector ``u``:
- :class:`BetaHead`: ``u_k ~ Beta(alpha_k, beta_k)`` with ``alpha, beta = softplus(.) + 1 >= 1`` (unimodal, finite
  density). Support (0, 1): HRTC's skill weights, or raw actions mapped affinely to their bounds.
- :class:`NormalHead`: ``u_k ~ Normal(mu_k, sigma_k)`` with a state-independent ``log sigma``. Unbounded: the consumer
  clips (HRTC-Normal clips weights to [0, 1] in the action filter; PPO-Normal clips actions to their bounds), and the
  log-probability is that of the unclipped sample, as in CleanRL and SB3.

Every distribution answers ``sample``, ``rsample`` (reparameterised, for SAC), ``log_prob`` (summed over the ``dim``
axis), ``entropy`` (summed) and ``mode`` (the evaluation rule: the Beta *mean* alpha / (alpha + beta), the paper's
exploitation rule; the Normal mean).
"""

from __future__ import annotations

from typing import Protocol

import torch
from torch import nn
from torch.nn import functional as F

# float32 Beta samples can round to exactly 0 or 1, where log p = -inf for alpha, beta > 1: keep them inside.
BETA_EPS = 1e-6


class WeightDistribution(Protocol):
    def sample(self) -> torch.Tensor: ...
    def rsample(self) -> torch.Tensor: ...
    def log_prob(self, u: torch.Tensor) -> torch.Tensor: ...
    def entropy(self) -> torch.Tensor: ...
    def mode(self) -> torch.Tensor: ...


class BetaDistribution:
    """Independent Beta per component. ``alpha, beta``: (batch, dim), both >= 1."""

    def __init__(self, alpha: torch.Tensor, beta: torch.Tensor) -> None:
        self.alpha, self.beta = alpha, beta
        self._dist = torch.distributions.Beta(alpha, beta)

    def sample(self) -> torch.Tensor:
        return self._dist.sample().clamp(BETA_EPS, 1.0 - BETA_EPS)

    def rsample(self) -> torch.Tensor:
        """A sample differentiable in alpha and beta (implicit reparameterisation, Figurnov et al. 2018)."""
        return self._dist.rsample().clamp(BETA_EPS, 1.0 - BETA_EPS)

    def log_prob(self, u: torch.Tensor) -> torch.Tensor:
        return self._dist.log_prob(u.clamp(BETA_EPS, 1.0 - BETA_EPS)).sum(-1)

    def entropy(self) -> torch.Tensor:
        return self._dist.entropy().sum(-1)

    def mode(self) -> torch.Tensor:
        """The Beta mean alpha / (alpha + beta) (used at evaluation, as in the paper)."""
        return self.alpha / (self.alpha + self.beta)

    @property
    def concentration(self) -> torch.Tensor:
        """alpha + beta, (batch, dim): the meta-policy's confidence in each weight."""
        return self.alpha + self.beta


class NormalDistribution:
    """Independent Normal per component. ``mean, std``: (batch, dim)."""

    def __init__(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        self.mean, self.std = mean, std
        self._dist = torch.distributions.Normal(mean, std)

    def sample(self) -> torch.Tensor:
        return self._dist.sample()

    def rsample(self) -> torch.Tensor:
        """``mean + std * eps``: differentiable in the mean and std."""
        return self._dist.rsample()

    def log_prob(self, u: torch.Tensor) -> torch.Tensor:
        return self._dist.log_prob(u).sum(-1)

    def entropy(self) -> torch.Tensor:
        return self._dist.entropy().sum(-1)

    def mode(self) -> torch.Tensor:
        return self.mean


class BetaHead(nn.Module):
    """Linear layer to ``(alpha, beta)``, each ``softplus(.) + 1``. Near-zero weights and bias ``init_bias``, so every
    component starts at ``Beta(c, c)`` with ``c = softplus(init_bias) + 1``: mean 0.5; ``init_bias=0`` gives
    c = 1.69 (std 0.27), a very negative one the uniform Beta(1, 1) (std 0.29)."""

    def __init__(self, in_features: int, dim: int, init_bias: float = 0.0) -> None:
        super().__init__()
        self.dim = dim
        self.linear = nn.Linear(in_features, 2 * dim)
        nn.init.orthogonal_(self.linear.weight, gain=0.01)
        nn.init.constant_(self.linear.bias, float(init_bias))

    def forward(self, features: torch.Tensor) -> BetaDistribution:
        alpha, beta = (F.softplus(self.linear(features)) + 1.0).chunk(2, dim=-1)
        return BetaDistribution(alpha, beta)

    @torch.no_grad()
    def start_at(self, means: torch.Tensor) -> None:
        """Set the bias so that component k starts (near-zero weights) with Beta mean ``means[k]`` in (0, 1), with
        the smaller of alpha and beta at the head's starting ``c = softplus(init bias) + 1``: a mean of 0.5 keeps
        Beta(c, c); 0.9 gives Beta(9c, c)."""
        means = torch.as_tensor(means, dtype=self.linear.bias.dtype).clamp(BETA_EPS, 1.0 - BETA_EPS)
        if means.shape != (self.dim,):
            from hrtc.errors import ShapeError

            raise ShapeError(f"start_at takes {self.dim} means, got shape {tuple(means.shape)}")
        alpha, beta = (F.softplus(self.linear.bias) + 1.0).chunk(2)
        c = torch.minimum(alpha, beta)  # the head's current (starting) concentration scale
        alpha = torch.where(means >= 0.5, c * means / (1.0 - means), c)
        beta = torch.where(means >= 0.5, c, c * (1.0 - means) / means)
        self.linear.bias.copy_(torch.cat([_inverse_softplus(alpha - 1.0), _inverse_softplus(beta - 1.0)]))


def _inverse_softplus(y: torch.Tensor) -> torch.Tensor:
    """x with softplus(x) = y, for y > 0 (``log(expm1(y))``, in a form that stays finite for large y)."""
    return y + torch.log(-torch.expm1(-y))


class NormalHead(nn.Module):
    """Linear layer to the mean; a learned, state-independent ``log sigma`` starting at ``init_log_std``."""

    def __init__(self, in_features: int, dim: int, init_mean: float = 0.0, init_log_std: float = 0.0) -> None:
        super().__init__()
        self.dim = dim
        self.linear = nn.Linear(in_features, dim)
        nn.init.orthogonal_(self.linear.weight, gain=0.01)
        nn.init.constant_(self.linear.bias, init_mean)
        self.log_std = nn.Parameter(torch.full((dim,), float(init_log_std)))

    def forward(self, features: torch.Tensor) -> NormalDistribution:
        mean = self.linear(features)
        return NormalDistribution(mean, self.log_std.exp().expand_as(mean))


def make_head(kind: str, in_features: int, dim: int, **kwargs: float) -> BetaHead | NormalHead:
    """``kind`` is ``"beta"`` or ``"normal"``; keyword arguments go to the head's constructor."""
    if kind == "beta":
        return BetaHead(in_features, dim, **kwargs)
    if kind == "normal":
        return NormalHead(in_features, dim, **kwargs)
    from hrtc.errors import UnknownNameError

    raise UnknownNameError("dist", kind, ("beta", "normal"))
