"""The off-policy learner's pieces in isolation, and a meta-policy that learns a state-dependent switch with it."""

import copy
import dataclasses

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn

import envs
from hrtc.checkpoint import load_policy
from hrtc.config import RunConfig
from hrtc.distributions import BetaDistribution
from hrtc.learner import Step
from hrtc.policy import ActorCritic
from hrtc.sac import (
    BlendSearch,
    NStepAccumulator,
    ReplayBatch,
    ReplayBuffer,
    SACConfig,
    SACLearner,
    TwinQ,
    annealed_lr,
    mirror_batch,
    sac_losses,
    soft_q_target,
    soft_update,
    temperature_loss,
)
from hrtc.trainer import Trainer


# --------------------------------------------------------------------------------------------------- Beta rsample
@pytest.mark.parametrize(("a", "b"), [(1.5, 1.5), (3.0, 1.2), (1.1, 6.0)])
def test_beta_rsample_gradient_matches_finite_differences_of_the_mean(a, b):
    """d E[w] / d(alpha, beta) from reparameterised samples equals the finite-difference derivative of the exact mean
    alpha / (alpha + beta)."""
    torch.manual_seed(0)
    alpha = torch.tensor([a], dtype=torch.float64, requires_grad=True)
    beta = torch.tensor([b], dtype=torch.float64, requires_grad=True)
    w = BetaDistribution(alpha.expand(400_000, 1), beta.expand(400_000, 1)).rsample()
    w.mean().backward()

    def mean(x: float, y: float) -> float:
        return x / (x + y)

    h = 1e-5
    fd_alpha = (mean(a + h, b) - mean(a - h, b)) / (2 * h)
    fd_beta = (mean(a, b + h) - mean(a, b - h)) / (2 * h)
    assert alpha.grad.item() == pytest.approx(fd_alpha, abs=3e-3)
    assert beta.grad.item() == pytest.approx(fd_beta, abs=3e-3)


def test_beta_rsample_second_moment_gradient_matches_finite_differences():
    """The same for E[w^2] = alpha (alpha + 1) / ((alpha + beta)(alpha + beta + 1)): not only the mean is right."""
    torch.manual_seed(1)
    a, b = 2.0, 3.0
    alpha = torch.tensor([a], dtype=torch.float64, requires_grad=True)
    w = BetaDistribution(alpha.expand(400_000, 1), torch.full((400_000, 1), b, dtype=torch.float64)).rsample()
    (w**2).mean().backward()

    def second(x: float) -> float:
        return x * (x + 1) / ((x + b) * (x + b + 1))

    h = 1e-5
    assert alpha.grad.item() == pytest.approx((second(a + h) - second(a - h)) / (2 * h), abs=2e-3)


# --------------------------------------------------------------------------------------------------- the math
def test_soft_q_target_by_hand():
    rewards = torch.tensor([1.0, 2.0, 0.5])
    terminated = torch.tensor([0.0, 1.0, 0.0])
    q1, q2 = torch.tensor([10.0, 10.0, -1.0]), torch.tensor([8.0, 12.0, -3.0])
    logp = torch.tensor([-1.0, 0.5, 2.0])
    target = soft_q_target(rewards, terminated, q1, q2, logp, temperature=0.2, gamma=0.9)
    expected = [1.0 + 0.9 * (8.0 + 0.2), 2.0, 0.5 + 0.9 * (-3.0 - 0.4)]
    np.testing.assert_allclose(target.numpy(), expected, rtol=1e-6)


def test_temperature_rises_below_the_target_entropy_and_falls_above():
    for logp, direction in ((torch.full((64,), 3.0), 1), (torch.full((64,), -3.0), -1)):  # entropy -3, then +3
        log_t = torch.tensor(0.0, requires_grad=True)
        optimizer = torch.optim.SGD([log_t], lr=0.1)
        for _ in range(5):
            optimizer.zero_grad()
            temperature_loss(log_t, logp, target_entropy=-1.0).backward()
            optimizer.step()
        assert direction * log_t.item() > 0.5


def test_soft_update_is_polyak_averaging():
    source, target = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    before = target.weight.detach().clone()
    soft_update(target, source, tau=0.25)
    np.testing.assert_allclose(target.weight.detach().numpy(), (0.75 * before + 0.25 * source.weight).detach().numpy())
    soft_update(target, source, tau=1.0)
    assert torch.equal(target.weight, source.weight)


def test_twin_critics_are_independent_networks():
    q = TwinQ(5, 3, (16, 16))
    out = q(torch.randn(7, 5), torch.rand(7, 3))
    assert out.shape == (2, 7)
    assert not torch.allclose(out[0], out[1])


def test_layer_normed_critics_ignore_the_scale_of_each_hidden_layers_input_weights():
    """With q_layer_norm each hidden layer's pre-activation is normalised: scaling a hidden Linear's weights and bias
    by any c > 0 leaves the critics' output unchanged (it changes the plain critics' output)."""
    torch.manual_seed(0)
    obs, w = torch.randn(9, 5), torch.rand(9, 3)
    for layer_norm in (True, False):
        q = TwinQ(5, 3, (16, 16), layer_norm=layer_norm)
        before = q(obs, w).detach()
        with torch.no_grad():
            for critic in q.critics:
                hidden = [m for m in critic if isinstance(m, torch.nn.Linear)][:-1]
                for linear in hidden:
                    linear.weight.mul_(7.0)
                    linear.bias.mul_(7.0)
        after = q(obs, w).detach()
        assert torch.allclose(before, after, atol=1e-4) == layer_norm
        assert sum(isinstance(m, torch.nn.LayerNorm) for m in q.modules()) == (4 if layer_norm else 0)


def test_the_actor_loss_never_moves_the_critics():
    torch.manual_seed(0)
    policy, critics = ActorCritic(4, 3, "beta", (16,)), TwinQ(4, 3, (16,))
    target = TwinQ(4, 3, (16,))
    buffer = ReplayBuffer(100, 4, 3)
    rng = np.random.default_rng(0)
    buffer.add(rng.normal(size=(50, 4)), rng.random((50, 3)), rng.random(50), rng.normal(size=(50, 4)), np.zeros(50),
               np.full(50, 0.9))  # fmt: skip
    losses = sac_losses(policy, critics, target, buffer.sample(32, torch.Generator().manual_seed(0)), 0.1)
    (losses["actor"] + losses["value"]).backward(inputs=list(policy.parameters()))
    assert all(p.grad is None for p in critics.parameters())
    assert all(p.grad is not None for p in policy.actor_head.parameters())


def test_an_ensemble_target_takes_the_min_of_its_pair_and_the_actor_the_min_or_the_mean():
    """With N critics, the critics' target is the soft target of the chosen set of target critics only (a pair, or
    three: REDQ's M), and the actor's Q is the min (SAC's) or the mean (REDQ's) over all N (checked against each
    critic evaluated by hand)."""
    torch.manual_seed(0)
    policy, critics, target = ActorCritic(4, 3, "beta", (16,)), TwinQ(4, 3, (16,), n=4), TwinQ(4, 3, (16,), n=4)
    buffer = ReplayBuffer(100, 4, 3)
    rng = np.random.default_rng(0)
    buffer.add(rng.normal(size=(50, 4)), rng.random((50, 3)), rng.random(50), rng.normal(size=(50, 4)), np.zeros(50),
               np.full(50, 0.9))  # fmt: skip
    batch = buffer.sample(32, torch.Generator().manual_seed(0))
    out = {}
    for pair, actor_q in (((2, 3), "min"), ((0, 2), "mean"), ((0, 1, 3), "three")):
        torch.manual_seed(1)  # the same rsampled weights in every call and below
        out[actor_q] = sac_losses(policy, critics, target, batch, 0.1, target_set=pair,
                                  actor_q="min" if actor_q == "three" else actor_q)  # fmt: skip
        torch.manual_seed(1)
        with torch.no_grad():
            next_w = policy.distribution(batch.next_obs).rsample()
            next_logp = policy.distribution(batch.next_obs).log_prob(next_w)
            next_q = torch.stack([target.critics[i](torch.cat([batch.next_obs, next_w], -1)).squeeze(-1) for i in pair])
        expected = batch.rewards + batch.discount * (next_q.min(0).values - 0.1 * next_logp)
        torch.testing.assert_close(out[actor_q]["target"], expected)
    assert not torch.allclose(out["min"]["target"], out["mean"]["target"])
    assert not torch.allclose(out["three"]["target"], out["mean"]["target"])  # (0, 1, 3) is not (0, 2)
    assert (out["min"]["q_pi"] < out["mean"]["q_pi"]).all()  # the same rsampled weights: the min of 4 lies below


def _terminal_batch(obs: np.ndarray, samples: np.ndarray, rewards: np.ndarray):
    """Transitions that all end an episode: the critics' target is the reward itself (a plain regression)."""
    n = len(rewards)
    buffer = ReplayBuffer(n, obs.shape[1], samples.shape[1])
    buffer.add(obs, samples, rewards, obs, np.ones(n), np.full(n, 0.9))
    state = buffer.state_dict()
    return ReplayBatch(*(state[k] for k in ("obs", "samples", "rewards", "next_obs", "terminated", "discount")))


def test_the_critics_gradient_penalty_is_the_squared_slope_in_the_weights():
    """The critics' loss with ``grad_penalty`` = lambda is the plain loss plus lambda * E ||d(Q_1 + Q_2) / dw||^2,
    the slope checked against central finite differences of the critics in each weight."""
    torch.manual_seed(0)
    policy, critics, target = ActorCritic(3, 2, "beta", (8,)), TwinQ(3, 2, (16,)), TwinQ(3, 2, (16,))
    rng = np.random.default_rng(0)
    batch = _terminal_batch(rng.normal(size=(40, 3)), rng.random((40, 2)), rng.random(40))
    plain = sac_losses(policy, critics, target, batch, 0.1)["q"]
    penalised = sac_losses(policy, critics, target, batch, 0.1, grad_penalty=0.5)["q"]
    h, slopes = 1e-3, []
    with torch.no_grad():
        for k in range(2):
            step = torch.zeros(2)
            step[k] = h
            up, down = critics(batch.obs, batch.samples + step), critics(batch.obs, batch.samples - step)
            slopes.append((up - down).sum(0) / (2 * h))
    expected = 0.5 * (torch.stack(slopes, -1) ** 2).sum(-1).mean()
    assert (penalised - plain).item() == pytest.approx(expected.item(), rel=1e-2)
    assert torch.equal(sac_losses(policy, critics, target, batch, 0.1, grad_penalty=0.0)["q"], plain)


def test_bf16_critics_run_their_hidden_layers_in_bfloat16_and_give_float32_q_and_gradients():
    """q_bf16: each hidden layer's output is bfloat16 (the matrix products ran under autocast), the output layer's
    and so Q are float32 and within bfloat16's rounding of the float32 critics with the same weights; every weight,
    and its gradient, stays float32 (what the optimiser steps)."""
    torch.manual_seed(0)
    obs, w = torch.randn(64, 5), torch.rand(64, 3)
    plain = TwinQ(5, 3, (64, 64), layer_norm=True)
    fast = copy.deepcopy(plain)
    fast.bf16 = True
    dtypes: list[torch.dtype] = []
    hooks = [m.register_forward_hook(lambda _m, _i, out: dtypes.append(out.dtype)) for m in fast.modules()
             if isinstance(m, nn.Linear)]  # fmt: skip
    q_fast = fast(obs, w)
    for hook in hooks:
        hook.remove()
    assert dtypes == [torch.bfloat16, torch.bfloat16, torch.float32] * 2  # two hidden layers, then the output's
    q_plain = plain(obs, w)
    # Off, the layer-by-layer pass is the plain Sequential's, bit for bit (stored float32 runs retrace).
    assert torch.equal(q_plain, torch.stack([c(torch.cat([obs, w], -1)).squeeze(-1) for c in plain.critics]))
    assert q_fast.dtype == torch.float32 and q_fast.shape == (2, 64)
    assert not torch.equal(q_fast, q_plain)
    torch.testing.assert_close(q_fast, q_plain, rtol=0.0, atol=0.05 * float(q_plain.detach().abs().max()))
    q_fast.sum().backward()
    assert all(p.dtype == torch.float32 and p.grad is not None and p.grad.dtype == torch.float32
               for p in fast.parameters())  # fmt: skip


def test_a_learner_with_bf16_critics_takes_float32_gradient_steps():
    """sac.q_bf16 reaches the learner's critics and their targets; its gradient steps move float32 weights."""
    torch.manual_seed(0)
    cfg = SACConfig(q_hidden=(32, 32), batch_size=16, learning_starts=0, q_bf16=True)
    learner = SACLearner(ActorCritic(4, 3, "beta", hidden=(16,)), cfg, 0.95, torch.Generator().manual_seed(0))
    assert learner.critics.bf16 and learner.target_critics.bf16
    rng = np.random.default_rng(0)
    learner.buffer.add(rng.normal(size=(64, 4)).astype(np.float32), rng.random((64, 3), np.float32),
                       rng.normal(size=64).astype(np.float32), rng.normal(size=(64, 4)).astype(np.float32),
                       np.zeros(64, np.float32), np.full(64, 0.95, np.float32))  # fmt: skip
    before = [p.detach().clone() for p in learner.critics.parameters()]
    for _ in range(3):
        learner._gradient_step()
    after = list(learner.critics.parameters())
    assert all(p.dtype == torch.float32 for p in after)
    assert all(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
    assert np.isfinite(learner._row()["losses/q_loss"])


def test_mirror_batch_replaces_exactly_the_drawn_transitions_by_their_mirror_images():
    """obs and next_obs of the flagged rows become sign * obs[:, index]; the rest of the batch is untouched, and the
    mirror of a mirror (lunarlander's map is an involution) is the transition itself."""
    rng = np.random.default_rng(0)
    batch = ReplayBatch(*(torch.as_tensor(a, dtype=torch.float32) for a in (
        rng.normal(size=(6, 4)), rng.random((6, 3)), rng.normal(size=6), rng.normal(size=(6, 4)),
        np.array([0, 1, 0, 0, 1, 0]), np.full(6, 0.9))))  # fmt: skip
    index, sign = (0, 1, 3, 2), (-1.0, 1.0, 1.0, 1.0)  # negate the first entry, swap the last two
    flags = torch.tensor([True, False, True, True, False, False])
    out = mirror_batch(batch, index, sign, flags)
    for name in ("obs", "next_obs"):
        before, after = getattr(batch, name), getattr(out, name)
        torch.testing.assert_close(after[flags][:, 0], -before[flags][:, 0])
        torch.testing.assert_close(after[flags][:, 2:], before[flags][:, [3, 2]])
        torch.testing.assert_close(after[flags][:, 1], before[flags][:, 1])
        torch.testing.assert_close(after[~flags], before[~flags])
    for name in ("samples", "rewards", "terminated", "discount"):
        assert getattr(out, name) is getattr(batch, name)
    twice = mirror_batch(out, index, sign, flags)
    torch.testing.assert_close(twice.obs, batch.obs) and torch.testing.assert_close(twice.next_obs, batch.next_obs)


def test_a_fully_mirrored_gradient_step_is_the_step_on_the_mirrored_buffer():
    """sac.mirror_fraction reaches the gradient step: with fraction 1 on a buffer, the critics and the actor move
    exactly as with fraction 0 on the buffer's mirror image (same start, same draws)."""
    rng = np.random.default_rng(0)
    obs, nxt = rng.normal(size=(64, 4)).astype(np.float32), rng.normal(size=(64, 4)).astype(np.float32)
    rest = (rng.random((64, 3), np.float32), rng.normal(size=64).astype(np.float32))
    index, sign = (1, 0, 2, 3), (1.0, 1.0, -1.0, 1.0)
    learners = []
    for fraction, (o, n) in ((1.0, (obs, nxt)), (0.0, (obs[:, index] * sign, nxt[:, index] * sign))):
        torch.manual_seed(0)
        cfg = SACConfig(q_hidden=(16,), batch_size=16, learning_starts=0, mirror_index=index, mirror_sign=sign,
                        mirror_fraction=fraction)  # fmt: skip
        learner = SACLearner(ActorCritic(4, 3, "beta", hidden=(8,)), cfg, 0.95, torch.Generator().manual_seed(0))
        learner.buffer.add(o, rest[0], rest[1], n, np.zeros(64, np.float32), np.full(64, 0.95, np.float32))
        torch.manual_seed(1)  # the actor's rsample draws
        learner._gradient_step()
        learners.append(learner)
    mirrored, plain = learners
    for a, b in zip([*mirrored.critics.parameters(), *mirrored.policy.parameters()],
                    [*plain.critics.parameters(), *plain.policy.parameters()], strict=True):  # fmt: skip
        torch.testing.assert_close(a, b)
    start = SACLearner(ActorCritic(4, 3, "beta", hidden=(8,)), SACConfig(q_hidden=(16,)), 0.95,
                       torch.Generator().manual_seed(0))  # fmt: skip
    assert any(not torch.equal(a, b) for a, b in zip(plain.critics.parameters(), start.critics.parameters(),
                                                      strict=True))  # fmt: skip


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"mirror_fraction": 1.5}, r"sac.mirror_fraction must be a fraction in \[0, 1\]"),
        ({"mirror_fraction": 0.5}, "sac.mirror_fraction > 0 needs the task's mirror"),
        ({"mirror_index": (1, 0)}, "sac.mirror_index and sac.mirror_sign come together"),
        ({"mirror_index": (0, 0), "mirror_sign": (1, -1)}, "sac.mirror_index must be a permutation"),
        ({"mirror_index": (1, 0), "mirror_sign": (1, 2)}, "sac.mirror_index must be a permutation"),
        ({"mirror_index": (1, 0), "mirror_sign": (1,)}, "sac.mirror_index must be a permutation"),
        (
            {"mirror_index": (1, 0), "mirror_sign": (1, -1), "mirror_fraction": 0.5, "normalize_obs": True},
            "sac.mirror_fraction > 0 needs sac.normalize_obs=false",
        ),
    ],
)
def test_bad_mirror_settings_are_one_config_error(settings, message):
    from hrtc.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        SACConfig(**settings)


def test_a_mirror_of_another_observation_size_is_refused_by_the_learner():
    from hrtc.errors import ConfigError

    cfg = SACConfig(q_hidden=(8,), mirror_index=(1, 0), mirror_sign=(1, -1), mirror_fraction=0.5)
    with pytest.raises(ConfigError, match="sac.mirror_index maps 2 observation entries; this task's observation has 4"):
        SACLearner(ActorCritic(4, 3, "beta", hidden=(8,)), cfg, 0.95, torch.Generator().manual_seed(0))


@pytest.mark.parametrize(("n_critics", "min_over", "draws"), [(2, 2, False), (3, 3, False), (3, 2, True), (5, 3, True)])
def test_the_learner_draws_its_target_critics_only_when_it_has_more_than_it_takes(monkeypatch, n_critics, min_over,
                                                                                   draws):  # fmt: skip
    """sac.target_min_over = M of sac.n_critics = N: each gradient step's target takes the min over M target
    critics, a fresh random subset when N > M (REDQ), all of them in order when M = N (no draw from the generator)."""
    import hrtc.sac as sac_module

    seen: list[tuple[int, ...]] = []
    real = sac_module.sac_losses
    monkeypatch.setattr(sac_module, "sac_losses", lambda *a, **k: seen.append(a[5]) or real(*a, **k))
    cfg = SACConfig(q_hidden=(8,), batch_size=8, learning_starts=0, n_critics=n_critics, target_min_over=min_over)
    learner = SACLearner(ActorCritic(4, 3, "beta", hidden=(8,)), cfg, 0.95, torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    learner.buffer.add(rng.normal(size=(32, 4)).astype(np.float32), rng.random((32, 3), np.float32),
                       rng.normal(size=32).astype(np.float32), rng.normal(size=(32, 4)).astype(np.float32),
                       np.zeros(32, np.float32), np.full(32, 0.95, np.float32))  # fmt: skip
    for _ in range(20):
        learner._gradient_step()
    assert all(len(c) == min_over == len(set(c)) and set(c) <= set(range(n_critics)) for c in seen) and len(seen) == 20
    assert (len(set(seen)) > 1) == draws  # 20 draws of a subset from 3 or 10 possible: not all the same
    if not draws:
        assert set(seen) == {tuple(range(n_critics))}


@pytest.mark.parametrize("amx", [False, True])
@pytest.mark.parametrize("avx512_bf16", [False, True])
def test_bf16_auto_is_on_exactly_where_the_cpu_multiplies_bfloat16_in_hardware(monkeypatch, amx, avx512_bf16):
    """sac.q_bf16=auto reads torch's CPU probes (AMX tiles, AVX-512 BF16): on with either, off with neither; true and
    false are taken as given whatever the CPU."""
    from hrtc.sac import resolve_bf16

    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16)
    assert resolve_bf16("auto") is (amx or avx512_bf16)
    assert resolve_bf16(True) is True and resolve_bf16(False) is False
    learner = SACLearner(ActorCritic(4, 3, "beta", hidden=(8,)), SACConfig(q_hidden=(8,), q_bf16="auto"), 0.95,
                         torch.Generator().manual_seed(0))  # fmt: skip
    assert learner.critics.bf16 is (amx or avx512_bf16) and learner.target_critics.bf16 is learner.critics.bf16


def test_bf16_auto_on_this_machine_follows_its_cpu_flags():
    """Without patching: the probe agrees with the CPU flags Linux reports (amx_tile or avx512_bf16)."""
    from pathlib import Path

    from hrtc.sac import cpu_has_bf16_matmul

    cpuinfo = Path("/proc/cpuinfo")
    if not cpuinfo.exists():
        pytest.skip("no /proc/cpuinfo to compare with")
    flags = set(cpuinfo.read_text().split())
    assert cpu_has_bf16_matmul() is bool({"amx_tile", "avx512_bf16"} & flags)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("n_critics", 1, "sac.n_critics must be at least 2"),
        ("target_min_over", 3, r"sac.target_min_over must be between 2 and sac.n_critics \(2\), got 3"),
        ("target_min_over", 1, r"sac.target_min_over must be between 2 and sac.n_critics \(2\), got 1"),
        ("target_min_over", 2.0, "sac.target_min_over must be a positive integer"),
        ("actor_q", "max", "sac.actor_q must be 'min' or 'mean'"),
        ("critic_grad_penalty", -0.1, "sac.critic_grad_penalty must be >= 0"),
        ("critic_grad_penalty_start", -1, "sac.critic_grad_penalty_start must be a non-negative integer"),
        ("q_layer_norm", "yes", "sac.q_layer_norm must be true or false"),
        ("q_bf16", 1, "sac.q_bf16 must be true, false or auto"),
        ("q_bf16", "yes", "sac.q_bf16 must be true, false or auto"),
        ("actor_every", 0, "sac.actor_every must be a positive integer"),
        ("actor_every_from", -1, "sac.actor_every_from must be a non-negative integer"),
        ("policy_tau", 0.0, r"sac.policy_tau must be in \(0, 1\]"),
        ("priority_exponent", 1.5, r"sac.priority_exponent must be a number in \[0, 1\]"),
        ("priority_correction", -0.1, r"sac.priority_correction must be a number in \[0, 1\]"),
        ("priority_exponent", True, r"sac.priority_exponent must be a number in \[0, 1\]"),
    ],
)
def test_bad_ensemble_and_penalty_settings_are_one_config_error(key, value, message):
    from hrtc.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        SACConfig(**{key: value})


# --------------------------------------------------------------------------------------------------- replay buffer
def test_n_step_transitions_sum_discounted_rewards_and_stop_at_an_episode_end():
    """Two envs, n = 3, gamma 0.5: env 0 runs on (its 3rd decision completes its 1st transition); env 1 ends its
    episode (terminated) at its 2nd decision, which flushes both of its pending decisions with what they summed."""
    acc = NStepAccumulator(3, 0.5)
    obs = lambda t: np.array([[t, 0.0], [t, 1.0]], np.float32)  # noqa: E731  (obs = (decision, env))
    w = np.zeros((2, 1), np.float32)
    no = np.zeros(2, bool)
    assert acc.push(obs(0), w, np.array([1.0, 10.0]), obs(1), no, no) is None
    out = acc.push(obs(1), w, np.array([2.0, 20.0]), obs(2), np.array([False, True]), no)
    o, _, ret, nxt, term, disc = out  # env 1's two decisions: 10 + 0.5 * 20, and 20
    np.testing.assert_allclose(o[:, 0], [0, 1]) and np.testing.assert_allclose(o[:, 1], [1, 1])
    np.testing.assert_allclose(ret, [20.0, 20.0])
    np.testing.assert_allclose(nxt, [[2, 1], [2, 1]])
    np.testing.assert_allclose(term, [1, 1]) and np.testing.assert_allclose(disc, [0.25, 0.5])
    o, _, ret, nxt, term, disc = acc.push(obs(2), w, np.array([4.0, 0.0]), obs(3), no, no)
    np.testing.assert_allclose(o, [[0, 0]])  # env 0: 1 + 0.5 * 2 + 0.25 * 4, bootstrapped from decision 3
    np.testing.assert_allclose(ret, [3.0]) and np.testing.assert_allclose(nxt, [[3, 0]])
    np.testing.assert_allclose(term, [0]) and np.testing.assert_allclose(disc, [0.125])
    restored = NStepAccumulator(3, 0.5)
    restored.load_state_dict(acc.state_dict())  # what is pending survives a checkpoint
    assert [len(q) for q in restored.pending] == [2, 1]
    np.testing.assert_allclose(restored.pending[0][0][0], [1, 0])


def test_one_step_transitions_are_the_decisions_themselves():
    acc = NStepAccumulator(1, 0.9)
    o, w, r, nxt, term, disc = acc.push(np.ones((2, 3)), np.ones((2, 2)), np.array([1.0, 2.0]), np.zeros((2, 3)),
                                        np.array([False, True]), np.array([True, False]))  # fmt: skip
    np.testing.assert_allclose(r, [1, 2]) and np.testing.assert_allclose(term, [0, 1])
    np.testing.assert_allclose(disc, [0.9, 0.9])


def test_replay_buffer_wraps_around_and_keeps_the_newest():
    buffer = ReplayBuffer(5, 1, 1)
    for i in range(7):  # 7 single transitions into 5 places: 0 and 1 are overwritten
        buffer.add(np.full((1, 1), i), np.full((1, 1), i), np.array([i]), np.full((1, 1), i + 1), np.array([0.0]),
                   np.array([0.9]))  # fmt: skip
    assert len(buffer) == 5 and buffer.position == 2
    assert sorted(buffer.rewards.tolist()) == [2, 3, 4, 5, 6]
    state = buffer.state_dict()
    assert state["rewards"].tolist() == [2, 3, 4, 5, 6]  # oldest first
    other = ReplayBuffer(3, 1, 1)
    other.load_state_dict(state)  # a smaller buffer keeps the newest
    assert sorted(other.rewards.tolist()) == [4, 5, 6]


def test_replay_buffer_keep_drops_the_unflagged_transitions_of_a_wrapped_buffer_in_order_with_their_priorities():
    buffer = ReplayBuffer(5, 1, 1)
    for i in range(7):  # wrapped: holds 2..6, oldest at slot 2
        buffer.add(np.full((1, 1), i), np.full((1, 1), i), np.array([i]), np.full((1, 1), i + 1), np.array([0.0]),
                   np.array([0.9]))  # fmt: skip
    buffer.priorities[:] = np.arange(5) + 10.0  # slot j: 10 + j (slot 2 holds transition 2, slot 0 transition 5)
    buffer.keep(np.array([True, False, True, True, False]))  # oldest first: keep 2, 4, 5
    state = buffer.state_dict()
    assert len(buffer) == 3 and state["rewards"].tolist() == [2, 4, 5] and state["next_obs"][:, 0].tolist() == [3, 5, 6]
    assert state["priorities"].tolist() == [12.0, 14.0, 10.0]
    buffer.add(np.full((1, 1), 7), np.full((1, 1), 7), np.array([7]), np.full((1, 1), 8), np.array([0.0]),
               np.array([0.9]))  # fmt: skip
    assert buffer.state_dict()["rewards"].tolist() == [2, 4, 5, 7]  # appends after the kept ones
    with pytest.raises(ValueError, match="one flag per held transition"):
        buffer.keep(np.ones(3, bool))


def test_replay_buffer_samples_whole_transitions_uniformly():
    buffer = ReplayBuffer(10, 2, 1)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 2)).astype(np.float32)
    buffer.add(obs, obs[:, :1], obs[:, 0], obs + 1, np.array([0, 1, 0, 1]), np.full(4, 0.9))
    batch = buffer.sample(4000, torch.Generator().manual_seed(0))
    np.testing.assert_array_equal(batch.next_obs.numpy(), batch.obs.numpy() + 1)  # rows stay together
    np.testing.assert_array_equal(batch.rewards.numpy(), batch.obs[:, 0].numpy())
    counts = np.unique(batch.rewards.numpy(), return_counts=True)[1]
    assert len(counts) == 4 and counts.min() > 850  # only what was added, about 1000 each


def test_prioritised_draws_follow_the_priorities_and_their_importance_weights_undo_them():
    """Priorities 1, 3, 0, 4 with exponent 1: slots drawn with probability 1/8, 3/8, ~0, 4/8; importance weights
    (N P)^-0.5 over the batch's max; exponent 0 draws exactly as the uniform buffer does."""
    buffer = ReplayBuffer(10, 1, 1)
    buffer.add(np.arange(4.0)[:, None], np.zeros((4, 1)), np.arange(4.0), np.zeros((4, 1)), np.zeros(4), np.ones(4))
    assert buffer.priorities[:4].tolist() == [1.0] * 4  # new transitions: the largest priority so far (1 at first)
    buffer.update_priorities(np.arange(4), np.array([1.0, -3.0, 0.0, 4.0]))  # |TD error| + 1e-6
    assert buffer.max_priority == pytest.approx(4.0)
    batch = buffer.sample(40_000, torch.Generator().manual_seed(0), exponent=1.0, correction=0.5)
    counts = np.bincount(batch.rewards.numpy().astype(int), minlength=4) / 40_000
    np.testing.assert_allclose(counts, [1 / 8, 3 / 8, 0, 4 / 8], atol=0.01)
    np.testing.assert_array_equal(batch.indices, batch.rewards.numpy().astype(int))
    expected = (4 * np.array([1, 3, 4]) / 8) ** -0.5
    for slot, weight in zip((0, 1, 3), expected / expected.max(), strict=True):  # the batch's max is slot 0's
        np.testing.assert_allclose(batch.weights.numpy()[batch.indices == slot], weight, rtol=1e-5)
    # exponent 0: the uniform draw, the same slots from the same generator state, no weights
    uniform = ReplayBuffer(10, 1, 1)
    uniform.add(np.arange(4.0)[:, None], np.zeros((4, 1)), np.arange(4.0), np.zeros((4, 1)), np.zeros(4), np.ones(4))
    a = buffer.sample(64, torch.Generator().manual_seed(3))
    b = uniform.sample(64, torch.Generator().manual_seed(3))
    assert a.weights is None and a.indices is None and torch.equal(a.rewards, b.rewards)
    buffer.add(np.ones((1, 1)), np.zeros((1, 1)), np.array([9.0]), np.zeros((1, 1)), np.zeros(1), np.ones(1))
    assert buffer.priorities[4] == pytest.approx(4.0)  # a new one at the largest seen


def test_priorities_wrap_around_with_their_transitions_and_survive_a_checkpoint():
    buffer = ReplayBuffer(3, 1, 1)
    for i in range(5):  # slots 0, 1 overwritten by transitions 3, 4, each at the largest priority then
        buffer.add(np.full((1, 1), i), np.zeros((1, 1)), np.array([float(i)]), np.zeros((1, 1)), np.zeros(1),
                   np.ones(1))  # fmt: skip
        buffer.update_priorities(np.array([(i) % 3]), np.array([float(i + 1)]))
    assert buffer.rewards.tolist() == [3, 4, 2] and buffer.priorities.tolist() == pytest.approx([4, 5, 3])
    other = ReplayBuffer(3, 1, 1)
    other.load_state_dict(buffer.state_dict())  # oldest first: 2, 3, 4 with their priorities
    assert other.rewards.tolist() == [2, 3, 4] and other.priorities.tolist() == pytest.approx([3, 4, 5])
    assert other.max_priority == pytest.approx(5.0)
    old = {k: v for k, v in buffer.state_dict().items() if k not in ("priorities", "max_priority")}
    other.load_state_dict(old)  # a checkpoint from before prioritised replay: every slot at 1
    assert other.priorities.tolist() == [1.0, 1.0, 1.0] and other.max_priority == 1.0


def test_importance_weights_scale_each_transitions_squared_error_in_the_critics_loss():
    torch.manual_seed(0)
    policy, critics = ActorCritic(2, 2, "beta", (8,)), TwinQ(2, 2, (8,))
    obs = torch.randn(4, 2)
    batch = ReplayBatch(obs, torch.rand(4, 2), torch.randn(4), torch.randn(4, 2), torch.zeros(4), torch.full((4,), 0.9))
    torch.manual_seed(1)
    plain = sac_losses(policy, critics, copy.deepcopy(critics), batch, 0.1)
    torch.manual_seed(1)
    weights = torch.tensor([1.0, 0.5, 0.0, 0.25])
    weighted = sac_losses(policy, critics, copy.deepcopy(critics), batch._replace(weights=weights), 0.1)
    q = critics(batch.obs, batch.samples)
    expected = (((q - plain["target"]) ** 2) * weights).mean(-1).sum()
    torch.testing.assert_close(weighted["q"], expected)
    torch.testing.assert_close(plain["td"], (q - plain["target"]).abs().mean(0).detach())


def test_a_prioritised_learner_sets_the_drawn_transitions_priorities_to_their_td_errors():
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), SACConfig(batch_size=4, learning_starts=8, q_hidden=(8,),
                         log_every=1000, priority_exponent=0.5), 0.9, torch.Generator().manual_seed(0))  # fmt: skip
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs = rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2) * 10, obs, no, no))
        learner.update()
    assert learner.gradient_steps > 0
    p = learner.buffer.priorities[: len(learner.buffer)]
    assert (p != 1.0).any() and (p > 0).all()  # drawn slots now hold |TD error|, the rest the largest seen
    assert learner.buffer.max_priority == pytest.approx(max(1.0, p.max()))


def test_sac_config_validation():
    with pytest.raises(Exception, match="sac.batch_size"):
        SACConfig(batch_size=0)
    with pytest.raises(Exception, match="sac.updates_per_decision"):
        SACConfig(updates_per_decision=0)


def test_learner_takes_updates_per_decision_gradient_steps_after_learning_starts():
    policy = ActorCritic(2, 2, "beta", (8,))
    learner = SACLearner(policy, SACConfig(batch_size=4, learning_starts=8, updates_per_decision=0.5, q_hidden=(8,),
                                           log_every=1000), 0.9, torch.Generator().manual_seed(0))  # fmt: skip
    obs = np.zeros((2, 2), np.float32)
    step = Step(obs, np.full((2, 2), 0.5, np.float32), np.ones(2), obs, np.zeros(2, bool), np.zeros(2, bool))
    for _ in range(4):  # 8 decisions: learning starts with the 4th step
        learner.observe(step)
        learner.update()
    assert learner.gradient_steps == 1  # 2 decisions x 0.5
    for _ in range(6):
        learner.observe(step)
        learner.update()
    assert learner.gradient_steps == 7


def test_annealed_lr_is_linear_from_the_base_to_its_final_fraction_and_held_after():
    assert annealed_lr(3e-4, 0.1, 0.0) == pytest.approx(3e-4)
    assert annealed_lr(3e-4, 0.1, 0.5) == pytest.approx(3e-4 * 0.55)
    assert annealed_lr(3e-4, 0.1, 1.0) == pytest.approx(3e-5)
    assert annealed_lr(3e-4, 0.1, 1.7) == pytest.approx(3e-5)
    assert annealed_lr(3e-4, 1.0, 0.9) == pytest.approx(3e-4)  # 1: constant


def test_the_actor_anneals_its_step_size_over_the_run_while_the_critics_keep_theirs():
    """With ``actor_lr_final`` the actor's optimiser steps at the annealed rate of the decisions observed so far (a
    resumed run recomputes it from its counters); without the run's length it is a config error."""
    with pytest.raises(Exception, match="actor_lr_final"):
        SACConfig(actor_lr_final=1.5)
    cfg = SACConfig(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000, actor_lr_final=0.0)
    with pytest.raises(Exception, match="total_decisions"):
        SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0),
                         total_decisions=40)  # fmt: skip
    rng = np.random.default_rng(0)
    for _ in range(10):  # 20 decisions of 40
        obs = rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), obs, no, no))
        learner.update()
    assert learner.actor_optimizer.param_groups[0]["lr"] == pytest.approx(cfg.learning_rate * 0.5)
    assert learner.q_optimizer.param_groups[0]["lr"] == cfg.learning_rate
    resumed = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0),
                         total_decisions=40)  # fmt: skip
    resumed.load_state_dict(learner.state_dict())
    assert resumed.actor_lr == pytest.approx(cfg.learning_rate * 0.5)


def _critics_after(cfg: SACConfig, n_steps: int) -> list[torch.Tensor]:
    """The critics' parameters after ``n_steps`` observed steps of 2 envs (varied states, rewards and weights)."""
    torch.manual_seed(0)
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    for _ in range(n_steps):
        obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
        learner.update()
    return [p.detach().clone() for p in learner.critics.parameters()]


def test_the_critics_penalty_applies_only_from_its_start():
    """Before ``critic_grad_penalty_start`` decisions a penalised learner trains exactly as an unpenalised one; from
    then on its critics move differently."""
    base = dict(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000)
    plain = _critics_after(SACConfig(**base), 10)
    late = _critics_after(SACConfig(**base, critic_grad_penalty=1.0, critic_grad_penalty_start=21), 10)
    early = _critics_after(SACConfig(**base, critic_grad_penalty=1.0, critic_grad_penalty_start=10), 10)
    # 10 steps of 2 envs: 20 decisions, short of the late start (21); the early one applies from the 5th step on
    assert all(torch.equal(a, b) for a, b in zip(plain, late, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(plain, early, strict=True))


def test_the_actor_holds_still_until_actor_starts_while_the_critics_learn():
    """Before ``actor_starts`` decisions the meta-policy's distribution and the temperature stay as they started
    (the critics and V(s) learn); from then on the actor moves too."""
    torch.manual_seed(0)
    policy = ActorCritic(2, 2, "beta", (8,))
    cfg = SACConfig(batch_size=4, learning_starts=4, actor_starts=12, q_hidden=(8,), log_every=1000)
    learner = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0))
    actor = [p.detach().clone() for p in learner._actor_parameters]
    value, critics = [[p.detach().clone() for p in m.parameters()] for m in (policy.critic, learner.critics)]
    temperature = learner.temperature
    rng = np.random.default_rng(0)

    def step() -> None:
        obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
        learner.update()

    for _ in range(5):  # 10 decisions: 8 gradient steps (2 a step from the 2nd), all before the actor starts at 12
        step()
    assert learner.gradient_steps == 8
    assert all(torch.equal(a, p) for a, p in zip(actor, learner._actor_parameters, strict=True))
    assert learner.temperature == temperature
    assert not any(torch.equal(a, p) for a, p in zip(value, policy.critic.parameters(), strict=True))
    assert not any(torch.equal(a, p) for a, p in zip(critics, learner.critics.parameters(), strict=True))
    step()  # 12 decisions: the actor moves
    assert not all(torch.equal(a, p) for a, p in zip(actor, learner._actor_parameters, strict=True))
    assert learner.temperature != temperature


def test_the_actor_steps_on_every_actor_every_th_gradient_step():
    """With ``actor_every=2`` the actor and the temperature change on gradient steps 0, 2, 4, ... only, while the
    critics change on every one; with 1 (the default) the actor changes on every step."""
    for every, moved in ((2, [True, False, True, False]), (1, [True, True, True, True])):
        torch.manual_seed(0)
        policy = ActorCritic(2, 2, "beta", (8,))
        cfg = SACConfig(batch_size=4, learning_starts=2, updates_per_decision=0.5, actor_every=every, q_hidden=(8,),
                        log_every=1000)  # fmt: skip
        learner = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0))
        rng = np.random.default_rng(0)
        for _ in range(2):  # 4 decisions in the buffer, 1 gradient step owed
            obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
            no = np.zeros(2, bool)
            learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
        learner._credit = 0.0
        for expected in moved:
            actor = [p.detach().clone() for p in learner._actor_parameters]
            critics = [p.detach().clone() for p in learner.critics.parameters()]
            temperature = learner.temperature
            learner._gradient_step()
            actor_moved = not all(torch.equal(a, p) for a, p in zip(actor, learner._actor_parameters, strict=True))
            assert actor_moved == expected and (learner.temperature != temperature) == expected
            assert not any(torch.equal(a, p) for a, p in zip(critics, learner.critics.parameters(), strict=True))


def test_actor_every_applies_from_actor_every_from_decisions_on():
    """With ``actor_every=2, actor_every_from=6`` the actor steps on every gradient step while fewer than 6 decisions
    were observed (the odd steps too), and on every 2nd gradient step from the 6th decision on."""
    torch.manual_seed(0)
    policy = ActorCritic(2, 2, "beta", (8,))
    cfg = SACConfig(batch_size=4, learning_starts=2, updates_per_decision=0.5, actor_every=2, actor_every_from=6,
                    q_hidden=(8,), log_every=1000)  # fmt: skip
    learner = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    seen = []
    for _ in range(6):  # 2 envs: 2, 4, ..., 12 decisions; one gradient step owed per 2 decisions once 2 are in
        obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
        while learner._credit >= 1.0:
            actor = [p.detach().clone() for p in learner._actor_parameters]
            index, decisions = learner.gradient_steps, learner.decisions
            learner._gradient_step()
            learner._credit -= 1.0
            seen.append((decisions, index, not all(torch.equal(a, p) for a, p in zip(actor, learner._actor_parameters,
                                                                                    strict=True))))  # fmt: skip
    assert any(d < 6 and i % 2 == 1 for d, i, _ in seen) and any(d >= 6 and i % 2 == 1 for d, i, _ in seen)
    assert [moved for _, _, moved in seen] == [d < 6 or i % 2 == 0 for d, i, _ in seen]


def _averaging_learner(policy_tau: float) -> tuple[SACLearner, nn.Module]:
    """A small SAC learner with ``policy_tau`` and the run's policy it was given (nothing observed yet)."""
    torch.manual_seed(0)
    policy = ActorCritic(2, 2, "beta", (8,))
    cfg = SACConfig(batch_size=4, learning_starts=2, q_hidden=(8,), log_every=1000, policy_tau=policy_tau)
    return SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0)), policy


def _filled_learner(policy_tau: float) -> tuple[SACLearner, nn.Module]:
    """:func:`_averaging_learner` after 3 acts and observations of 2 envs (6 decisions in the buffer)."""
    learner, policy = _averaging_learner(policy_tau)
    rng = np.random.default_rng(0)
    for _ in range(3):
        obs, nxt = rng.normal(size=(2, 2)).astype(np.float32), rng.normal(size=(2, 2)).astype(np.float32)
        learner.act(obs)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), nxt, no, no))
    return learner, policy


def test_the_evaluated_policy_is_a_polyak_average_of_the_trained_one():
    """``policy_tau=1`` (the default): the run's policy is the trained one. ``policy_tau=0.25``: the trained policy is
    a copy, and after a gradient step each evaluated parameter is 0.75 x its old value + 0.25 x the trained one's."""
    learner, policy = _filled_learner(1.0)
    assert learner.policy is policy and "trained_policy" not in learner.state_dict()
    learner, policy = _filled_learner(0.25)
    assert learner.policy is not policy
    before = [p.detach().clone() for p in policy.parameters()]
    learner._gradient_step()
    trained = list(learner.policy.parameters())
    assert not all(torch.equal(a, p) for a, p in zip(before, trained, strict=True))  # the trained one moved
    for old, new, t in zip(before, policy.parameters(), trained, strict=True):
        torch.testing.assert_close(new, 0.75 * old + 0.25 * t.detach())
    # The trained policy acts: act's distribution is its own, not the average's.
    obs = np.zeros((1, 2), np.float32)
    _, acting = learner.act(obs)
    torch.testing.assert_close(acting.alpha, learner.policy.distribution(torch.as_tensor(obs)).alpha)
    assert not torch.allclose(acting.alpha, policy.distribution(torch.as_tensor(obs)).alpha)


def test_the_trained_copy_starts_from_the_runs_starting_weights_and_resumes_from_its_checkpoint():
    """Weights put into the run's policy after the learner is built (``init_from``, ``init_weights``) reach the trained
    copy at its first act; a state_dict round trip restores the trained copy, not the average."""
    learner, policy = _averaging_learner(0.1)
    with torch.no_grad():
        for p in policy.parameters():
            p.add_(1.0)
    learner.act(np.zeros((1, 2), np.float32))
    for a, b in zip(policy.parameters(), learner.policy.parameters(), strict=True):
        assert torch.equal(a, b)
    learner, policy = _filled_learner(0.1)
    for _ in range(3):
        learner._gradient_step()
    state = copy.deepcopy(learner.state_dict())
    fresh, fresh_policy = _averaging_learner(0.1)
    fresh_policy.load_state_dict(policy.state_dict())  # the trainer restores the run's (evaluated) policy first
    fresh.load_state_dict(state)
    for a, b in zip(learner.policy.parameters(), fresh.policy.parameters(), strict=True):
        assert torch.equal(a, b)
    assert not all(torch.equal(a, b) for a, b in zip(fresh.policy.parameters(), fresh_policy.parameters(),
                                                     strict=True))  # fmt: skip


# --------------------------------------------------------------------------------------------------- start search
def _play(search: BlendSearch, value, n_envs: int = 2, max_steps: int = 1_000) -> list[int]:
    """Plays episodes of one decision each until the search ends: candidate c's episode returns ``value(c)``.
    Returns the candidates in the order their episodes started (-1: the policy's)."""
    started = []
    for _ in range(max_steps):
        if search.winner is not None:
            return started
        samples = search.override(np.full((n_envs, search.candidates.shape[1]), 0.25, np.float32))
        playing = [int(c) for c in search.playing[:n_envs]]
        started += playing
        for i, c in enumerate(playing):
            expected = search.candidates[c] if c >= 0 else np.full(search.candidates.shape[1], 0.25)
            np.testing.assert_array_equal(samples[i], expected)
        search.observe(np.array([value(c) if c >= 0 else -1e9 for c in playing]), np.ones(n_envs, bool))
    raise AssertionError("the search did not end")


def test_start_search_candidates_are_the_start_and_distinct_nonzero_corners():
    search = BlendSearch(16, 6, torch.Generator().manual_seed(0))
    assert search.candidates.shape == (16, 6)
    np.testing.assert_array_equal(search.candidates[0], 0.5)  # the untrained blend's mean
    corners = search.candidates[1:]
    assert set(np.unique(corners)) <= {0.0, 1.0} and corners.sum(axis=1).min() >= 1
    assert len({tuple(c) for c in corners}) == 15
    every = BlendSearch(16, 2, torch.Generator().manual_seed(0))  # fewer corners than asked: all three of them
    assert sorted(map(tuple, every.candidates[1:])) == [(0.0, 1.0), (1.0, 0.0), (1.0, 1.0)]


def test_start_search_halves_to_the_best_candidate_in_2n_minus_2_episodes():
    """With each candidate's return fixed, successive halving keeps the better half each round and ends with the best:
    16 + 8 + 4 + 2 episodes of candidates; no candidate is started twice within a round."""
    search = BlendSearch(16, 6, torch.Generator().manual_seed(1))
    score = dict(enumerate(np.random.default_rng(0).permutation(16).astype(float)))
    started = _play(search, score.get)
    played = [c for c in started if c >= 0]
    assert len(played) == 30
    assert search.winner == max(score, key=score.get)
    assert [len(r) for r in search.returns] == [1 + (score[c] >= 8) + (score[c] >= 12) + (score[c] >= 14)
                                                for c in range(16)]  # fmt: skip


def test_start_search_ranks_by_the_mean_over_a_candidates_episodes():
    """A candidate lucky in its first episode but worse on average loses the later rounds."""
    search = BlendSearch(4, 3, torch.Generator().manual_seed(0))
    counts = [0] * 4
    means = {0: 1.0, 1: 5.0, 2: 3.0, 3: 0.0}

    def value(c: int) -> float:  # candidate 2 scores 10 in its first episode, then 0: mean 5, then 3.3
        counts[c] += 1
        return (10.0 if counts[c] == 1 else 0.0) if c == 2 else means[c]

    _play(search, value, n_envs=1)
    assert search.winner == 1 and search.returns[2] == [10.0, 0.0]


def test_an_env_with_nothing_left_in_the_round_acts_with_the_policy_and_a_resume_replays_what_was_cut():
    search = BlendSearch(2, 1, torch.Generator().manual_seed(0))  # the start and the one corner
    samples = search.override(np.full((3, 1), 0.25, np.float32))
    assert list(search.playing) == [0, 1, -1] and samples[2, 0] == np.float32(0.25)
    search.observe(np.array([1.0, 2.0, 0.0]), np.array([True, False, True]))
    state = copy.deepcopy(search.state_dict())
    resumed = BlendSearch(2, 1, torch.Generator().manual_seed(5))
    resumed.load_state_dict(state)
    resumed.restart_episodes()  # env 1's episode of candidate 1 was cut by the resume: it is played again
    resumed.override(np.zeros((2, 1), np.float32))
    assert list(resumed.playing[:2]) == [1, -1] and resumed.winner is None
    resumed.observe(np.array([3.0, 0.0]), np.array([True, False]))
    assert resumed.winner == 1 and resumed.returns == [[1.0], [3.0]]


@pytest.mark.parametrize("margin", [0.0, 0.25])
def test_the_learner_holds_the_actor_while_searching_then_starts_it_at_the_winning_blend(margin):
    """While the search runs the learner's samples are the candidates', the critics learn and the actor stays; once
    it ends, the Beta means (and the Polyak-averaged policy's) give the winning corner's weights on the env's span."""
    torch.manual_seed(0)
    policy = ActorCritic(2, 3, "beta", (8,))
    cfg = SACConfig(batch_size=4, learning_starts=2, q_hidden=(8,), log_every=1000, start_search=4, policy_tau=0.5)
    learner = SACLearner(policy, cfg, 0.9, torch.Generator().manual_seed(0), weight_margin=margin)
    actor = [p.detach().clone() for p in learner._actor_parameters]
    critics = [p.detach().clone() for p in learner.critics.parameters()]
    search = learner.search
    best = 1 + int(np.argmax(search.candidates[1:].sum(axis=1)))  # the corner with the most weights up wins
    obs = np.zeros((2, 2), np.float32)
    while learner.searching:
        samples, _ = learner.act(obs)
        rewards = np.array([10.0 if (s == search.candidates[best]).all() else 0.0 for s in samples])
        learner.observe(Step(obs, samples, rewards, obs, np.ones(2, bool), np.zeros(2, bool)))
        learner.update()
        if learner.searching:
            assert all(torch.equal(a, p) for a, p in zip(actor, learner._actor_parameters, strict=True))
    assert search.winner == best and learner.gradient_steps > 0
    assert not all(torch.equal(a, p) for a, p in zip(critics, learner.critics.parameters(), strict=True))
    weights = np.clip((1 + 2 * margin) * search.candidates[best] - margin, 0, 1)  # 0 or 1
    for net in (learner.policy, policy):
        mean = net.distribution(torch.zeros(1, 2)).mode().detach().numpy()[0]
        applied = np.clip(-margin + (1 + 2 * margin) * mean, 0, 1)
        np.testing.assert_allclose(applied, weights, atol=0.06 if margin == 0 else 1e-3)


def test_start_search_forget_empties_the_buffer_at_the_winner_and_waits_for_learning_starts_new_transitions():
    """With sac.start_search_forget the search's transitions leave the buffer when it ends; no gradient step is taken
    until learning_starts new ones are in, then they resume (and the counters survive a state_dict round trip)."""
    torch.manual_seed(0)
    cfg = SACConfig(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000, start_search=4,
                    start_search_forget=True)  # fmt: skip
    learner = SACLearner(ActorCritic(2, 3, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    obs, done = np.zeros((2, 2), np.float32), np.ones(2, bool)

    def step(learner: SACLearner) -> None:
        samples, _ = learner.act(obs)
        learner.observe(Step(obs, samples, samples.sum(axis=1), obs, done, np.zeros(2, bool)))
        learner.update()

    while learner.searching:
        step(learner)
    searched = learner.gradient_steps
    assert searched > 0 and len(learner.buffer) == 0
    resumed = SACLearner(ActorCritic(2, 3, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    resumed.load_state_dict(copy.deepcopy(learner.state_dict()))
    assert not resumed.searching
    for run in (learner, resumed):
        step(run)  # 2 new transitions of the 4 needed
        assert run.gradient_steps == searched and len(run.buffer) == 2
        step(run)  # 4: owed again
        assert run.gradient_steps > searched


def test_start_search_reset_gives_fresh_critics_equal_targets_and_a_new_optimiser_when_the_search_ends():
    """With sac.start_search_reset the critics the search trained are replaced at the winner by freshly initialised
    ones (not those it started from, not those it trained), the targets equal them, Adam's moments are gone, and the
    same generator seed gives the same fresh critics; without it the trained critics go on."""
    cfg = SACConfig(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000, start_search=4)
    obs, done = np.zeros((2, 2), np.float32), np.ones(2, bool)

    def search(reset: bool) -> tuple[SACLearner, list[torch.Tensor], list[torch.Tensor]]:
        torch.manual_seed(0)
        learner = SACLearner(ActorCritic(2, 3, "beta", (8,)), dataclasses.replace(cfg, start_search_reset=reset),
                             0.9, torch.Generator().manual_seed(0))  # fmt: skip
        initial = [p.detach().clone() for p in learner.critics.parameters()]
        trained: list[torch.Tensor] = []
        while True:
            samples, _ = learner.act(obs)
            trained = [p.detach().clone() for p in learner.critics.parameters()]
            learner.observe(Step(obs, samples, samples.sum(axis=1), obs, done, np.zeros(2, bool)))
            if not learner.searching:  # the observation that ended the search (and reset the critics, if asked)
                return learner, initial, trained
            learner.update()

    kept, initial, trained = search(reset=False)
    assert kept.gradient_steps > 0 and not all(map(torch.equal, initial, trained))
    assert all(map(torch.equal, trained, kept.critics.parameters())) and len(kept.q_optimizer.state) > 0
    reset, initial_r, trained_r = search(reset=True)
    assert all(map(torch.equal, trained, trained_r))  # the same search up to its end
    fresh = [p.detach().clone() for p in reset.critics.parameters()]
    assert not any(torch.equal(f, t) for f, t in zip(fresh, trained, strict=True) if f.numel() > 1)
    assert not any(torch.equal(f, i) for f, i in zip(fresh, initial_r, strict=True) if f.numel() > 1)
    assert all(map(torch.equal, fresh, reset.target_critics.parameters()))
    assert len(reset.q_optimizer.state) == 0
    assert {id(p) for g in reset.q_optimizer.param_groups for p in g["params"]} == {
        id(p) for p in reset.critics.parameters()}  # fmt: skip
    again, _, _ = search(reset=True)
    assert all(map(torch.equal, fresh, again.critics.parameters()))
    samples, _ = reset.act(obs)  # and they learn: the next gradient steps move them
    reset.observe(Step(obs, samples, samples.sum(axis=1), obs, done, np.zeros(2, bool)))
    reset.update()
    assert not all(map(torch.equal, fresh, reset.critics.parameters()))


def test_start_search_keep_winner_keeps_exactly_the_winners_own_transitions():
    """With sac.start_search_forget and sac.start_search_keep_winner the buffer keeps, when the search ends, the
    transitions whose samples are the winner's blend, and only those (each candidate's episodes here have their own
    reward, so a count per candidate tells them apart); without keep_winner it is empty."""
    cfg = SACConfig(batch_size=4, learning_starts=4, q_hidden=(8,), log_every=1000, start_search=4,
                    start_search_forget=True, start_search_keep_winner=True)  # fmt: skip
    torch.manual_seed(0)
    learner = SACLearner(ActorCritic(2, 3, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    obs, not_done = np.zeros((2, 2), np.float32), np.zeros(2, bool)
    played: dict[bytes, int] = {}
    for t in range(10_000):
        samples, _ = learner.act(obs)
        done = np.full(2, t % 3 == 2)  # 3-decision episodes
        for row in samples:
            played[row.tobytes()] = played.get(row.tobytes(), 0) + 1
        learner.observe(Step(obs, samples, samples.sum(axis=1), obs, done, not_done))
        if not learner.searching:
            break
        learner.update()
    winner = learner.search.candidates[learner.search.winner]
    held = learner.buffer.state_dict()["samples"].numpy()
    assert len(held) == played[winner.tobytes()] > 0 and (held == winner).all()
    assert len(played) == 4 and sum(played.values()) > len(held)  # the others' transitions left
    with pytest.raises(Exception, match="start_search_keep_winner needs sac.start_search_forget=true"):
        SACConfig(start_search=4, start_search_keep_winner=True)


def test_a_run_with_a_start_search_resumes_it_and_plays_each_of_its_episodes_on_the_composed_env(tmp_path, caplog):
    """The real Trainer on the switch line: a run stopped mid-search resumes it from its checkpoint (the episodes the
    stop cut are played again), the search ends with one winner, and every candidate's episodes are the env's 25
    steps of -|x| (each a return in [-50, 0])."""
    from hrtc.checkpoint import load_checkpoint

    def cfg(steps: int) -> RunConfig:
        return RunConfig(task=SWITCH_TASK, skills=SWITCH_SKILLS, learner="sac", seed=0, steps=steps, num_envs=2,
                         vector="sync", eval_every=50, eval_episodes=2, progress=False, hidden=(8,),
                         sac=SACConfig(q_hidden=(8,), batch_size=8, learning_starts=20, start_search=4))  # fmt: skip

    Trainer(cfg(60), tmp_path).train()  # 30 decisions of 2 envs: two episodes of round one done, two cut at 5 steps
    search = load_checkpoint(tmp_path / "checkpoints" / "last.pt")["optimizer"]["start_search"]
    assert search["winner"] is None and sum(map(len, search["returns"])) == 2
    with caplog.at_level("INFO", logger="hrtc.sac"):
        Trainer(cfg(400), tmp_path, resume=True).train()
    search = load_checkpoint(tmp_path / "checkpoints" / "last.pt")["optimizer"]["start_search"]
    assert search["winner"] is not None and [len(r) for r in search["returns"]].count(0) == 0
    assert sum(map(len, search["returns"])) == 4 + 2  # round one (4) and the final pair (2): none played twice
    assert all(-50.0 <= r <= 0.0 for returns in search["returns"] for r in returns)
    assert any("sac.start_search:" in record.message and "won" in record.message for record in caplog.records)


def test_start_search_settings_are_checked():
    with pytest.raises(Exception, match="at least 2 candidate"):
        SACConfig(start_search=1)
    with pytest.raises(Exception, match="sac.start_search must be a non-negative integer"):
        SACConfig(start_search=-3)
    with pytest.raises(Exception, match="sac.start_search_forget must be true or false"):
        SACConfig(start_search_forget="yes")
    with pytest.raises(Exception, match="sac.start_search_reset must be true or false"):
        SACConfig(start_search_reset=1)
    with pytest.raises(Exception, match="needs the Beta meta-policy"):
        SACLearner(ActorCritic(2, 2, "normal", (8,)), SACConfig(start_search=4), 0.9, torch.Generator())


@pytest.mark.parametrize(
    ("overrides", "why"),
    [
        (
            ["algo.init_weights={centring: 1.0, descent: 1.0, touchdown: 1.0}"],
            "algo.init_weights gives the actor's start",
        ),
        (["dist=normal"], "it needs algo=hrtc dist=beta, got algo=hrtc dist=normal"),
        ([], None),
        (["learner=ppo"], None),
    ],
)
def test_lunarlanders_default_start_search_steps_aside_where_the_run_gives_the_start(overrides, why, caplog):
    """lunarlander's default searches for the actor's start (sac.start_search=16, its episodes then forgotten); a run
    that gives the start itself, or whose weights are not Beta, runs without the search and the log says why."""
    from omegaconf import OmegaConf

    from hrtc.cli import compose
    from hrtc.config import RunConfig

    with caplog.at_level("WARNING", logger="hrtc.config"):
        cfg = RunConfig.from_mapping(OmegaConf.to_container(compose(["task=lunarlander", *overrides]), resolve=True))
    skipped = [r.message for r in caplog.records if "sac.start_search=16 skipped" in r.message]
    if why is None:
        assert (cfg.sac.start_search, cfg.sac.start_search_forget) == (16, True) and not skipped
    else:
        assert not (cfg.sac.start_search or cfg.sac.start_search_forget or cfg.sac.start_search_reset
                    or cfg.sac.start_search_keep_winner)  # fmt: skip
        assert skipped == [f"sac.start_search=16 skipped: {why}"]
    assert cfg.sac.gamma == 0.998 and cfg.weight_margin == 0.25 and cfg.steps == 50_000


# --------------------------------------------------------------------------------------------------- learning
SWITCH_TASK = "test_switch_line"


class SwitchLine(gym.Env):
    """A point on a line, reward -|x| per step, 25 steps from a random start in [-1, 1]: the right move depends on
    the side, so a meta-policy over a left and a right skill must switch with the state."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def skill_state(self):
        return {"position": np.array([self.x])}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = float(self.np_random.uniform(-1, 1)), 0
        return np.array([self.x], np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + 0.2 * float(action[0]), -2, 2))
        self.t += 1
        return np.array([self.x], np.float32), -abs(self.x), False, self.t >= 25, {}


if SWITCH_TASK not in envs.names():
    envs.register(SWITCH_TASK)(SwitchLine)

SWITCH_SKILLS = {
    "left": {"skill": {"_target_": "skills.static.StaticIntent", "action": [-1.0]}},
    "right": {"skill": {"_target_": "skills.static.StaticIntent", "action": [1.0]}},
}


def test_sac_meta_policy_learns_a_state_dependent_switch(tmp_path):
    """Trained by the real Trainer with learner=sac, the Beta means put the right skill up left of 0 and the left
    skill up right of it (a constant weighting cannot do both), and the evaluation return improves."""
    cfg = RunConfig(
        task=SWITCH_TASK, skills=SWITCH_SKILLS, learner="sac", seed=0, steps=5_000, num_envs=2, vector="sync",
        eval_every=2_500, eval_episodes=10, progress=False, hidden=(32, 32),
        sac=SACConfig(q_hidden=(64, 64), batch_size=64, learning_starts=200, gamma=0.9, learning_rate=1e-3),
    )  # fmt: skip
    Trainer(cfg, tmp_path).train()
    evals = pd.read_csv(tmp_path / "eval.csv")
    loaded = load_policy(tmp_path / "checkpoints" / "last.pt")
    with torch.no_grad():
        left_side = loaded.policy.distribution(torch.full((64, 1), -0.6)).mode().mean(0).numpy()
        right_side = loaded.policy.distribution(torch.full((64, 1), 0.6)).mode().mean(0).numpy()
    print("weights (left, right) at x=-0.6:", left_side, "at x=0.6:", right_side, list(evals["episode_reward"]))
    assert left_side[1] - left_side[0] > 0.4  # push right when left of the goal
    assert right_side[0] - right_side[1] > 0.4  # push left when right of it
    assert evals["episode_reward"].iloc[-1] > evals["episode_reward"].iloc[0] + 1.0
    train = pd.read_csv(tmp_path / "train.csv")
    assert {"losses/q_loss", "losses/temperature", "losses/entropy"} <= set(train.columns)
    assert train["losses/gradient_steps"].sum() > 0


# --------------------------------------------------------------------------------------------- annealed n-step targets
def _fed(cfg: SACConfig, decisions: int, gamma: float = 0.9) -> SACLearner:
    """A learner that observed ``decisions`` vector steps of 2 envs (no episode ends), without gradient steps."""
    learner = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, gamma, torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    for t in range(decisions):
        obs = np.array([[t, 0.0], [t, 1.0]], np.float32)
        no = np.zeros(2, bool)
        learner.observe(Step(obs, rng.random((2, 2)).astype(np.float32), rng.normal(size=2), obs + [1, 0], no, no))
    return learner


def test_annealed_targets_fill_one_buffer_per_length_with_the_same_decisions():
    """n_step 3 -> 1: the first buffer holds what an n_step=3 learner's holds, the second what an n_step=1 one's."""
    base = dict(batch_size=8, learning_starts=10_000, q_hidden=(8,), log_every=1000)
    annealed = _fed(SACConfig(**base, n_step=3, n_step_final=1, n_step_anneal=40), 12)
    for n, held in ((3, annealed.buffer), (1, annealed.final_buffer)):
        plain = _fed(SACConfig(**base, n_step=n), 12).buffer.state_dict()
        state = held.state_dict()
        for key in ("obs", "samples", "rewards", "next_obs", "terminated", "discount"):
            assert torch.equal(state[key], plain[key]), (n, key)
    assert len(annealed.buffer) == 20 and len(annealed.final_buffer) == 24  # 2 decisions of each env still pending


def test_annealed_targets_share_falls_linearly_from_the_long_to_the_final_transitions():
    """The minibatch's share of 3-decision transitions (discount gamma^3, none ends here) is 1 at the start, about
    half half-way through n_step_anneal decisions and 0 after it; the rest are 1-decision ones (gamma)."""
    cfg = SACConfig(batch_size=2000, learning_starts=10_000, q_hidden=(8,), log_every=1000, n_step=3, n_step_final=1,
                    n_step_anneal=80)  # fmt: skip
    learner = _fed(cfg, 20)  # 40 decisions observed: half-way
    assert learner.long_share == pytest.approx(0.5)
    batch = learner._draw()
    long = torch.isclose(batch.discount, torch.tensor(0.9**3))
    assert torch.isclose(batch.discount[~long], torch.tensor(0.9)).all()
    assert 0.45 < long.float().mean() < 0.55
    learner.decisions = 0  # the share at the start (the same buffers)
    assert torch.isclose(learner._draw().discount, torch.tensor(0.9**3)).all()
    learner.decisions = 80
    assert learner.long_share == 0.0
    assert torch.isclose(learner._draw().discount, torch.tensor(0.9)).all()
    assert _fed(SACConfig(batch_size=8, q_hidden=(8,)), 1).long_share == 1.0  # not annealed: one buffer, all of it


def test_annealed_targets_survive_a_checkpoint_and_need_one_to_resume():
    from hrtc.errors import ConfigError

    cfg = SACConfig(batch_size=8, learning_starts=10_000, q_hidden=(8,), log_every=1000, n_step=3, n_step_final=1,
                    n_step_anneal=40)  # fmt: skip
    learner = _fed(cfg, 7)
    resumed = SACLearner(ActorCritic(2, 2, "beta", (8,)), cfg, 0.9, torch.Generator().manual_seed(0))
    resumed.load_state_dict(learner.state_dict())
    for a, b in ((learner.buffer, resumed.buffer), (learner.final_buffer, resumed.final_buffer)):
        held, restored = a.state_dict(), b.state_dict()
        assert all(torch.equal(held[k], restored[k]) for k in held if isinstance(held[k], torch.Tensor))
    assert [len(q) for q in resumed.final_accumulator.pending] == [0, 0]
    assert [len(q) for q in resumed.accumulator.pending] == [2, 2]
    plain = _fed(SACConfig(batch_size=8, learning_starts=10_000, q_hidden=(8,), n_step=3), 7)
    with pytest.raises(ConfigError, match="ran without sac.n_step_final"):
        resumed.load_state_dict(plain.state_dict())


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"n_step": 3, "n_step_final": 1}, "sac.n_step_final and sac.n_step_anneal come together"),
        ({"n_step_anneal": 100}, "sac.n_step_final and sac.n_step_anneal come together"),
        ({"n_step": 3, "n_step_final": 3, "n_step_anneal": 100}, "nothing to anneal"),
        ({"n_step": 3, "n_step_final": 1, "n_step_anneal": 100, "priority_exponent": 0.5}, "two buffers"),
        ({"n_step_final": -1, "n_step_anneal": 100}, "sac.n_step_final must be a non-negative integer"),
    ],
)
def test_bad_annealed_target_settings_are_one_config_error(settings, message):
    from hrtc.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        SACConfig(**settings)
