"""PPO pieces as plain functions: GAE, the clipped surrogate, and one update over a rollout (Schulman et al. 2017)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import nn


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


@dataclass(frozen=True)
class PPOConfig:
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
    max_grad_norm: float = 0.5
    norm_adv: bool = True
    target_kl: float | None = None
    normalize_obs: bool = True
    scale_reward: bool = True


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

    Returns the standard diagnostics under CleanRL's names (``losses/approx_kl`` etc., last epoch's means).
    A minibatch whose loss is not finite is skipped and counted in ``losses/skipped`` (of ``losses/minibatches``).
    """
    size = batch.obs.shape[0]
    minibatch = max(1, size // cfg.num_minibatches)
    clipfracs, stats, skipped, total = [], {}, 0, 0
    for _ in range(cfg.update_epochs):
        order = torch.randperm(size, generator=generator)
        epoch_stats: dict[str, list[float]] = {"pg": [], "v": [], "ent": [], "kl": [], "old_kl": []}
        for start in range(0, size, minibatch):
            idx = order[start : start + minibatch]
            total += 1
            dist = policy.distribution(batch.obs[idx])
            logratio = dist.log_prob(batch.samples[idx]) - batch.logprobs[idx]
            ratio = logratio.exp()
            with torch.no_grad():
                epoch_stats["old_kl"].append(float((-logratio).mean()))
                epoch_stats["kl"].append(float(((ratio - 1) - logratio).mean()))
                clipfracs.append(float(((ratio - 1.0).abs() > cfg.clip_coef).float().mean()))
            adv = batch.advantages[idx]
            if cfg.norm_adv and adv.numel() > 1:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_coef, 1 + cfg.clip_coef)).mean()
            v_loss = 0.5 * ((policy.value(batch.obs[idx]) - batch.returns[idx]) ** 2).mean()
            entropy = dist.entropy().mean()
            loss = pg_loss - cfg.ent_coef * entropy + cfg.vf_coef * v_loss
            if not torch.isfinite(loss):
                skipped += 1
                continue
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(policy.parameters(), cfg.max_grad_norm)
            optimizer.step()
            epoch_stats["pg"].append(pg_loss.item())
            epoch_stats["v"].append(v_loss.item())
            epoch_stats["ent"].append(entropy.item())
        stats = {k: float(np.mean(v)) if v else float("nan") for k, v in epoch_stats.items()}
        if cfg.target_kl is not None and stats["kl"] > cfg.target_kl:
            break
    return {
        "losses/policy_loss": stats["pg"],
        "losses/value_loss": stats["v"],
        "losses/entropy": stats["ent"],
        "losses/approx_kl": stats["kl"],
        "losses/old_approx_kl": stats["old_kl"],
        "losses/clipfrac": float(np.mean(clipfracs)) if clipfracs else float("nan"),
        "losses/explained_variance": explained_variance(batch.values.numpy(), batch.returns.numpy()),
        "losses/skipped": float(skipped),
        "losses/minibatches": float(total),
    }
