"""The meta-policy (actor) and the master critic V(s).

The same class serves HRTC (the actor's distribution is over the K skill weights) and plain PPO (over the raw
action); only ``out_dim`` and the consumer of the sample differ, so both are compared with identical networks.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from hrtc.distributions import BetaDistribution, NormalDistribution, make_head
from hrtc.encoders import build_encoder


def mlp(in_dim: int, hidden: Sequence[int], activation: type[nn.Module] = nn.Tanh) -> nn.Sequential:
    """Orthogonally initialised MLP (gain sqrt 2), as in CleanRL's continuous PPO."""
    layers: list[nn.Module] = []
    for width in hidden:
        linear = nn.Linear(in_dim, width)
        nn.init.orthogonal_(linear.weight, gain=2**0.5)
        nn.init.zeros_(linear.bias)
        layers += [linear, activation()]
        in_dim = width
    return nn.Sequential(*layers)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs on the (normalised) observation, or on an image encoder's features.

    With an ``encoder`` (e.g. :class:`~hrtc.encoders.ConvEncoder`) both MLPs read the features of one shared
    encoder (the paper's CarRacing network: a convolutional trunk with fully connected actor and critic); the
    observation stays a flat vector and the encoder reshapes it. Without one the networks are exactly the MLPs.

    Args:
        obs_dim: observation size.
        out_dim: size of the distribution's sample (K skills for HRTC, the action size for PPO).
        dist: ``"beta"`` or ``"normal"``.
        hidden: hidden widths, shared by actor and critic.
        normal_init_mean, normal_init_log_std: the Normal head's starting point (in the sample's units).
        beta_init_bias: the Beta head's starting bias (see :class:`~hrtc.distributions.BetaHead`).
        encoder: a module mapping (batch, obs_dim) to (batch, encoder.out_dim) features, or None.
    """

    def __init__(
        self,
        obs_dim: int,
        out_dim: int,
        dist: str = "beta",
        hidden: Sequence[int] = (64, 64),
        normal_init_mean: float = 0.0,
        normal_init_log_std: float = 0.0,
        beta_init_bias: float = 0.0,
        encoder: nn.Module | None = None,
    ) -> None:
        super().__init__()
        self.obs_dim, self.out_dim, self.dist_kind = obs_dim, out_dim, dist
        self.encoder = encoder
        self._features_cache: tuple | None = None
        if encoder is not None:
            obs_dim = int(encoder.out_dim)  # the MLPs read the encoder's features
        self.actor_body = mlp(obs_dim, hidden)
        if dist == "normal":
            kwargs = {"init_mean": normal_init_mean, "init_log_std": normal_init_log_std}
        else:
            kwargs = {"init_bias": beta_init_bias}
        self.actor_head = make_head(dist, hidden[-1] if hidden else obs_dim, out_dim, **kwargs)
        self.critic = nn.Sequential(mlp(obs_dim, hidden), nn.Linear(hidden[-1] if hidden else obs_dim, 1))
        nn.init.orthogonal_(self.critic[-1].weight, gain=1.0)
        nn.init.zeros_(self.critic[-1].bias)

    def distribution(self, obs: torch.Tensor) -> BetaDistribution | NormalDistribution:
        """The meta-policy's distribution for ``obs`` (batch, obs_dim)."""
        if self.encoder is not None:
            obs = self._features(obs)
        return self.actor_head(self.actor_body(obs))

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        """V(s), (batch,)."""
        if self.encoder is not None:
            obs = self._features(obs)
        return self.critic(obs).squeeze(-1)

    def _features(self, obs: torch.Tensor) -> torch.Tensor:
        """The encoder's features of ``obs``. PPO asks for ``distribution(x)`` and then ``value(x)`` of the same
        batch: the second call reuses the first's features (and autograd graph) instead of running the encoder
        twice, when the batch is equal, the grad mode is the same and no encoder weight has changed since."""
        versions = tuple(p._version for p in self.encoder.parameters())
        key = (tuple(obs.shape), obs.dtype, torch.is_grad_enabled(), versions)
        cached = self._features_cache
        if cached is not None and cached[0] == key and torch.equal(cached[1], obs):
            features = cached[2]
            self._features_cache = None  # one reuse: a later call recomputes (its graph may have been freed)
            return features
        features = self.encoder(obs)
        self._features_cache = (key, obs.detach(), features)
        return features


def build_policy(obs_dim: int, low: np.ndarray, high: np.ndarray, dist: str, hidden: Sequence[int],
                 beta_init_bias: float = 0.0, encoder: Mapping[str, Any] | None = None) -> ActorCritic:  # fmt: skip
    """The meta-policy and master critic for observations of ``obs_dim`` values and samples bounded by ``low`` and
    ``high`` (one per skill weight for HRTC, per action for PPO). A Normal head starts at the centre of the bounds
    with a standard deviation of a quarter of their range; ``encoder`` is a spec for :func:`~hrtc.encoders.
    build_encoder` (pixel tasks) or None."""
    low, high = np.asarray(low), np.asarray(high)
    centre = float(np.mean((low + high) / 2))
    log_std = float(np.log(np.mean(high - low) / 4))
    trunk = build_encoder(encoder, obs_dim) if encoder is not None else None
    return ActorCritic(obs_dim, int(low.shape[0]), dist, hidden, centre, log_std, beta_init_bias, encoder=trunk)


def to_action(u: np.ndarray, low: np.ndarray, high: np.ndarray, dist: str) -> np.ndarray:
    """A sample (or the mode) ``u`` of the meta-policy's distribution as the action it stands for: Beta samples in
    (0, 1) affinely onto ``[low, high]``, Normal samples clipped to it (in the inputs' dtype). For HRTC the bounds
    are [0, 1]^K, so the weights are ``u``; a learned PPO skill maps its mode onto its task's action bounds."""
    if dist == "beta":
        return low + (high - low) * u
    return np.clip(u, low, high)
