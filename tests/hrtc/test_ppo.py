"""GAE against hand-computed closed forms, and the PPO update's basic behaviour."""

import numpy as np
import pytest
import torch

from hrtc.errors import ConfigError, UnknownNameError
from hrtc.learner import Step
from hrtc.policy import ActorCritic
from hrtc.ppo import (
    REFERENCE_PPO,
    Batch,
    PPOConfig,
    PPOLearner,
    compute_gae,
    explained_variance,
    one_step_advantages,
    ppo_update,  # fmt: skip
    value_loss,
)


def test_gae_lambda_one_is_discounted_return_minus_value():
    rng = np.random.default_rng(0)
    rewards, values = rng.normal(size=(6, 1)), rng.normal(size=(6, 1))
    next_value, gamma = np.array([0.7]), 0.9
    adv, ret = compute_gae(rewards, values, np.zeros((6, 1)), next_value, gamma, lam=1.0)
    expected = [sum(gamma**k * rewards[t + k, 0] for k in range(6 - t)) + gamma ** (6 - t) * 0.7 for t in range(6)]
    np.testing.assert_allclose(ret[:, 0], expected)
    np.testing.assert_allclose(adv, ret - values)


def test_gae_lambda_zero_is_the_td_error():
    rewards = np.array([[1.0], [2.0], [3.0]])
    values = np.array([[0.5], [0.25], [1.0]])
    adv, _ = compute_gae(rewards, values, np.zeros((3, 1)), np.array([2.0]), 0.5, lam=0.0)
    np.testing.assert_allclose(adv[:, 0], [1 + 0.5 * 0.25 - 0.5, 2 + 0.5 * 1.0 - 0.25, 3 + 0.5 * 2.0 - 1.0])


def test_gae_hand_computed_with_an_episode_end():
    # Two steps, episode ends after step 0: step 0 must not see step 1's value or reward.
    rewards, values = np.array([[1.0], [1.0]]), np.array([[0.0], [0.0]])
    dones = np.array([[1.0], [0.0]])
    adv, _ = compute_gae(rewards, values, dones, np.array([10.0]), gamma=0.9, lam=0.8)
    np.testing.assert_allclose(adv[:, 0], [1.0, 1.0 + 0.9 * 10.0])


def test_gae_is_independent_across_envs():
    rng = np.random.default_rng(3)
    r, v, d = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), (rng.random((5, 3)) < 0.3).astype(float)
    nv = rng.normal(size=3)
    adv, _ = compute_gae(r, v, d, nv, 0.99, 0.95)
    for i in range(3):
        single, _ = compute_gae(r[:, i : i + 1], v[:, i : i + 1], d[:, i : i + 1], nv[i : i + 1], 0.99, 0.95)
        np.testing.assert_allclose(adv[:, i : i + 1], single)


def test_explained_variance():
    y = np.arange(10.0)
    assert explained_variance(y, y) == pytest.approx(1.0)
    assert explained_variance(np.full(10, y.mean()), y) == pytest.approx(0.0)


@pytest.mark.parametrize("dist", ["beta", "normal"])
def test_ppo_update_raises_the_probability_of_advantaged_samples(dist):
    torch.manual_seed(0)
    policy = ActorCritic(3, 2, dist, (16,), 0.5, -1.0)
    obs = torch.randn(256, 3)
    with torch.no_grad():
        d = policy.distribution(obs)
        u = d.sample()
        logp = d.log_prob(u)
        values = policy.value(obs)
    advantages = (u[:, 0] - u[:, 0].mean()) * 10  # reward the first component being high
    batch = Batch(obs, u, logp, advantages, values + advantages, values)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-3)
    with torch.no_grad():
        before = float(policy.distribution(obs).mode()[:, 0].mean())
    stats = ppo_update(policy, opt, batch, PPOConfig(update_epochs=4, num_minibatches=4), torch.Generator())
    with torch.no_grad():
        after = float(policy.distribution(obs).mode()[:, 0].mean())
    assert after > before
    for key in ("losses/approx_kl", "losses/clipfrac", "losses/explained_variance", "losses/value_loss"):
        assert np.isfinite(stats[key])
    assert stats["losses/skipped"] == 0


# -------------------------------------------------------------------------------------------------- the reference PPO
def test_one_step_advantages_by_hand():
    # Two envs, three steps; env 0's episode ends after step 1 (nothing bootstrapped across it).
    rewards = np.array([[1.0, 0.0], [2.0, 1.0], [3.0, -1.0]])
    values = np.array([[0.5, 1.0], [0.25, 2.0], [1.0, 0.0]])
    dones = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    next_value, gamma = np.array([2.0, 4.0]), 0.5
    adv, ret = one_step_advantages(rewards, values, dones, next_value, gamma)
    expected_ret = np.array([[1 + 0.5 * 0.25, 0 + 0.5 * 2.0], [2.0, 1 + 0.5 * 0.0], [3 + 0.5 * 2.0, -1 + 0.5 * 4.0]])
    np.testing.assert_allclose(ret, expected_ret)
    np.testing.assert_allclose(adv, expected_ret - values)
    np.testing.assert_allclose(adv, compute_gae(rewards, values, dones, next_value, gamma, lam=0.0)[0])


def test_smooth_l1_value_loss_by_hand():
    predicted, target = torch.tensor([0.0, 0.5, 3.0, -2.0]), torch.tensor([0.0, 0.0, 0.0, -1.5])
    # Huber with threshold 1: 0.5 d^2 inside, |d| - 0.5 outside: 0, 0.125, 2.5, 0.125
    assert float(value_loss(predicted, target, "smooth_l1")) == pytest.approx((0 + 0.125 + 2.5 + 0.125) / 4)
    assert float(value_loss(predicted, target, "mse")) == pytest.approx(0.5 * (0 + 0.25 + 9 + 0.25) / 4)
    with pytest.raises(UnknownNameError):
        value_loss(predicted, target, "l3")


def _on_policy_batch(n: int, advantages: torch.Tensor, returns: torch.Tensor) -> tuple[ActorCritic, Batch]:
    """A small Beta actor-critic (seed 0) and ``n`` transitions sampled from it on random observations."""
    torch.manual_seed(0)
    policy = ActorCritic(3, 2, "beta", (8,))
    obs = torch.randn(n, 3)
    with torch.no_grad():
        d = policy.distribution(obs)
        u = d.sample()
        return policy, Batch(obs, u, d.log_prob(u), advantages, returns, policy.value(obs))


def test_reference_minibatches_are_128_with_the_remainder_last():
    torch.manual_seed(1)  # the advantages and returns (the helper seeds the policy and samples itself)
    policy, batch = _on_policy_batch(2000, torch.randn(2000), torch.randn(2000))
    cfg = PPOConfig(**{**REFERENCE_PPO, "update_epochs": 2})
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
    stats = ppo_update(policy, opt, batch, cfg, torch.Generator().manual_seed(0))
    assert stats["losses/minibatches"] == 2 * 16  # 15 of 128 and one of 80 per epoch, as BatchSampler(drop_last=False)


def test_without_clipping_a_large_gradient_moves_the_weights_further():
    def first_step(max_grad_norm):
        policy, batch = _on_policy_batch(64, torch.zeros(64), torch.full((64,), 1e3))
        before = [p.detach().clone() for p in policy.parameters()]
        cfg = PPOConfig(update_epochs=1, num_minibatches=1, max_grad_norm=max_grad_norm, norm_adv=False)
        ppo_update(policy, torch.optim.SGD(policy.parameters(), lr=1e-3), batch, cfg, torch.Generator())
        return sum(float((p.detach() - b).norm() ** 2) for p, b in zip(policy.parameters(), before, strict=True)) ** 0.5

    clipped, free = first_step(0.5), first_step(None)
    assert clipped == pytest.approx(1e-3 * 0.5, rel=1e-3) and free > 100 * clipped


@pytest.mark.parametrize(("target_kl", "kl_stop", "steps"), [
    (None, "epoch", 4 * 8),  # no stop: every epoch's every minibatch
    (None, "minibatch", 4 * 8),
    (1e-9, "epoch", 8),  # CleanRL's: the first epoch runs whole, then its mean KL (> 0) stops the update
    (1e-9, "minibatch", 1),  # SB3's: the first minibatch has KL 0 (nothing moved yet); the second is checked, stops
])  # fmt: skip
def test_target_kl_stops_after_an_epoch_or_before_a_minibatch(target_kl, kl_stop, steps):
    torch.manual_seed(1)
    policy, batch = _on_policy_batch(256, torch.randn(256), torch.randn(256))
    cfg = PPOConfig(update_epochs=4, num_minibatches=8, target_kl=target_kl, kl_stop=kl_stop)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    stats = ppo_update(policy, opt, batch, cfg, torch.Generator().manual_seed(0))
    assert stats["losses/minibatches"] == steps
    if target_kl is not None:
        assert stats["losses/approx_kl"] > target_kl  # what stopped it is reported


def test_a_minibatch_stop_before_an_epochs_first_step_keeps_the_last_epochs_losses():
    """One minibatch per epoch: epoch 1 steps (KL 0), epoch 2's only minibatch is past the target and stops before
    any step. The losses reported are epoch 1's (finite, as the same update without a stop after one epoch), the KL the
    one that stopped it (a run's train.csv once showed NaN entropies there)."""
    advantages, returns = torch.randn(2, 64, generator=torch.Generator().manual_seed(1))
    reports = []
    for epochs, target_kl in ((3, 1e-9), (1, None)):
        policy, batch = _on_policy_batch(64, advantages, returns)
        cfg = PPOConfig(update_epochs=epochs, num_minibatches=1, target_kl=target_kl, kl_stop="minibatch")
        opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
        reports.append(ppo_update(policy, opt, batch, cfg, torch.Generator().manual_seed(0)))
    stopped, one_epoch = reports
    assert stopped["losses/minibatches"] == 1
    for key in ("losses/policy_loss", "losses/value_loss", "losses/entropy"):
        assert np.isfinite(stopped[key]) and stopped[key] == pytest.approx(one_epoch[key])
    assert stopped["losses/approx_kl"] > 1.5e-9 and one_epoch["losses/approx_kl"] == pytest.approx(0.0, abs=1e-7)


def test_minibatch_kl_stop_bounds_how_far_one_update_moves_the_policy():
    """Large steps (lr 0.05, no clipping to flatten the surrogate) carry the policy far within one epoch: the
    minibatch stop ends the update at the first minibatch past 1.5 x target_kl, the epoch stop only after a whole
    epoch has gone past it."""

    def after(kl_stop):
        advantages = torch.randn(512, generator=torch.Generator().manual_seed(3))
        policy, batch = _on_policy_batch(512, advantages, torch.zeros(512))
        cfg = PPOConfig(update_epochs=4, num_minibatches=16, target_kl=0.01, kl_stop=kl_stop, max_grad_norm=None,
                        clip_coef=10.0)  # fmt: skip
        opt = torch.optim.Adam(policy.parameters(), lr=0.05)
        steps = ppo_update(policy, opt, batch, cfg, torch.Generator().manual_seed(0))["losses/minibatches"]
        with torch.no_grad():
            logratio = policy.distribution(batch.obs).log_prob(batch.samples) - batch.logprobs
            return steps, float(((logratio.exp() - 1) - logratio).mean())

    (mb_steps, mb_kl), (epoch_steps, epoch_kl) = after("minibatch"), after("epoch")
    assert mb_steps < epoch_steps == 16 and mb_kl < 0.5 * epoch_kl


@pytest.mark.parametrize("bootstrap_terminal", [False, True])
def test_bootstrap_terminal_adds_gamma_v_of_the_final_state(bootstrap_terminal):
    torch.manual_seed(0)
    policy = ActorCritic(3, 2, "beta", (8,))
    cfg = PPOConfig(num_steps=2, scale_reward=False, bootstrap_terminal=bootstrap_terminal)
    learner = PPOLearner(policy, cfg, num_envs=3, gamma=0.9, num_updates=1, generator=torch.Generator())
    obs, next_obs = np.random.default_rng(0).normal(size=(2, 3, 3)).astype(np.float32)
    u, _ = learner.act(obs)
    rewards = np.array([1.0, 2.0, 3.0])
    terminated, truncated = np.array([True, False, False]), np.array([False, True, False])
    learner.observe(Step(obs, u, rewards, next_obs, terminated, truncated))
    with torch.no_grad():
        v_next = policy.value(torch.as_tensor(next_obs)).numpy()
    expected = rewards + 0.9 * v_next * np.array([bootstrap_terminal, True, False])
    np.testing.assert_allclose(learner.rollout.rewards[0], expected, rtol=1e-6)
    np.testing.assert_array_equal(learner.rollout.dones[0], [1, 1, 0])


@pytest.mark.parametrize(
    "bad", [{"advantage": "td"}, {"value_loss": "l3"}, {"minibatch_size": 0}, {"max_grad_norm": 0.0},
            {"adam_eps": -1.0}, {"norm_adv": "no"}, {"kl_stop": "update"}])  # fmt: skip
def test_bad_ppo_settings_are_config_errors(bad):
    with pytest.raises((ConfigError, UnknownNameError)):
        PPOConfig(**bad)


def test_carracing_paper_task_is_the_reference_exactly():
    """The task config holds every reference setting: PPO (REFERENCE_PPO; a 2,000-transition rollout), protocol,
    network (six xavier convolutions with biases 0.1 on grey / 128 - 1, ReLU 100-unit actor and critic, PyTorch's
    Linear init)."""
    from omegaconf import OmegaConf

    from envs.carracing import REFERENCE_PROTOCOL
    from hrtc.cli import compose
    from hrtc.config import RunConfig

    cfg = RunConfig.from_mapping(OmegaConf.to_container(compose(["task=carracing_paper", "algo=ppo"]), resolve=True))
    assert {k: getattr(cfg.ppo, k) for k in REFERENCE_PPO} == REFERENCE_PPO
    assert cfg.ppo.num_steps * cfg.num_envs == 2000
    assert {k: cfg.env_kwargs[k] for k in REFERENCE_PROTOCOL} == REFERENCE_PROTOCOL
    assert cfg.env_kwargs["action_repeat"] == 8 and cfg.env_kwargs["frame_stack"] == 4
    assert (cfg.hidden, cfg.activation, cfg.weight_init) == ((100,), "relu", "torch")
    assert cfg.encoder["scale"] * 255 + cfg.encoder["offset"] == pytest.approx(255 / 128 - 1)
    assert cfg.encoder["offset"] == -1.0 and cfg.encoder["init"] == "xavier"


# --------------------------------------------------------------------------------------------------- throughput, device
def _pixel_learner(seed: int = 0) -> PPOLearner:
    from hrtc.encoders import ConvEncoder

    torch.manual_seed(seed)
    encoder = ConvEncoder(shape=(2, 96, 96), channels=(4, 4, 8, 8, 8, 8))
    policy = ActorCritic(2 * 96 * 96, 2, "beta", (16,), encoder=encoder)
    cfg = PPOConfig(num_steps=4, num_minibatches=2, update_epochs=2, scale_reward=False, normalize_obs=False)
    return PPOLearner(policy, cfg, num_envs=2, gamma=0.99, num_updates=1, generator=torch.Generator().manual_seed(1))


def test_uint8_pixels_are_stored_as_uint8_and_learn_exactly_as_floats():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (5, 2, 2 * 96 * 96)).astype(np.uint8)
    runs = []
    for dtype in (np.uint8, np.float32):
        learner = _pixel_learner()
        torch.manual_seed(2)
        for t in range(4):
            u, _ = learner.act(frames[t].astype(dtype))
            done = np.array([t == 1, False])
            learner.observe(Step(frames[t].astype(dtype), u, np.array([1.0, -0.5]), frames[t + 1].astype(dtype), done,
                                 np.zeros(2, bool)))  # fmt: skip
        assert learner.rollout.obs.dtype == dtype and learner.rollout.obs.nbytes == 4 * 2 * 2 * 96 * 96 * (
            1 if dtype == np.uint8 else 4
        )
        runs.append((learner.update(), [p.detach().clone() for p in learner.policy.parameters()]))
    (stats8, params8), (stats32, params32) = runs
    assert stats8 == pytest.approx(stats32, rel=1e-6, nan_ok=True)
    for a, b in zip(params8, params32, strict=True):
        torch.testing.assert_close(a, b)


def test_device_auto_is_cuda_only_when_torch_sees_a_gpu(monkeypatch):
    from hrtc.policy import resolve_device

    assert resolve_device("cpu") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    with pytest.raises(ConfigError, match="sees no GPU"):
        resolve_device("cuda")
    with pytest.raises(UnknownNameError):
        resolve_device("tpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("cuda") == resolve_device("cuda")


def test_device_cuda_without_a_gpu_is_one_error_line():
    import subprocess
    import sys
    from pathlib import Path

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run([sys.executable, str(root / "scripts" / "train.py"), "task=carracing_paper", "device=cuda"],
                            cwd=root, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 2 and result.stderr.strip().splitlines() == [
        f"error: device=cuda, but torch {torch.__version__} sees no GPU; use device=cpu or device=auto"
    ]


def test_device_auto_keeps_sac_on_the_cpu_on_a_gpu_machine(monkeypatch):
    """The bare command (cartpole_swingup learns with SAC) must run on a GPU machine: auto is the CPU for SAC, the GPU
    for PPO; only an explicit device=cuda with SAC is refused."""
    from omegaconf import OmegaConf

    from hrtc.cli import compose
    from hrtc.config import RunConfig

    def config(*overrides: str) -> RunConfig:
        return RunConfig.from_mapping(OmegaConf.to_container(compose(list(overrides)), resolve=True))

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    sac = config("task=cartpole_swingup")
    ppo = config("task=cartpole_swingup", "learner=ppo")
    assert (sac.learner, sac.policy_device) == ("sac", "cpu") and ppo.policy_device == "auto"
    with pytest.raises(ConfigError, match="learner=sac runs on the CPU"):
        config("task=cartpole_swingup", "device=cuda")
