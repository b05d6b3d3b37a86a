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

from hrtc.distributions import BetaDistribution, BetaHead, NormalDistribution, make_head
from hrtc.encoders import build_encoder
from hrtc.errors import ConfigError, UnknownNameError

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU}
# orthogonal: CleanRL's (gain sqrt 2 hidden, 1 value output, 0.01 distribution head, zero biases); torch: PyTorch's
# default Linear init (uniform in +-1/sqrt(fan_in), weights and biases), as the reference CarRacing code leaves it.
WEIGHT_INITS = ("orthogonal", "torch")


DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> torch.device:
    """The torch device a ``device`` setting names: ``cpu``, ``cuda`` (the current GPU; an error when torch sees
    none) or ``auto`` (``cuda`` when torch sees a GPU, else ``cpu``)."""
    if name not in DEVICES:
        raise UnknownNameError("device", str(name), DEVICES)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device=cuda, but torch {torch.__version__} sees no GPU; use device=cpu or device=auto")
    return torch.device(name)


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
        activation: the MLPs' hidden activation, ``tanh`` or ``relu`` (the reference CarRacing network's).
        weight_init: the MLPs' and heads' initialisation, ``orthogonal`` or ``torch`` (:data:`WEIGHT_INITS`; with
            ``torch`` the Beta head's ``init_bias`` is not applied); the encoder initialises itself.
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
        activation: str = "tanh",
        weight_init: str = "orthogonal",
    ) -> None:
        super().__init__()
        if activation not in ACTIVATIONS:
            raise UnknownNameError("activation", activation, tuple(ACTIVATIONS))
        if weight_init not in WEIGHT_INITS:
            raise UnknownNameError("weight_init", weight_init, WEIGHT_INITS)
        self.obs_dim, self.out_dim, self.dist_kind = obs_dim, out_dim, dist
        self.encoder = encoder
        self._features_cache: tuple | None = None
        if encoder is not None:
            obs_dim = int(encoder.out_dim)  # the MLPs read the encoder's features
        act = ACTIVATIONS[activation]
        self.actor_body = mlp(obs_dim, hidden, act)
        if dist == "normal":
            kwargs = {"init_mean": normal_init_mean, "init_log_std": normal_init_log_std}
        else:
            kwargs = {"init_bias": beta_init_bias}
        self.actor_head = make_head(dist, hidden[-1] if hidden else obs_dim, out_dim, **kwargs)
        self.critic = nn.Sequential(mlp(obs_dim, hidden, act), nn.Linear(hidden[-1] if hidden else obs_dim, 1))
        nn.init.orthogonal_(self.critic[-1].weight, gain=1.0)
        nn.init.zeros_(self.critic[-1].bias)
        if weight_init == "torch":
            for part in (self.actor_body, self.actor_head, self.critic):
                for module in part.modules():
                    if isinstance(module, nn.Linear):
                        module.reset_parameters()

    def distribution(self, obs: torch.Tensor) -> BetaDistribution | NormalDistribution:
        """The meta-policy's distribution for ``obs`` (batch, obs_dim); uint8 pixels are converted by the encoder."""
        return self.actor_head(self.actor_body(self._inputs(obs)))

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        """V(s), (batch,)."""
        return self.critic(self._inputs(obs)).squeeze(-1)

    def _inputs(self, obs: torch.Tensor) -> torch.Tensor:
        """What the MLPs read: the encoder's features, or the observation itself as floats."""
        if self.encoder is not None:
            return self._features(obs)
        return obs if obs.is_floating_point() else obs.float()

    def _features(self, obs: torch.Tensor) -> torch.Tensor:
        """The encoder's features of ``obs``. PPO asks for ``distribution(x)`` and then ``value(x)`` of the same
        batch: the second call reuses the first's features (and autograd graph) instead of running the encoder
        twice, when the batch is equal, the grad mode is the same and no encoder weight has changed since."""
        versions = tuple(p._version for p in self.encoder.parameters())
        key = (tuple(obs.shape), obs.dtype, obs.device, torch.is_grad_enabled(), versions)
        cached = self._features_cache
        # The very same tensor, unmodified since (its version counter), needs no element-wise comparison.
        same = cached is not None and cached[1] is obs and cached[3] == obs._version
        if cached is not None and cached[0] == key and (same or torch.equal(cached[1], obs)):
            features = cached[2]
            self._features_cache = None  # one reuse: a later call recomputes (its graph may have been freed)
            return features
        features = self.encoder(obs)
        self._features_cache = (key, obs.detach() if obs.requires_grad else obs, features, obs._version)
        return features


def build_policy(obs_dim: int, low: np.ndarray, high: np.ndarray, dist: str, hidden: Sequence[int],
                 beta_init_bias: float = 0.0, encoder: Mapping[str, Any] | None = None, activation: str = "tanh",
                 weight_init: str = "orthogonal", device: str = "cpu") -> ActorCritic:  # fmt: skip
    """The meta-policy and master critic for observations of ``obs_dim`` values and samples bounded by ``low`` and
    ``high`` (one per skill weight for HRTC, per action for PPO). A Normal head starts at the centre of the bounds
    with a standard deviation of a quarter of their range; ``encoder`` is a spec for :func:`~hrtc.encoders.
    build_encoder` (pixel tasks) or None; ``activation`` and ``weight_init`` as :class:`ActorCritic`'s; placed on
    ``device`` (:func:`resolve_device`)."""
    low, high = np.asarray(low), np.asarray(high)
    centre = float(np.mean((low + high) / 2))
    log_std = float(np.log(np.mean(high - low) / 4))
    trunk = build_encoder(encoder, obs_dim) if encoder is not None else None
    return ActorCritic(obs_dim, int(low.shape[0]), dist, hidden, centre, log_std, beta_init_bias, encoder=trunk,
                       activation=activation, weight_init=weight_init).to(resolve_device(device))  # fmt: skip


def start_at(policy: ActorCritic, weights: Mapping[str, float], skills: Sequence[str], margin: float = 0.0) -> None:
    """Make the untrained HRTC meta-policy's Beta means give ``weights`` (skill name: applied weight in [0, 1]; a skill
    not named keeps the mean 0.5 of the paper's start). A weight w is the Beta mean u = (w + m) / (1 + 2 m) on the
    span [-m, 1 + m] (``margin`` m), kept in [0.05, 0.95]: with m = 0 a mean cannot reach 0 or 1, so 0 and 1 start
    at 0.05 and 0.95; with m = 0.25 they are exact. Only the Beta head's bias changes (:meth:`BetaHead.start_at`): the
    network's outputs are near its bias at the start, so every state starts at these weights, and learning moves
    them."""
    if not isinstance(policy.actor_head, BetaHead):
        raise ConfigError("starting weights need the Beta meta-policy (dist=beta)")
    means = np.full(len(skills), 0.5)
    for name, weight in weights.items():
        if name not in skills:
            raise UnknownNameError("skill", name, tuple(skills))
        means[list(skills).index(name)] = (float(weight) + margin) / (1.0 + 2.0 * margin)
    policy.actor_head.start_at(torch.as_tensor(np.clip(means, 0.05, 0.95), dtype=torch.float32))


def to_action(u: np.ndarray, low: np.ndarray, high: np.ndarray, dist: str) -> np.ndarray:
    """A sample (or the mode) ``u`` of the meta-policy's distribution as the action it stands for: Beta samples in
    (0, 1) affinely onto ``[low, high]``, Normal samples clipped to it (in the inputs' dtype). For HRTC the bounds
    are [0, 1]^K, so the weights are ``u``; a learned PPO skill maps its mode onto its task's action bounds."""
    if dist == "beta":
        return low + (high - low) * u
    return np.clip(u, low, high)
