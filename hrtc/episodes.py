"""The one episode loop: a fixed decision rule acting in an environment, one episode per seed, optionally traced.

The trainer's evaluations, ``scripts/eval.py``, ``scripts/eval_skill.py``, the reference rules
(:mod:`hrtc.references`) and the benchmarks all run their episodes here, on the seeds :func:`eval_seeds` gives.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch

from hrtc.distributions import BetaDistribution
from hrtc.logging.trace import Recorder
from hrtc.normalize import ObsNormalizer, normalize_obs
from hrtc.policy import ActorCritic, to_action


class Decision(NamedTuple):
    """One decision of a fixed rule: its input ``obs`` (as the policy saw it), its output ``weights`` (the skill
    weights for HRTC; the raw sample for flat PPO), the action sent to the environment, and the Beta parameters when
    it has them."""

    obs: np.ndarray
    weights: np.ndarray
    action: np.ndarray
    alpha: np.ndarray | None = None
    beta: np.ndarray | None = None


def eval_seeds(seed: int, episodes: int) -> list[int]:
    """Evaluation episode seeds: the same at every evaluation, and disjoint from the training envs' reset seeds
    (``1000 * seed + ...``, below a million for any seed under 1000)."""
    return [1_000_000 + 1_000 * seed + k for k in range(episodes)]


class EpisodeReturns(NamedTuple):
    """Per-episode sums over :func:`play_episodes`' episodes: ``returns`` of the reward the learner sees, and
    ``true_returns`` of the task's own reward (``info["true_reward"]`` where the env shapes its reward, e.g.
    ``carracing_paper``; the same as ``returns`` where it does not)."""

    returns: np.ndarray
    true_returns: np.ndarray


def play_episodes(
    env: gym.Env,
    decide: Callable[[np.ndarray], Decision],
    seeds: Sequence[int],
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
    values: Callable[[np.ndarray], np.ndarray] | None = None,
) -> EpisodeReturns:
    """One episode per seed acting with ``decide``: their returns and true returns. With a ``recorder`` every decision
    is traced (weights, alpha/beta, proposals, action, reward, skill diagnostics, and frames from ``render`` when the
    recorder asks) and handed over when the episode ends, with ``values`` of the traced observations (one batch)."""
    returns, true_returns = [], []
    for episode, seed in enumerate(seeds):
        obs, _ = env.reset(seed=int(seed))
        trace = recorder.begin(episode, int(seed), render) if recorder is not None else None
        total, true_total, done = 0.0, 0.0, False
        while not done:
            decision = decide(obs)
            obs, reward, terminated, truncated, info = env.step(decision.action)
            total += float(reward)
            true_total += float(info.get("true_reward", reward))
            done = terminated or truncated
            if trace is not None:
                d = decision
                trace.add(d.obs, d.weights, d.alpha, d.beta, d.action, float(reward), info)
        returns.append(total)
        true_returns.append(true_total)
        if trace is not None and recorder is not None:
            trace.episode_return = total
            if values is not None and trace.obs:
                trace.values = values(np.stack(trace.obs))
            recorder.end(trace)
    return EpisodeReturns(np.asarray(returns), np.asarray(true_returns))


def run_episodes(
    env: gym.Env,
    decide: Callable[[np.ndarray], Decision],
    seeds: Sequence[int],
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
    values: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """The returns of :func:`play_episodes` (the reward the learner sees)."""
    return play_episodes(env, decide, seeds, recorder, render, values).returns


def mode_decider(policy: ActorCritic, normalizer: ObsNormalizer | None, space: gym.spaces.Box,
                 dist: str) -> Callable[[np.ndarray], Decision]:  # fmt: skip
    """The meta-policy acting deterministically: the mode of its distribution (the Beta mean for HRTC), on the
    policy's device."""
    device = next(policy.parameters()).device

    @torch.no_grad()
    def decide(obs: np.ndarray) -> Decision:
        nobs = normalize_obs(normalizer, obs[None])
        distribution = policy.distribution(torch.as_tensor(nobs, device=device))
        u = distribution.mode().cpu().numpy()[0]
        alpha, beta = beta_parameters(distribution)
        return Decision(nobs[0], u, to_action(u, space.low, space.high, dist).astype(np.float32), alpha, beta)

    return decide


@torch.no_grad()
def evaluate_episodes(
    policy: ActorCritic,
    normalizer: ObsNormalizer | None,
    env: gym.Env,
    seeds: Sequence[int],
    dist: str,
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
) -> EpisodeReturns:
    """Returns and true returns of one deterministic episode per seed (:func:`mode_decider`); recorded with the
    master critic's values when a ``recorder`` is given (see :func:`play_episodes`)."""
    device = next(policy.parameters()).device

    def values(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return policy.value(torch.as_tensor(obs, device=device)).cpu().numpy()

    decide = mode_decider(policy, normalizer, env.action_space, dist)  # type: ignore[arg-type]
    return play_episodes(env, decide, seeds, recorder, render, values if recorder is not None else None)


def evaluate(
    policy: ActorCritic,
    normalizer: ObsNormalizer | None,
    env: gym.Env,
    seeds: Sequence[int],
    dist: str,
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
) -> np.ndarray:
    """The returns of :func:`evaluate_episodes`."""
    return evaluate_episodes(policy, normalizer, env, seeds, dist, recorder, render).returns


def beta_parameters(distribution: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The first row's Beta parameters (alpha, beta) of ``distribution``; (None, None) for other distributions."""
    if isinstance(distribution, BetaDistribution):
        return distribution.alpha.cpu().numpy()[0], distribution.beta.cpu().numpy()[0]
    return None, None
