"""The learner plug-in point: how the meta-policy learns from the decisions the trainer collects.

The trainer owns the environments and the schedule (evaluation, checkpoints, health, recording); a learner owns
everything about learning: what it stores (a rollout, a replay buffer), its optimisers and when it updates. Two ship:
:class:`hrtc.ppo.PPOLearner` (the paper's) and :class:`hrtc.sac.SACLearner` (off-policy, reparameterised Beta).
Both train the same :class:`~hrtc.policy.ActorCritic`, so evaluation, checkpoints and learned skills are shared.

Each vector-env step the trainer calls ``act`` (training decisions), steps the envs, calls ``observe`` with what
happened and then ``update``; a learner with ``update_while_stepping`` is updated while the workers step instead
(its update reads only transitions already observed), so the update overlaps the skills' solves.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import numpy as np

from hrtc.distributions import WeightDistribution


class Step(NamedTuple):
    """One vector-env step of N envs, as the policy saw it: ``obs`` (N, obs_dim) the decision's input, ``samples``
    (N, K) the policy's samples, ``rewards`` (N,) summed over the decision's env steps, ``next_obs`` (N, obs_dim) the
    true successor (the final observation where an episode ended), ``terminated`` / ``truncated`` (N,) bool."""

    obs: np.ndarray
    samples: np.ndarray
    rewards: np.ndarray
    next_obs: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray


class Learner(Protocol):
    """What the trainer asks of a learner."""

    #: the ``train.csv`` columns its update statistics fill
    columns: tuple[str, ...]
    #: update while the vector envs step (it reads only observed transitions) rather than after ``observe``
    update_while_stepping: bool

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, WeightDistribution]:
        """Training decisions for ``obs`` (N, obs_dim): samples (N, K) and the distribution they came from."""
        ...

    def observe(self, step: Step) -> None:
        """Take in one vector step (what ``act`` decided and what the envs answered)."""
        ...

    def update(self) -> dict[str, float] | None:
        """Learn from what was observed, if it is time to; statistics for a ``train.csv`` row when one is due (an
        empty dict when it updated without a row due), None when it did not update."""
        ...

    @property
    def at_boundary(self) -> bool:
        """Whether nothing observed is pending an update (a checkpoint now loses no collected data)."""
        ...

    def state_dict(self) -> dict[str, Any]: ...
    def load_state_dict(self, state: dict[str, Any]) -> None: ...


def build_learner(name: str, settings: Any, policy: Any, num_envs: int, total_steps: int, steps_per_decision: int,
                  generator: Any, weight_margin: float = 0.0) -> Learner:  # fmt: skip
    """Learner ``name`` (``ppo`` or ``sac``) with its ``settings`` block for ``policy``, on ``num_envs`` envs for a
    run of ``total_steps`` env steps; it discounts per decision (``gamma ** steps_per_decision``). ``weight_margin``:
    the composed env's weight span beyond [0, 1] (SAC's start search sets the actor's means in it)."""
    from hrtc.ppo import PPOLearner
    from hrtc.sac import SACLearner

    gamma = settings.gamma**steps_per_decision
    if name == "sac":
        return SACLearner(policy, settings, gamma, generator, weight_margin, -(-total_steps // steps_per_decision))
    num_updates = -(-total_steps // (settings.num_steps * num_envs * steps_per_decision))
    return PPOLearner(policy, settings, num_envs, gamma, num_updates, generator)
