"""PPO pieces as plain functions: GAE, the clipped surrogate, and one update over a rollout (Schulman et al. 2017).

The defaults are CleanRL's continuous PPO. :data:`REFERENCE_PPO` holds the settings of the PPO CarRacing code the
paper's network follows (xtma/pytorch_car_caring ``train.py``, ``Agent``): one-step advantages r + gamma V(s') - V(s)
bootstrapped at every transition (it stores no episode ends), no advantage normalisation, smooth-L1 value loss x2, no
entropy term, no gradient clipping, buffer 2,000, minibatch 128, 10 epochs, clip 0.1, Adam lr 1e-3 (eps 1e-8).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from hrtc.errors import ConfigError, UnknownNameError

ADVANTAGES = ("gae", "one_step")
VALUE_LOSSES = ("mse", "smooth_l1")
KL_STOPS = ("epoch", "minibatch")  # where target_kl is checked: CleanRL's (after each epoch) or SB3's


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    dones: np.ndarray,
    next_value: np.ndarray,
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation.

    ``rewards``, ``values``, ``dones``: (T, N); ``dones[t]`` is 1 where the episode ended *after* step t (its
    successor is a new episode, so nothing is bootstrapped across it; bootstrap a truncation by adding
    ``gamma * V(final_obs)`` to its reward beforehand). ``next_value``: (N,), V of the state after the last step.
    Returns ``(advantages, returns)``, each (T, N), with ``returns = advantages + values``.
    """
    steps = rewards.shape[0]
    advantages = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros_like(next_value, dtype=np.float64)
    for t in reversed(range(steps)):
        following = next_value if t == steps - 1 else values[t + 1]
        nonterminal = 1.0 - dones[t]
        delta = rewards[t] + gamma * following * nonterminal - values[t]
        last = delta + gamma * lam * nonterminal * last
        advantages[t] = last
    return advantages, advantages + values


def one_step_advantages(
    rewards: np.ndarray, values: np.ndarray, dones: np.ndarray, next_value: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """One-step (TD(0)) advantages ``r_t + gamma V(s_{t+1}) (1 - done_t) - V(s_t)`` and their value targets
    ``r_t + gamma V(s_{t+1}) (1 - done_t)``; the same shapes and conventions as :func:`compute_gae` (it equals GAE
    with lambda 0). Returns ``(advantages, returns)``, each (T, N)."""
    following = np.concatenate([values[1:], next_value[None]], axis=0).astype(np.float64)
    returns = rewards + gamma * following * (1.0 - dones)
    return returns - values, returns


def value_loss(predicted: torch.Tensor, target: torch.Tensor, kind: str = "mse") -> torch.Tensor:
    """The critic's loss, a mean over the batch: ``mse`` 0.5 (V - R)^2 (CleanRL), ``smooth_l1`` Huber with
    threshold 1 (0.5 (V - R)^2 where |V - R| < 1, else |V - R| - 0.5; the reference's ``F.smooth_l1_loss``)."""
    if kind == "mse":
        return 0.5 * ((predicted - target) ** 2).mean()
    if kind == "smooth_l1":
        return F.smooth_l1_loss(predicted, target)
    raise UnknownNameError("value loss function", kind, VALUE_LOSSES)


@dataclass(frozen=True)
class PPOConfig:
    """PPO's settings. ``advantage``: ``gae`` (lambda ``gae_lambda``) or ``one_step``; ``bootstrap_terminal``: bootstrap
    gamma V(s') at terminal transitions too (the reference stores no episode ends); ``value_loss``: ``mse`` or
    ``smooth_l1``, weighted by ``vf_coef``; ``max_grad_norm``: None for no clipping; ``minibatch_size``: transitions
    per minibatch (the last one takes the remainder), else the rollout split in ``num_minibatches``; ``adam_eps``:
    Adam's epsilon."""

    learning_rate: float = 3e-4
    anneal_lr: bool = True
    num_steps: int = 512  # env steps per env per rollout
    gamma: float = 0.99
    gae_lambda: float = 0.95
    update_epochs: int = 10
    num_minibatches: int = 8
    clip_coef: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float | None = 0.5
    norm_adv: bool = True
    target_kl: float | None = None
    kl_stop: str = "epoch"
    normalize_obs: bool = True
    scale_reward: bool = True
    advantage: str = "gae"
    bootstrap_terminal: bool = False
    value_loss: str = "mse"
    minibatch_size: int | None = None
    adam_eps: float = 1e-5

    def __post_init__(self) -> None:
        if self.advantage not in ADVANTAGES:
            raise UnknownNameError("advantage estimator", self.advantage, ADVANTAGES)
        if self.value_loss not in VALUE_LOSSES:
            raise UnknownNameError("value loss function", self.value_loss, VALUE_LOSSES)
        if self.kl_stop not in KL_STOPS:
            raise UnknownNameError("ppo.kl_stop", self.kl_stop, KL_STOPS)
        size = self.minibatch_size
        if size is not None and (not isinstance(size, int) or isinstance(size, bool) or size < 1):
            raise ConfigError(f"ppo.minibatch_size must be a positive integer or null, got {size!r}")
        if self.max_grad_norm is not None and not self.max_grad_norm > 0:
            raise ConfigError(f"ppo.max_grad_norm must be positive or null, got {self.max_grad_norm!r}")
        if not self.adam_eps > 0:
            raise ConfigError(f"ppo.adam_eps must be positive, got {self.adam_eps!r}")
        for name in ("norm_adv", "bootstrap_terminal", "anneal_lr", "normalize_obs", "scale_reward"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"ppo.{name} must be true or false, got {getattr(self, name)!r}")


# The reference CarRacing PPO (module docstring) in this PPO's terms; num_steps x num_envs = 2,000 transitions.
REFERENCE_PPO: dict[str, Any] = {
    "learning_rate": 1e-3, "anneal_lr": False, "gamma": 0.99, "update_epochs": 10, "clip_coef": 0.1,
    "ent_coef": 0.0, "vf_coef": 2.0, "max_grad_norm": None, "norm_adv": False, "normalize_obs": False,
    "scale_reward": False, "advantage": "one_step", "bootstrap_terminal": True, "value_loss": "smooth_l1",
    "minibatch_size": 128, "adam_eps": 1e-8,
}  # fmt: skip


class Batch(NamedTuple):
    """A flattened rollout: obs (B, obs_dim), samples (B, dim), logprobs, advantages, returns, values (B,)."""

    obs: torch.Tensor
    samples: torch.Tensor
    logprobs: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor
    values: torch.Tensor


def explained_variance(predicted: np.ndarray, target: np.ndarray) -> float:
    """1 - Var[target - predicted] / Var[target]; nan when the target is constant."""
    var = np.var(target)
    return float("nan") if var == 0 else float(1.0 - np.var(target - predicted) / var)


def ppo_update(
    policy: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: Batch,
    cfg: PPOConfig,
    generator: torch.Generator,
) -> dict[str, float]:
    """K epochs of minibatch updates on the clipped surrogate (Eq. 4-5), value loss and entropy bonus.

    Returns the standard diagnostics under CleanRL's names (``losses/approx_kl`` etc., last epoch's means; the losses
    of the last epoch that took a step where the minibatch stop ended one before its first).
    A minibatch whose loss is not finite is skipped and counted in ``losses/skipped`` (of ``losses/minibatches``).

    ``cfg.target_kl`` stops the update early: with ``kl_stop="epoch"`` (CleanRL's) after the first epoch whose mean
    approx KL exceeds it; with ``"minibatch"`` (stable-baselines3's) before the first gradient step whose minibatch
    already has an approx KL above 1.5 x ``target_kl``, so no single epoch can carry the policy far past it.
    """
    size = batch.obs.shape[0]
    minibatch = cfg.minibatch_size or max(1, size // cfg.num_minibatches)
    clipfracs, stats, skipped, total, stopped = [], {}, 0, 0, False
    for _ in range(cfg.update_epochs):
        order = torch.randperm(size, generator=generator).to(batch.obs.device)
        epoch_stats: dict[str, list[float]] = {"pg": [], "v": [], "ent": [], "kl": [], "old_kl": []}
        for start in range(0, size, minibatch):
            idx = order[start : start + minibatch]
            obs = batch.obs[idx]  # gathered once: the value below reuses the encoder's features of this very tensor
            dist = policy.distribution(obs)
            logratio = dist.log_prob(batch.samples[idx]) - batch.logprobs[idx]
            ratio = logratio.exp()
            with torch.no_grad():
                epoch_stats["old_kl"].append(float((-logratio).mean()))
                epoch_stats["kl"].append(float(((ratio - 1) - logratio).mean()))
                clipfracs.append(float(((ratio - 1.0).abs() > cfg.clip_coef).float().mean()))
            if cfg.kl_stop == "minibatch" and cfg.target_kl is not None and epoch_stats["kl"][-1] > 1.5 * cfg.target_kl:
                stopped = True
                break
            total += 1
            adv = batch.advantages[idx]
            if cfg.norm_adv and adv.numel() > 1:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_coef, 1 + cfg.clip_coef)).mean()
            v_loss = value_loss(policy.value(obs), batch.returns[idx], cfg.value_loss)
            entropy = dist.entropy().mean()
            loss = pg_loss - cfg.ent_coef * entropy + cfg.vf_coef * v_loss
            if not torch.isfinite(loss):
                skipped += 1
                continue
            optimizer.zero_grad()
            loss.backward()
            if cfg.max_grad_norm is not None:
                nn.utils.clip_grad_norm_(policy.parameters(), cfg.max_grad_norm)
            optimizer.step()
            epoch_stats["pg"].append(pg_loss.item())
            epoch_stats["v"].append(v_loss.item())
            epoch_stats["ent"].append(entropy.item())
        # An epoch the minibatch stop ends before its first step keeps the previous losses; its KL (the stop) is kept.
        stats = {k: float(np.mean(v)) if v else stats.get(k, float("nan")) for k, v in epoch_stats.items()}
        if stopped or (cfg.kl_stop == "epoch" and cfg.target_kl is not None and stats["kl"] > cfg.target_kl):
            break
    return {
        "losses/policy_loss": stats["pg"],
        "losses/value_loss": stats["v"],
        "losses/entropy": stats["ent"],
        "losses/approx_kl": stats["kl"],
        "losses/old_approx_kl": stats["old_kl"],
        "losses/clipfrac": float(np.mean(clipfracs)) if clipfracs else float("nan"),
        "losses/explained_variance": explained_variance(batch.values.cpu().numpy(), batch.returns.cpu().numpy()),
        "losses/skipped": float(skipped),
        "losses/minibatches": float(total),
    }


# --------------------------------------------------------------------------------------------------- the learner
PPO_COLUMNS = ("losses/policy_loss", "losses/value_loss", "losses/entropy", "losses/approx_kl", "losses/clipfrac",
               "losses/explained_variance", "losses/skipped", "charts/learning_rate")  # fmt: skip


class Rollout:
    """On-policy storage for ``num_steps`` vector steps of ``num_envs`` envs: obs, samples, log-probabilities,
    (scaled, bootstrapped) rewards, episode ends and values, each (T, N, ...). Observations keep uint8 pixels as
    uint8 (a quarter of float32's memory; the encoder converts them), anything else as float32 (``obs_dtype``)."""

    def __init__(
        self, num_steps: int, num_envs: int, obs_dim: int, sample_dim: int, obs_dtype: Any = np.float32
    ) -> None:
        self.obs = np.zeros((num_steps, num_envs, obs_dim), np.uint8 if np.dtype(obs_dtype) == np.uint8 else np.float32)
        self.samples = np.zeros((num_steps, num_envs, sample_dim), np.float32)
        self.logprobs, self.rewards, self.dones, self.values = (np.zeros((num_steps, num_envs), np.float32)
                                                                 for _ in range(4))  # fmt: skip
        self.t = 0

    @property
    def full(self) -> bool:
        return self.t == self.obs.shape[0]

    def batch(self, advantages: np.ndarray, returns: np.ndarray, device: torch.device | str = "cpu") -> Batch:
        """The rollout flattened over (T, N) with its advantages and returns, on ``device``."""
        flat = self.obs.shape[0] * self.obs.shape[1]
        return Batch(
            torch.as_tensor(self.obs.reshape(flat, -1), device=device),
            torch.as_tensor(self.samples.reshape(flat, -1), device=device),
            torch.as_tensor(self.logprobs.reshape(-1), device=device),
            torch.as_tensor(advantages.reshape(-1), dtype=torch.float32, device=device),
            torch.as_tensor(returns.reshape(-1), dtype=torch.float32, device=device),
            torch.as_tensor(self.values.reshape(-1), device=device),
        )


class PPOLearner:
    """The paper's learner: rollouts of ``cfg.num_steps`` decisions per env, GAE, K epochs of the clipped update.

    Args:
        policy: the actor-critic (meta-policy and master critic).
        cfg: the PPO settings.
        num_envs, gamma: the vector envs and the discount per decision (``gamma ** decision_every``).
        num_updates: updates in the whole run (for the learning-rate schedule).
        generator: draws the minibatch order (a CPU generator: the same order on any device).

    The policy may live on any device (``policy.to("cuda")``): acting and the update run there, and the learner
    takes and returns numpy arrays on the CPU. The rollout is stored on the CPU and sent over once per update.
    """

    update_while_stepping = False
    columns = PPO_COLUMNS

    def __init__(self, policy: nn.Module, cfg: PPOConfig, num_envs: int, gamma: float, num_updates: int,
                 generator: torch.Generator) -> None:  # fmt: skip
        from hrtc.normalize import RewardScaler

        self.policy, self.cfg, self.gamma, self.num_updates = policy, cfg, gamma, num_updates
        self.generator = generator
        self.optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
        self.reward_scaler = RewardScaler(num_envs, gamma) if cfg.scale_reward else None
        self.rollout = Rollout(cfg.num_steps, num_envs, policy.obs_dim, policy.out_dim)
        self.updates = 0
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # log-probabilities and values of the last act

    @property
    def device(self) -> torch.device:
        return next(self.policy.parameters()).device

    def _value(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.policy.value(torch.as_tensor(obs, device=self.device)).cpu().numpy()

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> tuple[np.ndarray, object]:
        tobs = torch.as_tensor(obs, device=self.device)
        distribution = self.policy.distribution(tobs)
        u = distribution.sample()
        self._pending = (distribution.log_prob(u).cpu().numpy(), self.policy.value(tobs).cpu().numpy())
        return u.cpu().numpy(), distribution

    def observe(self, step: Any) -> None:
        ro, t = self.rollout, self.rollout.t
        done = step.terminated | step.truncated
        rewards = self.reward_scaler(step.rewards, done) if self.reward_scaler else step.rewards.astype(np.float64)
        # Bootstrap the time limit (not a terminal state), and with bootstrap_terminal every episode end.
        bootstrap = step.truncated | step.terminated if self.cfg.bootstrap_terminal else step.truncated
        if bootstrap.any():
            idx = np.flatnonzero(bootstrap)
            rewards[idx] += self.gamma * self._value(step.next_obs[idx])
        if t == 0 and (ro.obs.dtype == np.uint8) != (step.obs.dtype == np.uint8):  # pixels stay uint8
            ro.obs = np.zeros(ro.obs.shape, np.uint8 if step.obs.dtype == np.uint8 else np.float32)
        ro.obs[t], ro.samples[t], ro.rewards[t], ro.dones[t] = step.obs, step.samples, rewards, done
        ro.logprobs[t], ro.values[t] = self._pending  # type: ignore[misc]
        ro.t += 1
        self._next_obs = step.next_obs

    @property
    def at_boundary(self) -> bool:
        return self.rollout.t == 0

    def update(self) -> dict[str, float] | None:
        if not self.rollout.full:
            return None
        if self.cfg.anneal_lr:
            self.optimizer.param_groups[0]["lr"] = (1.0 - self.updates / self.num_updates) * self.cfg.learning_rate
        ro = self.rollout
        next_value = self._value(self._next_obs)
        if self.cfg.advantage == "one_step":
            adv, ret = one_step_advantages(ro.rewards, ro.values, ro.dones, next_value, self.gamma)
        else:
            adv, ret = compute_gae(ro.rewards, ro.values, ro.dones, next_value, self.gamma, self.cfg.gae_lambda)
        stats = ppo_update(self.policy, self.optimizer, ro.batch(adv, ret, self.device), self.cfg, self.generator)
        ro.t = 0
        self.updates += 1
        stats["charts/learning_rate"] = self.optimizer.param_groups[0]["lr"]
        return stats

    def state_dict(self) -> dict[str, Any]:
        return {"optimizer": self.optimizer.state_dict(), "updates": self.updates,
                "reward_rms": self.reward_scaler.rms.state_dict() if self.reward_scaler else {}}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        self.updates = int(state.get("updates", 0))
        if self.reward_scaler and state.get("reward_rms"):
            self.reward_scaler.rms.load_state_dict(state["reward_rms"])
