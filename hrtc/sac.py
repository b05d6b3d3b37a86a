"""Soft actor-critic for the Beta meta-policy (Haarnoja et al. 2018), as plain functions plus a replay buffer.

The meta-policy is the same :class:`~hrtc.policy.ActorCritic` PPO trains: its actor outputs Beta(alpha_k, beta_k) per
weight. SAC differs in how it learns the actor: twin critics Q_i(s, w) on (state, weights) are fitted to the soft
Bellman target, and the actor maximises ``min_i Q_i(s, w) - temperature * log pi(w | s)`` through reparameterised
Beta samples (``torch.distributions.Beta.rsample``: implicit reparameterisation gradients). The temperature is tuned
so that the policy's entropy stays near ``target_entropy``. The actor-critic's own critic V(s) (the master critic)
is fitted to the soft value ``min_i Q_i(s, w) - temperature * log pi(w | s)`` with ``w ~ pi``, so recordings and
learned skills read a meaningful V(s) whichever learner trained the policy.

Every function here is pure (tensors in, tensors or floats out) except :func:`soft_update` (in-place Polyak
averaging) and the buffer.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from hrtc.errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SACConfig:
    """The ``sac`` block of a run's config (see ``hrtc/conf/config.yaml`` for what each key means)."""

    learning_rate: float = 3e-4
    actor_lr_final: float = 1.0  # the actor's step size at the run's last decision, a fraction of learning_rate
    gamma: float = 0.99  # per env step; a decision spanning k env steps is discounted by gamma**k
    tau: float = 0.005
    batch_size: int = 256
    buffer_size: int = 100_000
    learning_starts: int = 500  # decisions (summed over envs) taken with the initial policy before any update
    actor_starts: int = 0  # decisions observed before the actor (and temperature) first move; the critics learn before
    updates_per_decision: float = 1.0  # gradient steps per decision collected (the update-to-data ratio)
    actor_every: int = 1  # the actor and temperature step on every actor_every-th gradient step (TD3's policy delay)
    actor_every_from: int = 0  # decisions observed before actor_every applies; before, the actor steps on every step
    policy_tau: float = 1.0  # Polyak rate per gradient step of the evaluated policy toward the trained (1: the same)
    q_hidden: tuple[int, ...] = (256, 256)
    q_layer_norm: bool = False  # a LayerNorm after each critic hidden layer's Linear, before its ReLU (RLPD's critics)
    q_bf16: bool | str = False  # critic hidden layers in bfloat16 (CPU autocast); "auto": where cpu_has_bf16_matmul
    target_entropy_per_weight: float = -1.0  # target entropy = this x K (nats)
    init_temperature: float = 0.1
    log_every: int = 250  # decisions between rows of train.csv
    normalize_obs: bool = False  # a replay buffer holds old samples: no drifting normaliser by default
    n_step: int = 1  # decisions summed into each critic target before bootstrapping (1: the one-step target)
    n_step_final: int = 0  # > 0: the targets go from n_step decisions to this many over n_step_anneal decisions
    n_step_anneal: int = 0  # decisions (summed over envs) over which the share of n_step targets falls from 1 to 0
    n_critics: int = 2  # critics Q_1..Q_N; each target takes the min of target_min_over of them, drawn at random
    target_min_over: int = 2  # M of REDQ: the target's min is over M of the N target critics (M = N: all, no draw)
    actor_q: str = "min"  # what the actor maximises: "min" over all N critics (SAC's) or their "mean" (REDQ's)
    critic_grad_penalty: float = 0.0  # lambda: the critics' loss adds lambda * E ||d(sum_i Q_i) / dw||^2 (stored w)
    critic_grad_penalty_start: int = 0  # decisions (summed over envs) observed before the penalty applies
    priority_exponent: float = 0.0  # prioritised replay: P(draw) ~ |TD error|^this (0: uniform draws)
    priority_correction: float = 0.5  # importance weights (N P_i)^-this, over the batch's max, in the critics' loss
    start_search: int = 0  # constant corner blends tried by successive halving before the actor moves (0: none)
    start_search_forget: bool = False  # empty the replay buffer when the search ends (its corners' episodes dropped)
    start_search_reset: bool = False  # the critics (targets, optimiser) start afresh when the search ends
    start_search_keep_winner: bool = False  # with start_search_forget: the winner's own transitions stay
    mirror_index: tuple[int, ...] | None = None  # a mirror image of the observation: obs'[i] = sign[i] * obs[index[i]]
    mirror_sign: tuple[float, ...] | None = None  # (a task's symmetry under which its skills are equivariant)
    mirror_fraction: float = 0.0  # share of each minibatch's transitions replaced by their mirror images (0: none)

    def __post_init__(self) -> None:
        for name in ("batch_size", "buffer_size", "log_every", "n_step", "n_critics", "target_min_over", "actor_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"sac.{name} must be a positive integer, got {value!r}")
        for name in ("learning_starts", "actor_starts", "actor_every_from", "critic_grad_penalty_start",
                     "start_search", "n_step_final", "n_step_anneal"):  # fmt: skip
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ConfigError(f"sac.{name} must be a non-negative integer, got {value!r}")
        if not 0.0 < self.learning_rate < 1.0:
            raise ConfigError(f"sac.learning_rate must be in (0, 1), got {self.learning_rate}")
        if isinstance(self.actor_lr_final, bool) or not 0.0 <= self.actor_lr_final <= 1.0:
            raise ConfigError(f"sac.actor_lr_final must be a fraction in [0, 1], got {self.actor_lr_final!r}")
        if not 0.0 <= self.gamma <= 1.0:
            raise ConfigError(f"sac.gamma must be in [0, 1], got {self.gamma}")
        if not 0.0 < self.tau <= 1.0:
            raise ConfigError(f"sac.tau must be in (0, 1], got {self.tau}")
        if not 0.0 < self.policy_tau <= 1.0:
            raise ConfigError(f"sac.policy_tau must be in (0, 1], got {self.policy_tau}")
        if not self.updates_per_decision > 0:
            raise ConfigError(f"sac.updates_per_decision must be > 0, got {self.updates_per_decision}")
        if not self.init_temperature > 0:
            raise ConfigError(f"sac.init_temperature must be > 0, got {self.init_temperature}")
        if self.n_critics < 2:
            raise ConfigError(f"sac.n_critics must be at least 2 (a target is the min of a pair), got {self.n_critics}")
        if not 2 <= self.target_min_over <= self.n_critics:
            raise ConfigError(f"sac.target_min_over must be between 2 and sac.n_critics ({self.n_critics}), got "
                              f"{self.target_min_over}")  # fmt: skip
        if not (np.isfinite(self.critic_grad_penalty) and self.critic_grad_penalty >= 0.0):
            raise ConfigError(f"sac.critic_grad_penalty must be >= 0 and finite, got {self.critic_grad_penalty}")
        if not isinstance(self.q_layer_norm, bool):
            raise ConfigError(f"sac.q_layer_norm must be true or false, got {self.q_layer_norm!r}")
        if not (isinstance(self.q_bf16, bool) or self.q_bf16 == "auto"):
            raise ConfigError(f"sac.q_bf16 must be true, false or auto, got {self.q_bf16!r}")
        for name in ("priority_exponent", "priority_correction"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise ConfigError(f"sac.{name} must be a number in [0, 1], got {value!r}")
        if self.start_search == 1:
            raise ConfigError("sac.start_search needs at least 2 candidate blends to choose from (0: no search), got 1")
        for name in ("start_search_forget", "start_search_reset", "start_search_keep_winner"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"sac.{name} must be true or false, got {getattr(self, name)!r}")
        if self.start_search_keep_winner and not self.start_search_forget:
            raise ConfigError("sac.start_search_keep_winner needs sac.start_search_forget=true (without it every "
                              "search transition stays)")  # fmt: skip
        if self.n_step_final and self.n_step_final == self.n_step:
            raise ConfigError(f"sac.n_step_final ({self.n_step_final}) is sac.n_step: nothing to anneal (0: none)")
        if bool(self.n_step_final) != bool(self.n_step_anneal):
            raise ConfigError("sac.n_step_final and sac.n_step_anneal come together (the targets' final length "
                              f"and the decisions to reach it), got {self.n_step_final} and "
                              f"{self.n_step_anneal}")  # fmt: skip
        if self.n_step_final and (self.priority_exponent > 0 or self.start_search_forget):
            raise ConfigError("sac.n_step_final draws from two buffers: it takes neither prioritised replay "
                              "(sac.priority_exponent) nor sac.start_search_forget")  # fmt: skip
        if self.actor_q not in ("min", "mean"):
            raise ConfigError(f"sac.actor_q must be 'min' or 'mean', got {self.actor_q!r}")
        if not self.q_hidden or any(int(h) < 1 for h in self.q_hidden):
            raise ConfigError(f"sac.q_hidden must list positive layer widths, got {list(self.q_hidden)}")
        if isinstance(self.mirror_fraction, bool) or not 0.0 <= self.mirror_fraction <= 1.0:
            raise ConfigError(f"sac.mirror_fraction must be a fraction in [0, 1], got {self.mirror_fraction!r}")
        if (self.mirror_index is None) != (self.mirror_sign is None):
            raise ConfigError("sac.mirror_index and sac.mirror_sign come together (the observation's mirror image)")
        if self.mirror_index is not None:
            index, sign = list(self.mirror_index), list(self.mirror_sign or ())
            if sorted(index) != list(range(len(index))) or len(sign) != len(index) or set(sign) - {1, -1}:
                raise ConfigError(f"sac.mirror_index must be a permutation of 0..n-1 and sac.mirror_sign n values of 1 "
                                  f"or -1, got {index} and {sign}")  # fmt: skip
        if self.mirror_fraction > 0 and self.mirror_index is None:
            raise ConfigError("sac.mirror_fraction > 0 needs the task's mirror (sac.mirror_index, sac.mirror_sign)")
        if self.mirror_fraction > 0 and self.normalize_obs:
            raise ConfigError("sac.mirror_fraction > 0 needs sac.normalize_obs=false (a mirror image of a normalised "
                              "observation is not the normalised mirror image)")  # fmt: skip


# --------------------------------------------------------------------------------------------------- replay buffer
class ReplayBatch(NamedTuple):
    """Transitions ``(s, w, r, s', terminated, discount)``: obs (B, obs_dim), samples (B, K), rewards (B,) (the
    discounted sum over up to ``n_step`` decisions), next_obs (B, obs_dim) the state bootstrapped from, terminated (B,)
    as floats (1 where s' is terminal: nothing is bootstrapped from it; a time limit is not), discount (B,) the factor
    of the bootstrap (gamma to the number of decisions summed). A prioritised draw adds ``weights`` (B,), the
    importance weights of the critics' loss, and ``indices`` (B,), the buffer slots drawn (for their new priorities)."""

    obs: torch.Tensor
    samples: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    terminated: torch.Tensor
    discount: torch.Tensor
    weights: torch.Tensor | None = None
    indices: np.ndarray | None = None


class ReplayBuffer:
    """A ring buffer of transitions in preallocated float32 arrays; the oldest is overwritten when full.

    Each slot also holds a priority (Schaul et al. 2016, proportional): a new transition gets the largest priority
    seen so far, so it is drawn soon; :meth:`update_priorities` sets drawn ones to ``|TD error| + 1e-6``.
    :meth:`sample` uses them only with ``exponent`` > 0."""

    def __init__(self, capacity: int, obs_dim: int, sample_dim: int) -> None:
        self.capacity = int(capacity)
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.samples = np.zeros((capacity, sample_dim), np.float32)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.float32)
        self.discount = np.zeros(capacity, np.float32)
        self.priorities = np.zeros(capacity, np.float64)
        self.max_priority = 1.0
        self.position, self.size = 0, 0

    def __len__(self) -> int:
        return self.size

    def clear(self) -> None:
        """Forget every transition (the arrays stay allocated; priorities start again from 1)."""
        self.position, self.size, self.max_priority = 0, 0, 1.0

    def keep(self, mask: np.ndarray) -> None:
        """Forget the transitions where ``mask`` (over :meth:`state_dict`'s order, oldest first) is False; the rest
        stay in their order, with their priorities."""
        state = self.state_dict()
        mask = np.asarray(mask, bool)
        if mask.shape != (self.size,):
            raise ValueError(f"keep needs one flag per held transition ({self.size}), got shape {mask.shape}")
        kept = {k: v[torch.from_numpy(mask)] if isinstance(v, torch.Tensor) else v for k, v in state.items()}
        self.load_state_dict(kept)

    def add(self, obs: np.ndarray, samples: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray,
            terminated: np.ndarray, discount: np.ndarray) -> None:  # fmt: skip
        """Append a batch of N transitions (leading axis N on every argument)."""
        n = len(rewards)
        idx = (self.position + np.arange(n)) % self.capacity
        self.obs[idx], self.samples[idx], self.rewards[idx] = obs, samples, rewards
        self.next_obs[idx], self.terminated[idx], self.discount[idx] = next_obs, terminated, discount
        self.priorities[idx] = self.max_priority
        self.position = int((self.position + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample(self, batch_size: int, generator: torch.Generator, exponent: float = 0.0,
               correction: float = 0.5) -> ReplayBatch:  # fmt: skip
        """``batch_size`` transitions drawn with replacement from what the buffer holds: uniformly with ``exponent``
        0; else slot i with probability ``P_i = p_i^exponent / sum_j p_j^exponent``, with importance weights
        ``(N P_i)^-correction`` divided by the batch's largest (so they only scale the loss down)."""
        if exponent == 0.0:
            idx = torch.randint(0, self.size, (batch_size,), generator=generator).numpy()
            weights = None
        else:
            scaled = self.priorities[: self.size] ** exponent
            probs = torch.from_numpy(scaled / scaled.sum())
            idx = torch.multinomial(probs, batch_size, replacement=True, generator=generator).numpy()
            w = (self.size * probs[idx]) ** -correction
            weights = (w / w.max()).float()
        arrays = (self.obs, self.samples, self.rewards, self.next_obs, self.terminated, self.discount)
        return ReplayBatch(*(torch.from_numpy(a[idx]) for a in arrays), weights=weights,
                           indices=None if weights is None else idx)  # fmt: skip

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """The drawn slots' new priorities, ``|TD error| + 1e-6`` (a slot drawn twice keeps the last)."""
        priorities = np.abs(np.asarray(td_errors, np.float64)) + 1e-6
        self.priorities[indices] = priorities
        self.max_priority = max(self.max_priority, float(priorities.max()))

    def state_dict(self) -> dict[str, torch.Tensor | int | float]:
        """The filled part in chronological order (oldest first), as tensors (``weights_only`` loads them)."""
        order = (np.arange(self.size) + (self.position if self.size == self.capacity else 0)) % self.capacity
        arrays = {k: torch.from_numpy(getattr(self, k)[order].copy())
                  for k in (*_FIELDS, "priorities")}  # fmt: skip
        return {**arrays, "capacity": self.capacity, "max_priority": self.max_priority}

    def load_state_dict(self, state: dict) -> None:
        self.position, self.size, self.max_priority = 0, 0, 1.0
        n = int(state["rewards"].shape[0])
        keep = slice(max(0, n - self.capacity), n)  # a smaller buffer keeps the newest
        if "discount" not in state:  # saved before n-step targets: every transition was one decision
            state = {**state, "discount": torch.full_like(state["rewards"], float("nan"))}
        self.add(*(np.asarray(state[k][keep].numpy()) for k in _FIELDS))
        # A buffer saved before prioritised replay has none: its slots keep add()'s priority 1 (drawn soon).
        self.max_priority = float(state.get("max_priority", 1.0))
        if "priorities" in state:
            self.priorities[: self.size] = state["priorities"][keep].numpy()


_FIELDS = ("obs", "samples", "rewards", "next_obs", "terminated", "discount")


class NStepAccumulator:
    """Turns each env's stream of decisions into n-step transitions: the discounted sum of up to ``n`` rewards and the
    state ``n`` decisions later (sooner where the episode ended: its final state, bootstrapped unless terminal).

    ``push`` takes one vector step and returns the transitions it completes (the oldest pending decision of every env
    that now has ``n``, and all of an env whose episode ended), as arrays for :meth:`ReplayBuffer.add`."""

    def __init__(self, n: int, gamma: float) -> None:
        self.n, self.gamma = int(n), float(gamma)
        self.pending: list[list[tuple[np.ndarray, np.ndarray, float]]] = []

    def push(self, obs: np.ndarray, samples: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray,
             terminated: np.ndarray, truncated: np.ndarray) -> tuple[np.ndarray, ...] | None:  # fmt: skip
        while len(self.pending) < len(rewards):
            self.pending.append([])
        out: list[tuple] = []
        for i, queue in enumerate(self.pending[: len(rewards)]):
            queue.append((obs[i], samples[i], float(rewards[i])))
            ended = bool(terminated[i] or truncated[i])
            while queue and (len(queue) == self.n or ended):
                ret = sum(self.gamma**j * r for j, (_, _, r) in enumerate(queue))
                out.append((queue[0][0], queue[0][1], ret, next_obs[i], float(terminated[i]),
                            self.gamma ** len(queue)))  # fmt: skip
                queue.pop(0)
        if not out:
            return None
        return tuple(np.asarray([t[j] for t in out], np.float32) for j in range(6))

    def state_dict(self) -> dict[str, Any]:
        return {"pending": [[(torch.from_numpy(np.asarray(o, np.float32)), torch.from_numpy(np.asarray(w, np.float32)),
                              r) for o, w, r in queue] for queue in self.pending]}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.pending = [[(o.numpy(), w.numpy(), float(r)) for o, w, r in queue] for queue in state.get("pending", [])]


# --------------------------------------------------------------------------------------------------- start search
class BlendSearch:
    """Successive halving over constant blends, one episode per play: the fixed weights the actor starts from.

    The candidates are the start (every sample 0.5: the untrained blend's mean) and ``n - 1`` distinct corners of the
    sample cube (each sample 0 or 1, so each weight is exactly 0 or 1 whatever the weight span), drawn at random (all
    of them where there are fewer). Round one plays every candidate for one episode; each later round plays the better
    half, by mean return over its episodes so far, once more, until one is left (``2n - 2`` episodes for n a power of
    two). An env with nothing to play while a round's last episodes finish acts with the policy.

    :meth:`override` puts the candidates' samples in place of the policy's; :meth:`observe` takes each decision's
    rewards and episode ends. ``winner`` is the chosen candidate's index (None while searching)."""

    def __init__(self, n: int, k: int, generator: torch.Generator) -> None:
        if k <= 20:  # every nonzero corner is a number in [1, 2^k): a draw without replacement
            codes = (torch.randperm(2**k - 1, generator=generator)[: n - 1] + 1).numpy()
            bits = (codes[:, None] >> np.arange(k)[None, :]) & 1
        else:  # too many to enumerate: random ones (a repeat is only a wasted candidate)
            bits = torch.randint(0, 2, (n - 1, k), generator=generator).numpy()
        self.candidates = np.vstack([np.full((1, k), 0.5), bits]).astype(np.float32)
        self.returns: list[list[float]] = [[] for _ in range(len(self.candidates))]
        self.alive = list(range(len(self.candidates)))  # the round's candidates
        self.queue = list(self.alive)  # what the round has yet to start
        self.pending = len(self.queue)  # what the round has yet to finish
        self.playing = np.zeros(0, np.int64)  # per env: a candidate, -1 the policy, -2 at an episode's start
        self.episode_return = np.zeros(0)
        self.winner: int | None = None

    def mean(self, candidate: int) -> float:
        return float(np.mean(self.returns[candidate])) if self.returns[candidate] else float("nan")

    def _grow(self, n: int) -> None:
        if len(self.playing) < n:
            extra = n - len(self.playing)
            self.playing = np.concatenate([self.playing, np.full(extra, -2, np.int64)])
            self.episode_return = np.concatenate([self.episode_return, np.zeros(extra)])

    def override(self, samples: np.ndarray) -> np.ndarray:
        """``samples`` (N, K) with the candidates' in place of the policy's for the envs playing one."""
        self._grow(len(samples))
        for i in range(len(samples)):
            if self.playing[i] == -2:
                self.playing[i] = self.queue.pop(0) if self.queue and self.winner is None else -1
        playing = self.playing[: len(samples)]
        out = samples.copy()
        out[playing >= 0] = self.candidates[playing[playing >= 0]]
        return out

    def observe(self, rewards: np.ndarray, ended: np.ndarray) -> None:
        self._grow(len(rewards))
        self.episode_return[: len(rewards)] += rewards
        for i in np.flatnonzero(ended):
            if (candidate := int(self.playing[i])) >= 0:
                self.returns[candidate].append(float(self.episode_return[i]))
                self.pending -= 1
            self.playing[i], self.episode_return[i] = -2, 0.0
            if self.pending == 0 and self.winner is None:
                self._next_round()

    def _next_round(self) -> None:
        ranked = sorted(self.alive, key=lambda c: (-self.mean(c), c))
        self.alive = ranked[: max(1, len(ranked) // 2)]
        if len(self.alive) == 1:
            self.winner = self.alive[0]
        else:
            self.queue, self.pending = list(self.alive), len(self.alive)

    def restart_episodes(self) -> None:
        """The envs were reset (a resumed run): the candidates they were playing go back to the round's queue."""
        for candidate in self.playing[self.playing >= 0]:
            self.queue.insert(0, int(candidate))
        self.playing[:], self.episode_return[:] = -2, 0.0

    def state_dict(self) -> dict[str, Any]:
        return {"candidates": torch.from_numpy(self.candidates.copy()), "returns": [list(r) for r in self.returns],
                "alive": list(self.alive), "queue": list(self.queue), "pending": self.pending,
                "playing": self.playing.tolist(), "episode_return": self.episode_return.tolist(),
                "winner": self.winner}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.candidates = state["candidates"].numpy().astype(np.float32)
        self.returns = [list(r) for r in state["returns"]]
        self.alive, self.queue, self.pending = list(state["alive"]), list(state["queue"]), int(state["pending"])
        self.playing = np.asarray(state["playing"], np.int64)
        self.episode_return = np.asarray(state["episode_return"], np.float64)
        self.winner = state["winner"]

    def label(self, candidate: int) -> str:
        """A candidate's weights as a string, e.g. ``011010`` (``s``: the start's 0.5)."""
        return "".join("s" if v == 0.5 else str(int(v)) for v in self.candidates[candidate])

    def summary(self) -> str:
        """Every candidate by mean return, with its episode count: ``011010 261.5 (4), ...``."""
        order = sorted(range(len(self.candidates)), key=lambda c: -self.mean(c) if self.returns[c] else np.inf)
        return ", ".join(f"{self.label(c)} {self.mean(c):.1f} ({len(self.returns[c])})" for c in order)


# --------------------------------------------------------------------------------------------------- networks
def cpu_has_bf16_matmul() -> bool:
    """Whether this CPU multiplies bfloat16 matrices in hardware: Intel's AMX tiles or AVX-512 BF16 (AMD Zen 4 has
    the latter). There the critics' bfloat16 hidden layers measured 0.63-0.70x of float32's gradient step
    (``benchmarks/results/cartpole_swingup/learner_diagnosis``, sections 19-20); without them autocast would
    emulate bfloat16 and cost more than it saves."""
    probes = ("_is_amx_tile_supported", "_is_avx512_bf16_supported")  # torch.cpu's own probes (private, so guarded)
    return any(bool(getattr(torch.cpu, name, lambda: False)()) for name in probes)


def resolve_bf16(setting: bool | str) -> bool:
    """``sac.q_bf16`` as the critics take it: ``"auto"`` is :func:`cpu_has_bf16_matmul`, a bool itself."""
    return cpu_has_bf16_matmul() if setting == "auto" else bool(setting)


class TwinQ(nn.Module):
    """``n`` critics Q_i(s, w): ReLU MLPs on the concatenated state and weights. (B, obs_dim), (B, K) -> (n, B).

    ``layer_norm`` puts a LayerNorm between each hidden layer's Linear and its ReLU (as RLPD's critics do).
    ``bf16`` runs the hidden layers under CPU autocast (their matrix products in bfloat16: ~2x faster on AVX-512 BF16,
    4-6x on AMX); the output layer, and so Q, stay float32, as do the weights, their gradients and the optimiser.
    (Stacking the critics' layers into batched matrix products was measured slower on CPU than separate layers.)"""

    def __init__(
        self, obs_dim: int, sample_dim: int, hidden: Sequence[int], n: int = 2, layer_norm: bool = False,
        bf16: bool = False,
    ) -> None:  # fmt: skip
        super().__init__()
        self.critics = nn.ModuleList(_relu_mlp(obs_dim + sample_dim, hidden, layer_norm) for _ in range(n))
        self.bf16 = bf16

    def forward(self, obs: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
        x = torch.cat([obs, samples], dim=-1)
        out = []
        for critic in self.critics:
            h = x
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.bf16):
                for layer in critic[:-1]:
                    h = layer(h)
            out.append(critic[-1](h.float()).squeeze(-1))
        return torch.stack(out)


def _relu_mlp(in_dim: int, hidden: Sequence[int], layer_norm: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, int(width)), *([nn.LayerNorm(int(width))] if layer_norm else []), nn.ReLU()]
        in_dim = int(width)
    return nn.Sequential(*layers, nn.Linear(in_dim, 1))


# --------------------------------------------------------------------------------------------------- the math
def soft_q_target(rewards: torch.Tensor, terminated: torch.Tensor, next_q1: torch.Tensor, next_q2: torch.Tensor,
                  next_logp: torch.Tensor, temperature: float | torch.Tensor,
                  gamma: float | torch.Tensor) -> torch.Tensor:  # fmt: skip
    """The soft Bellman target ``r + gamma (1 - terminated) (min(Q1', Q2') - temperature log pi(w' | s'))``, (B,)."""
    soft_value = torch.min(next_q1, next_q2) - temperature * next_logp
    return rewards + gamma * (1.0 - terminated) * soft_value


def temperature_loss(log_temperature: torch.Tensor, logp: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """``-log(temperature) * (log pi + target_entropy)``: its gradient raises the temperature while the policy's
    entropy ``-log pi`` is below the target and lowers it above (Haarnoja et al. 2018b, Eq. 18, in log space)."""
    return -(log_temperature * (logp.detach() + target_entropy)).mean()


def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging in place: ``target <- (1 - tau) target + tau source``."""
    with torch.no_grad():
        for t, s in zip(target.parameters(), source.parameters(), strict=True):
            t.mul_(1.0 - tau).add_(s, alpha=tau)


def mirror_batch(batch: ReplayBatch, index: Sequence[int] | torch.Tensor, sign: Sequence[float] | torch.Tensor,
                 mirrored: torch.Tensor) -> ReplayBatch:  # fmt: skip
    """``batch`` with the transitions where ``mirrored`` (B,) is True replaced by their mirror images: ``obs`` and
    ``next_obs`` become ``sign * obs[:, index]``; the weights, rewards, ends and discounts stay. Sound where the task
    is symmetric under that map and every skill is equivariant (a mirrored state gets the mirrored action from each
    skill, so the same weights blend the mirrored action): the mirrored transition is one the task could have given."""
    idx = torch.as_tensor(index, dtype=torch.long)
    signs = torch.as_tensor(sign, dtype=batch.obs.dtype)
    keep = mirrored.unsqueeze(-1)
    obs = torch.where(keep, batch.obs[:, idx] * signs, batch.obs)
    next_obs = torch.where(keep, batch.next_obs[:, idx] * signs, batch.next_obs)
    return batch._replace(obs=obs, next_obs=next_obs)


def rsample_with_logp(distribution: object) -> tuple[torch.Tensor, torch.Tensor]:
    """A reparameterised sample ``w`` of a weight distribution and its log-probability (summed over weights)."""
    w = distribution.rsample()  # type: ignore[attr-defined]
    return w, distribution.log_prob(w)  # type: ignore[attr-defined]


def sac_losses(policy: nn.Module, critics: TwinQ, target_critics: TwinQ, batch: ReplayBatch,
               temperature: float | torch.Tensor, target_set: tuple[int, ...] = (0, 1), actor_q: str = "min",
               grad_penalty: float = 0.0) -> dict[str, torch.Tensor]:  # fmt: skip
    """The critics', actor's and master critic's losses on one minibatch, with the actor's log-probabilities.

    ``policy`` is an :class:`~hrtc.policy.ActorCritic` (``distribution(obs)``, ``value(obs)``). Every critic fits the
    soft target on the stored weights, built from the target critics ``target_set`` (the min over them); the actor
    maximises ``Q(s, w) - temperature log pi(w | s)`` on fresh reparameterised weights, with Q the ``min`` or the
    ``mean`` over all critics (``actor_q``); V(s) fits that soft value. ``grad_penalty`` > 0 adds
    ``grad_penalty * E ||d(sum_i Q_i(s, w)) / dw||^2`` at the stored weights (the Beta samples) to the critics' loss:
    the critics then keep a slope in a weight only where the returns ask for it. ``td`` (B,), the mean over the
    critics of ``|Q_i - target|``, is a prioritised buffer's new priority. The caller must keep the actor loss's
    gradient out of the critics (see :meth:`SACLearner._gradient_step`)."""
    with torch.no_grad():
        next_w, next_logp = rsample_with_logp(policy.distribution(batch.next_obs))
        next_q = target_critics(batch.next_obs, next_w)
        next_min = next_q[list(target_set)].min(0).values  # passed as both of the target's pair: min(q, q) = q
        target = soft_q_target(
            batch.rewards, batch.terminated, next_min, next_min, next_logp, temperature, batch.discount
        )
    samples = batch.samples.clone().requires_grad_(True) if grad_penalty > 0 else batch.samples
    q_stored = critics(batch.obs, samples)
    td = q_stored - target  # (n, B)
    # A prioritised batch weighs each transition's squared error by its importance weight (uniform: all 1).
    q_loss = (td**2).mean(-1).sum() if batch.weights is None else (td**2 * batch.weights).mean(-1).sum()
    if grad_penalty > 0:
        (slope,) = torch.autograd.grad(q_stored.sum(), samples, create_graph=True)  # (B, K): d(sum_i Q_i) / dw
        q_loss = q_loss + grad_penalty * (slope**2).sum(-1).mean()
    w, logp = rsample_with_logp(policy.distribution(batch.obs))
    q_all = critics(batch.obs, w)
    q_pi = q_all.min(0).values if actor_q == "min" else q_all.mean(0)
    actor_loss = (temperature * logp - q_pi).mean()
    value_loss = F.mse_loss(policy.value(batch.obs), (q_pi - temperature * logp).detach())
    return {"q": q_loss, "actor": actor_loss, "value": value_loss, "logp": logp, "q_pi": q_pi, "target": target,
            "td": td.detach().abs().mean(0)}  # fmt: skip


def annealed_lr(base: float, final_fraction: float, progress: float) -> float:
    """The step size a fraction ``progress`` of the way through a run: linear from ``base`` at 0 to ``base *
    final_fraction`` at 1 (held there after it)."""
    return base * (1.0 - (1.0 - final_fraction) * min(max(progress, 0.0), 1.0))


# --------------------------------------------------------------------------------------------------- the learner
_SUMMED = ("losses/q_loss", "losses/policy_loss", "losses/value_loss", "losses/entropy", "losses/q_mean")
SAC_COLUMNS = ("losses/q_loss", "losses/policy_loss", "losses/value_loss", "losses/entropy", "losses/temperature",
               "losses/q_mean", "losses/gradient_steps", "charts/learning_rate")  # fmt: skip


class SACLearner:
    """Off-policy learning of the meta-policy: a replay buffer, twin critics Q(s, w) with Polyak targets, the
    reparameterised Beta actor, the temperature tuned to ``target_entropy_per_weight * K``.

    Every observed decision goes to the buffer; once it holds ``learning_starts`` decisions, each ``update`` takes
    ``updates_per_decision`` gradient steps per decision observed since the last one. It runs while the vector envs
    step (``update_while_stepping``), so its cost overlaps the skills' solves.

    Args:
        policy: the actor-critic whose actor is trained (its critic V(s) is fitted to the soft value).
        cfg: the SAC settings.
        gamma: the discount per decision (``cfg.gamma ** decision_every``).
        generator: draws the replay minibatches.
        weight_margin: the composed env's weight span beyond [0, 1] (where a start search puts the actor's means).
        total_decisions: the run's decisions summed over its envs (what ``actor_lr_final`` anneals the actor over).

    With ``start_search`` n > 0 the first episodes play constant blends instead (:class:`BlendSearch`; the actor and
    the temperature held, the critics learning from them); the actor then starts at the blend that won. With
    ``start_search_forget`` the buffer is emptied then, and gradient steps wait until it holds ``learning_starts``
    new transitions again; with ``start_search_reset`` the critics, their targets and their optimiser start afresh
    then (drawn from ``generator``), so nothing the search's critics learnt remains but the winner; with
    ``start_search_keep_winner`` (and forget) the winner's own transitions stay in the buffer.

    With ``n_step_final`` > 0 each decision also goes to a second buffer as an ``n_step_final``-decision transition,
    and a minibatch takes each transition from the first buffer with the share :attr:`long_share` (1 falling to 0
    over ``n_step_anneal`` decisions), from the second otherwise: the targets anneal from one length to the other.
    """

    update_while_stepping = True
    columns = SAC_COLUMNS

    def __init__(self, policy: nn.Module, cfg: SACConfig, gamma: float, generator: torch.Generator,
                 weight_margin: float = 0.0, total_decisions: int | None = None) -> None:  # fmt: skip
        import copy

        from hrtc.distributions import BetaHead

        # ``policy`` is the run's: what evaluations, checkpoints and exports use. With policy_tau < 1 it is a Polyak
        # average of the trained policy (self.policy, which acts and learns); with 1 it is the trained policy itself.
        self.evaluated, self.cfg, self.gamma, self.generator = policy, cfg, gamma, generator
        if cfg.actor_lr_final < 1.0 and not (total_decisions and total_decisions > 0):
            raise ConfigError("sac.actor_lr_final < 1 needs the run's length (total_decisions) to anneal over")
        self.total_decisions = total_decisions
        self.policy = copy.deepcopy(policy) if cfg.policy_tau < 1.0 else policy
        self._synced = self.policy is policy  # a copy takes the run's starting weights (init_from...) at its first act
        policy = self.policy
        obs_dim, k = int(policy.obs_dim), int(policy.out_dim)
        if cfg.mirror_index is not None and len(cfg.mirror_index) != obs_dim:
            raise ConfigError(f"sac.mirror_index maps {len(cfg.mirror_index)} observation entries; this task's "
                              f"observation has {obs_dim}")  # fmt: skip
        self._mirror = None  # (index, sign) as tensors, built once, when minibatches are mirrored
        if cfg.mirror_fraction > 0:
            self._mirror = (torch.as_tensor(cfg.mirror_index, dtype=torch.long),
                            torch.as_tensor(cfg.mirror_sign, dtype=torch.float32))  # fmt: skip
        bf16 = resolve_bf16(cfg.q_bf16)
        if cfg.q_bf16 == "auto":
            log.info("sac.q_bf16=auto: the critics' hidden layers in %s", "bfloat16" if bf16 else "float32 (no "
                     "bfloat16 matrix instructions on this CPU)")  # fmt: skip
        self._bf16 = bf16
        self.critics = self._new_critics(obs_dim, k)
        self.target_critics = copy.deepcopy(self.critics).requires_grad_(False)
        self.q_optimizer = torch.optim.Adam(self.critics.parameters(), lr=cfg.learning_rate)
        self.actor_optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.learning_rate)
        # What actor_starts holds still: every parameter of the policy but its master critic V(s)'s own layers.
        critic_ids = {id(p) for p in policy.critic.parameters()}
        self._actor_parameters = [p for p in policy.parameters() if id(p) not in critic_ids]
        self.log_temperature = torch.tensor(float(np.log(cfg.init_temperature)), requires_grad=True)
        self.temperature_optimizer = torch.optim.Adam([self.log_temperature], lr=cfg.learning_rate)
        self.target_entropy = cfg.target_entropy_per_weight * k
        self.buffer = ReplayBuffer(cfg.buffer_size, obs_dim, k)
        self.accumulator = NStepAccumulator(cfg.n_step, gamma)
        # Annealed targets: the same decisions also go, as n_step_final-decision transitions, to a second buffer;
        # a minibatch draws each transition from the first with the share long_share, from the second otherwise.
        self.final_buffer, self.final_accumulator = None, None
        if cfg.n_step_final:
            self.final_buffer = ReplayBuffer(cfg.buffer_size, obs_dim, k)
            self.final_accumulator = NStepAccumulator(cfg.n_step_final, gamma)
        self.decisions, self.gradient_steps = 0, 0
        self._credit = 0.0  # gradient steps owed to the decisions observed
        self._refill = 0  # transitions the buffer must hold before gradient steps are owed again (after a forget)
        self._since_row = 0  # decisions since the last train.csv row
        self._sums: torch.Tensor | None = None  # sums of the _SUMMED statistics over the row's gradient steps
        self._steps_in_row = 0
        self.weight_margin = float(weight_margin)
        self.search: BlendSearch | None = None
        if cfg.start_search:
            if not isinstance(getattr(policy, "actor_head", None), BetaHead):
                raise ConfigError("sac.start_search needs the Beta meta-policy (algo=hrtc dist=beta)")
            self.search = BlendSearch(cfg.start_search, k, generator)

    def _new_critics(self, obs_dim: int, k: int) -> TwinQ:
        cfg = self.cfg
        return TwinQ(obs_dim, k, cfg.q_hidden, n=cfg.n_critics, layer_norm=cfg.q_layer_norm, bf16=self._bf16)

    def _reset_critics(self) -> None:
        """Fresh critics (their initialisation drawn from the learner's generator, so a run's seed fixes it), targets
        equal to them, and a new optimiser (Adam's moments gone)."""
        seed = int(torch.randint(2**31 - 1, (1,), generator=self.generator))
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            fresh = self._new_critics(int(self.policy.obs_dim), int(self.policy.out_dim))
        self.critics.load_state_dict(fresh.state_dict())
        self.target_critics.load_state_dict(fresh.state_dict())
        self.q_optimizer = torch.optim.Adam(self.critics.parameters(), lr=self.cfg.learning_rate)

    @property
    def searching(self) -> bool:
        return self.search is not None and self.search.winner is None

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> tuple[np.ndarray, object]:
        if not self._synced:
            self.policy.load_state_dict(self.evaluated.state_dict())
            self._synced = True
        distribution = self.policy.distribution(torch.as_tensor(obs))
        samples = distribution.sample().numpy()
        return (self.search.override(samples) if self.searching else samples), distribution  # type: ignore[union-attr]

    def observe(self, step: Any) -> None:
        completed = self.accumulator.push(step.obs, step.samples, step.rewards, step.next_obs, step.terminated,
                                          step.truncated)  # fmt: skip
        if completed is not None:
            self.buffer.add(*completed)
        if self.final_accumulator is not None:
            completed = self.final_accumulator.push(step.obs, step.samples, step.rewards, step.next_obs,
                                                    step.terminated, step.truncated)  # fmt: skip
            if completed is not None:
                self.final_buffer.add(*completed)  # type: ignore[union-attr]
        if self.searching:
            self.search.observe(step.rewards, step.terminated | step.truncated)  # type: ignore[union-attr]
            if not self.searching:
                self._start_at_winner()
        n = len(step.rewards)
        self.decisions += n
        self._since_row += n
        if self.decisions >= self.cfg.learning_starts and len(self.buffer) >= self._refill:
            self._credit += n * self.cfg.updates_per_decision

    def _start_at_winner(self) -> None:
        """The actor's Beta means at the winning blend (the policy unchanged where the start won)."""
        search = self.search
        assert search is not None and search.winner is not None
        log.info("sac.start_search: %s won (weights in the order of the skills; s: the start's 0.5); by mean return "
                 "(episodes): %s", search.label(search.winner), search.summary())  # fmt: skip
        if self.cfg.start_search_forget:  # the critics keep what they learnt (unless reset); new episodes only
            if self.cfg.start_search_keep_winner:  # the winner's own decisions (their samples are its blend) stay
                held = self.buffer.state_dict()["samples"].numpy()
                self.buffer.keep(np.all(held == search.candidates[search.winner].astype(np.float32), axis=1))
            else:
                self.buffer.clear()
            self._credit, self._refill = 0.0, max(1, self.cfg.learning_starts)
        if self.cfg.start_search_reset:
            self._reset_critics()
        samples = search.candidates[search.winner]
        if np.all(samples == 0.5):
            return
        m = self.weight_margin
        weights = np.clip((1.0 + 2.0 * m) * samples - m, 0.0, 1.0)
        means = torch.as_tensor(np.clip((weights + m) / (1.0 + 2.0 * m), 0.05, 0.95), dtype=torch.float32)
        for policy in {id(p): p for p in (self.policy, self.evaluated)}.values():
            policy.actor_head.start_at(means)

    @property
    def at_boundary(self) -> bool:
        return True  # every observed decision is in the buffer

    @property
    def actor_lr(self) -> float:
        """The actor's step size now (``learning_rate``, or annealed toward ``actor_lr_final`` of it)."""
        if self.cfg.actor_lr_final >= 1.0:
            return self.cfg.learning_rate
        progress = self.decisions / self.total_decisions  # type: ignore[operator]
        return annealed_lr(self.cfg.learning_rate, self.cfg.actor_lr_final, progress)

    @property
    def long_share(self) -> float:
        """The share of a minibatch drawn as ``n_step``-decision transitions: 1, falling linearly to 0 over
        ``n_step_anneal`` decisions when ``n_step_final`` is set (the rest are ``n_step_final``-decision ones)."""
        if not self.cfg.n_step_final:
            return 1.0
        return max(0.0, 1.0 - self.decisions / self.cfg.n_step_anneal)

    def _draw(self) -> ReplayBatch:
        cfg = self.cfg
        if self.final_buffer is None:
            return self.buffer.sample(cfg.batch_size, self.generator, cfg.priority_exponent, cfg.priority_correction)
        share = self.long_share
        n_long = int((torch.rand(cfg.batch_size, generator=self.generator) < share).sum()) if share > 0 else 0
        if n_long == 0 or len(self.buffer) == 0:
            return self.final_buffer.sample(cfg.batch_size, self.generator)
        if n_long == cfg.batch_size or len(self.final_buffer) == 0:
            return self.buffer.sample(cfg.batch_size, self.generator)
        parts = (self.buffer.sample(n_long, self.generator), self.final_buffer.sample(cfg.batch_size - n_long,
                                                                                      self.generator))  # fmt: skip
        return ReplayBatch(*(torch.cat([getattr(p, f) for p in parts]) for f in _FIELDS))

    @property
    def temperature(self) -> float:
        return float(self.log_temperature.detach().exp())

    def update(self) -> dict[str, float] | None:
        steps = int(self._credit)
        if steps == 0:
            return self._row() if self._since_row >= self.cfg.log_every else None
        self._credit -= steps
        for _ in range(steps):
            self._gradient_step()
        return self._row() if self._since_row >= self.cfg.log_every else {}

    def _gradient_step(self) -> None:
        batch = self._draw()
        if self._mirror is not None:  # (a mirrored transition's TD error still sets its slot's priority)
            mirrored = torch.rand(len(batch.rewards), generator=self.generator) < self.cfg.mirror_fraction
            batch = mirror_batch(batch, *self._mirror, mirrored)
        temperature = self.log_temperature.exp().detach()
        chosen = tuple(range(self.cfg.target_min_over))
        if self.cfg.n_critics > self.cfg.target_min_over:  # REDQ: a fresh random subset per gradient step (M = N: none)
            chosen = tuple(torch.randperm(self.cfg.n_critics, generator=self.generator)[: len(chosen)].tolist())
        penalty = self.cfg.critic_grad_penalty if self.decisions >= self.cfg.critic_grad_penalty_start else 0.0
        losses = sac_losses(self.policy, self.critics, self.target_critics, batch, temperature, chosen,
                            self.cfg.actor_q, penalty)  # fmt: skip
        # Each backward pass accumulates into its own parameters only: the actor's loss never moves the critics.
        # Before actor_starts the critics learn the starting policy's Q; after it the actor (and the temperature) take
        # one step per actor_every critic steps (from actor_every_from decisions on; one per step before). V(s) learns
        # on every step.
        every = self.cfg.actor_every if self.decisions >= self.cfg.actor_every_from else 1
        actor_moves = (self.decisions >= self.cfg.actor_starts and not self.searching
                       and self.gradient_steps % every == 0)  # fmt: skip
        self.actor_optimizer.zero_grad()
        policy_loss = losses["actor"] + losses["value"] if actor_moves else losses["value"]
        policy_loss.backward(inputs=list(self.policy.parameters()))
        self.q_optimizer.zero_grad()
        losses["q"].backward(inputs=list(self.critics.parameters()))
        self.q_optimizer.step()
        if not actor_moves:  # V(s) still learns the soft value; the rest (a shared encoder too) stays
            for parameter in self._actor_parameters:
                parameter.grad = None
        if self.cfg.actor_lr_final < 1.0:
            self.actor_optimizer.param_groups[0]["lr"] = self.actor_lr
        self.actor_optimizer.step()
        if actor_moves:
            self.temperature_optimizer.zero_grad()
            temperature_loss(self.log_temperature, losses["logp"], self.target_entropy).backward()
            self.temperature_optimizer.step()
        if batch.indices is not None:
            self.buffer.update_priorities(batch.indices, losses["td"].numpy())
        soft_update(self.target_critics, self.critics, self.cfg.tau)
        if self.evaluated is not self.policy:
            soft_update(self.evaluated, self.policy, self.cfg.policy_tau)
        self.gradient_steps += 1
        with torch.no_grad():  # summed as tensors: one conversion per train.csv row, not per gradient step
            values = torch.stack([losses["q"], losses["actor"], losses["value"], -losses["logp"].mean(),
                                  losses["q_pi"].mean()])  # fmt: skip
            self._sums = values if self._sums is None else self._sums + values
            self._steps_in_row += 1

    def _row(self) -> dict[str, float]:
        n = self._steps_in_row
        means = (self._sums / n).tolist() if n else [float("nan")] * len(_SUMMED)
        row = dict(zip(_SUMMED, means, strict=True))
        row.update({"losses/gradient_steps": float(n), "losses/temperature": self.temperature,
                    "charts/learning_rate": self.actor_lr})  # fmt: skip
        self._sums, self._steps_in_row, self._since_row = None, 0, 0
        return row

    def state_dict(self) -> dict[str, Any]:
        return {
            "critics": self.critics.state_dict(), "target_critics": self.target_critics.state_dict(),
            "q_optimizer": self.q_optimizer.state_dict(), "actor_optimizer": self.actor_optimizer.state_dict(),
            "log_temperature": self.log_temperature.detach().clone(),
            "temperature_optimizer": self.temperature_optimizer.state_dict(),
            "buffer": self.buffer.state_dict(), "n_step": self.accumulator.state_dict(),
            "counters": {"decisions": self.decisions, "gradient_steps": self.gradient_steps, "credit": self._credit,
                         "since_row": self._since_row, "refill": self._refill},
            **({"trained_policy": self.policy.state_dict()} if self.evaluated is not self.policy else {}),
            **({"start_search": self.search.state_dict()} if self.search is not None else {}),
            **({"final_buffer": self.final_buffer.state_dict(), "n_step_final": self.final_accumulator.state_dict()}
               if self.final_buffer is not None and self.final_accumulator is not None else {}),
        }  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name in ("critics", "target_critics", "q_optimizer", "actor_optimizer", "temperature_optimizer"):
            getattr(self, name).load_state_dict(state[name])
        with torch.no_grad():
            self.log_temperature.copy_(state["log_temperature"])
        self.buffer.load_state_dict(state["buffer"])
        if np.isnan(self.buffer.discount[: self.buffer.size]).any():  # an old buffer: one decision each
            self.buffer.discount[: self.buffer.size] = self.gamma
        self.accumulator.load_state_dict(state.get("n_step", {}))
        if self.final_buffer is not None and self.final_accumulator is not None:
            if "final_buffer" not in state:
                raise ConfigError("this checkpoint's learner ran without sac.n_step_final: it cannot resume with it")
            self.final_buffer.load_state_dict(state["final_buffer"])
            self.final_accumulator.load_state_dict(state["n_step_final"])
        counters = state["counters"]
        self.decisions, self.gradient_steps = int(counters["decisions"]), int(counters["gradient_steps"])
        self._credit, self._since_row = float(counters["credit"]), int(counters["since_row"])
        self._refill = int(counters.get("refill", 0))
        self._sums, self._steps_in_row = None, 0
        if self.evaluated is not self.policy:  # else a checkpoint without it (policy_tau was 1): the evaluated one
            self.policy.load_state_dict(state.get("trained_policy", self.evaluated.state_dict()))
            self._synced = True
        if self.search is not None and "start_search" in state:
            self.search.load_state_dict(state["start_search"])
            self.search.restart_episodes()  # a resumed run resets its envs
