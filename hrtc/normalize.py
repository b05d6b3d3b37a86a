"""Running statistics for observation normalisation and reward scaling (saved with the checkpoint)."""

from __future__ import annotations

import numpy as np
import torch


class RunningMeanStd:
    """Mean and variance over every batch seen (Chan et al.'s parallel update). ``shape``: one sample's shape."""

    def __init__(self, shape: tuple[int, ...] = (), epsilon: float = 1e-4) -> None:
        self.mean = np.zeros(shape, np.float64)
        self.var = np.ones(shape, np.float64)
        self.count = epsilon

    def update(self, batch: np.ndarray) -> None:
        batch = np.asarray(batch, np.float64)
        b_mean, b_var, b_count = batch.mean(0), batch.var(0), batch.shape[0]
        delta, total = b_mean - self.mean, self.count + b_count
        m2 = self.var * self.count + b_var * b_count + delta**2 * self.count * b_count / total
        self.mean, self.var, self.count = self.mean + delta * b_count / total, m2 / total, total

    def state_dict(self) -> dict[str, torch.Tensor | float]:
        """Tensors and floats only, so that ``torch.load(weights_only=True)`` reads it back."""
        mean, var = torch.tensor(np.asarray(self.mean)), torch.tensor(np.asarray(self.var))
        return {"mean": mean, "var": var, "count": float(self.count)}

    def load_state_dict(self, state: dict) -> None:
        self.mean = np.array(torch.as_tensor(state["mean"]).numpy(), np.float64)
        self.var = np.array(torch.as_tensor(state["var"]).numpy(), np.float64)
        self.count = float(state["count"])


class ObsNormalizer:
    """``clip((x - mean) / sqrt(var + eps), -clip, clip)``; statistics update only while ``training``."""

    def __init__(self, shape: tuple[int, ...], clip: float = 10.0, epsilon: float = 1e-8) -> None:
        self.rms, self.clip, self.epsilon = RunningMeanStd(shape), clip, epsilon

    def __call__(self, obs: np.ndarray, update: bool = False) -> np.ndarray:
        if update:
            self.rms.update(obs)
        normalized = (obs - self.rms.mean) / np.sqrt(self.rms.var + self.epsilon)
        return np.clip(normalized, -self.clip, self.clip).astype(np.float32)


class RewardScaler:
    """Divides rewards by the running std of the discounted return (as gymnasium's NormalizeReward), per env."""

    def __init__(self, num_envs: int, gamma: float, clip: float = 10.0, epsilon: float = 1e-8) -> None:
        self.rms, self.gamma, self.clip, self.epsilon = RunningMeanStd(()), gamma, clip, epsilon
        self.returns = np.zeros(num_envs)

    def __call__(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        self.returns = self.returns * self.gamma + rewards
        self.rms.update(self.returns)
        self.returns[dones] = 0.0
        return np.clip(rewards / np.sqrt(self.rms.var + self.epsilon), -self.clip, self.clip)

    def scale(self) -> float:
        """The divisor currently applied to rewards."""
        return float(np.sqrt(self.rms.var + self.epsilon))


def normalize_obs(normalizer: ObsNormalizer | None, obs: np.ndarray, update: bool = False) -> np.ndarray:
    """``obs`` (batch, obs_dim) as the policy sees it: normalised when the run normalises, else float32 (uint8 pixels
    stay uint8: the encoder converts them, and the rollout stores a quarter of the bytes)."""
    if normalizer is not None:
        return normalizer(obs, update)
    return obs if obs.dtype == np.uint8 else obs.astype(np.float32)
