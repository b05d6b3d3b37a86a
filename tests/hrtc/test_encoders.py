"""The convolutional encoder, the actor-critic that reads it, and the trainer wiring for pixel tasks."""

import numpy as np
import pytest
import torch

from hrtc.encoders import ConvEncoder, build_encoder, check_encoder_spec
from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from hrtc.policy import ActorCritic

SPEC = {"name": "conv", "shape": [4, 96, 96], "channels": [8, 16, 32, 64, 128, 256], "scale": 1 / 255}
OBS_DIM = 4 * 96 * 96


def test_six_convolutions_from_4x96x96_to_256x1x1():
    encoder = ConvEncoder()
    convs = [m for m in encoder.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [c.out_channels for c in convs] == [8, 16, 32, 64, 128, 256]
    assert encoder.out_dim == 256 and encoder.out_hw == (1, 1)
    pixels = torch.randint(0, 256, (3, 4, 96, 96)).float()
    assert encoder(pixels).shape == (3, 256)


def test_flat_and_image_inputs_agree_and_pixels_are_scaled():
    torch.manual_seed(0)
    encoder = ConvEncoder(scale=1 / 255)
    unscaled = ConvEncoder(scale=1.0)
    unscaled.load_state_dict(encoder.state_dict())
    pixels = torch.randint(0, 256, (2, 4, 96, 96)).float()
    torch.testing.assert_close(encoder(pixels.reshape(2, -1)), encoder(pixels))
    torch.testing.assert_close(encoder(pixels), unscaled(pixels / 255))


def test_wrong_input_shape_is_refused():
    with pytest.raises(ShapeError, match="expects"):
        ConvEncoder()(torch.zeros(2, 3, 96, 96))


@pytest.mark.parametrize(
    ("spec", "error", "match"),
    [
        ({"name": "resnet"}, UnknownNameError, "valid encoders: conv"),
        ({"name": "conv", "kernel": 3}, ConfigError, "unknown encoder keys"),
        ({"name": "conv", "shape": [4, 16, 16]}, ConfigError, "too small"),
        ({"name": "conv", "channels": [8, 16]}, ConfigError, "six|6 positive"),
        ({"name": "conv", "shape": [4, 96]}, ConfigError, "channels, height, width"),
    ],
)
def test_bad_specs_raise_one_clear_error(spec, error, match):
    with pytest.raises(error, match=match):
        check_encoder_spec(spec)


def test_build_encoder_checks_the_observation_size():
    assert build_encoder(SPEC, OBS_DIM).in_dim == OBS_DIM
    with pytest.raises(ConfigError, match="observations have 100"):
        build_encoder(SPEC, 100)


def test_without_an_encoder_the_actor_critic_is_the_plain_mlp():
    torch.manual_seed(3)
    plain = ActorCritic(5, 2, "beta", (64, 64))
    torch.manual_seed(3)
    explicit = ActorCritic(5, 2, "beta", (64, 64), encoder=None)
    assert plain.encoder is None and not any(k.startswith("encoder") for k in plain.state_dict())
    for (k, a), (_, b) in zip(plain.state_dict().items(), explicit.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    obs = torch.randn(4, 5)
    torch.testing.assert_close(plain.value(obs), explicit.value(obs))


def _pixel_policy(seed: int = 0) -> ActorCritic:
    torch.manual_seed(seed)
    return ActorCritic(OBS_DIM, 5, "beta", (100,), encoder=build_encoder(SPEC, OBS_DIM))


def test_one_shared_encoder_feeds_actor_and_critic():
    policy = _pixel_policy()
    obs = torch.randint(0, 256, (6, OBS_DIM)).float()
    dist, value = policy.distribution(obs), policy.value(obs)
    assert dist.sample().shape == (6, 5) and value.shape == (6,)
    assert policy.actor_body[0].in_features == 256 and policy.critic[0][0].in_features == 256
    assert sum(1 for k in policy.state_dict() if k.startswith("encoder.") and k.endswith("weight")) == 6


def test_reused_features_give_the_same_gradients_as_two_encoder_passes():
    obs = torch.randint(0, 256, (8, OBS_DIM)).float()
    u = torch.rand(8, 5).clamp(0.05, 0.95)

    def grads(reuse: bool) -> list[torch.Tensor]:
        policy = _pixel_policy(1)
        dist = policy.distribution(obs)
        if not reuse:
            policy._features_cache = None  # force a second encoder pass
        loss = -dist.log_prob(u).mean() + policy.value(obs.clone()).pow(2).mean()
        loss.backward()
        return [p.grad.clone() for p in policy.parameters()]

    for a, b in zip(grads(True), grads(False), strict=True):
        torch.testing.assert_close(a, b)


def test_features_are_recomputed_after_the_weights_change():
    policy = _pixel_policy(2)
    obs = torch.randint(0, 256, (4, OBS_DIM)).float()
    policy.distribution(obs)  # caches the features of obs
    with torch.no_grad():
        for p in policy.encoder.parameters():
            p.add_(0.05 * torch.randn_like(p))  # in place, as an optimiser step does
    reference = _pixel_policy(2)
    reference.load_state_dict(policy.state_dict())
    torch.testing.assert_close(policy.value(obs), reference.value(obs))


def test_the_trainer_builds_the_encoder_from_the_config():
    import gymnasium as gym

    from hrtc.config import RunConfig
    from hrtc.policy import build_policy

    space = gym.spaces.Box(0.0, 1.0, (5,), np.float32)
    cfg = RunConfig(task="carracing", skills={"hold": {}}, hidden=(100,), encoder=SPEC)
    policy = build_policy(OBS_DIM, space.low, space.high, cfg.dist, cfg.hidden, encoder=cfg.encoder)
    assert isinstance(policy.encoder, ConvEncoder)
    plain = RunConfig(task="carracing", skills={"hold": {}})
    assert build_policy(10, space.low, space.high, plain.dist, plain.hidden, encoder=plain.encoder).encoder is None
    with pytest.raises(UnknownNameError):
        RunConfig(task="carracing", skills={"hold": {}}, encoder={"name": "vit"})


def test_train_cli_runs_two_updates_on_carracing(tmp_path):
    """The real entry point, HRTC on pixels: two PPO updates and an evaluation, in a few seconds of CPU."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, str(root / "scripts" / "train.py"), "task=carracing", "steps=64", "ppo.num_steps=16",
           "ppo.num_minibatches=2", "ppo.update_epochs=1", "eval_every=64", "eval_episodes=1", "vector=sync",
           "progress=false", "+task.env_kwargs.max_frames=200", f"hydra.run.dir={tmp_path}"]  # fmt: skip
    subprocess.run(cmd, check=True, cwd=root, capture_output=True, timeout=600)
    import pandas as pd

    train = pd.read_csv(tmp_path / "train.csv")
    assert len(train) == 2 and np.isfinite(train["losses/value_loss"]).all()
    assert len(pd.read_csv(tmp_path / "eval.csv")) >= 2


def test_xavier_init_and_the_references_input_scaling():
    """The reference's network: xavier_uniform (gain sqrt 2) convolutions with biases 0.1, on grey / 128 - 1."""
    import math

    torch.manual_seed(0)
    encoder = ConvEncoder(scale=1 / 128, offset=-1.0, init="xavier")
    convs = [m for m in encoder.net if isinstance(m, torch.nn.Conv2d)]
    for conv in convs:
        assert torch.all(conv.bias == 0.1)
        fan_in = conv.in_channels * conv.kernel_size[0] * conv.kernel_size[1]
        fan_out = conv.out_channels * conv.kernel_size[0] * conv.kernel_size[1]
        bound = math.sqrt(2.0) * math.sqrt(6.0 / (fan_in + fan_out))
        assert conv.weight.abs().max() <= bound and conv.weight.abs().max() > 0.9 * bound
    obs = torch.randint(0, 256, (2, 4 * 96 * 96)).float()
    expected = encoder.net(obs.reshape(2, 4, 96, 96) / 128 - 1).detach()
    np.testing.assert_allclose(encoder(obs).detach(), expected, rtol=1e-4, atol=1e-5)  # the map folded into conv 1
    with pytest.raises(UnknownNameError):
        ConvEncoder(init="he")
    with pytest.raises(UnknownNameError):
        check_encoder_spec({"name": "conv", "init": "he"})


def test_relu_and_torch_init_and_a_saved_policy_keeps_its_activation(tmp_path):
    """The reference's heads (ReLU, PyTorch's default Linear init) through the real entry point, and load_policy
    rebuilds them from the checkpoint (a tanh rebuild would load the same weights and act differently)."""
    import subprocess
    import sys
    from pathlib import Path

    import pandas as pd

    from hrtc.checkpoint import load_policy

    policy = ActorCritic(10, 3, "beta", (100,), activation="relu", weight_init="torch")
    assert any(isinstance(m, torch.nn.ReLU) for m in policy.critic.modules())
    assert not any(isinstance(m, torch.nn.Tanh) for m in policy.modules())
    head = policy.actor_head.linear
    assert head.bias.abs().max() > 0.01 and head.weight.abs().max() <= 1 / 10  # U(-1/sqrt(100), 1/sqrt(100))
    with pytest.raises(UnknownNameError):
        ActorCritic(10, 3, activation="gelu")
    root = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, str(root / "scripts" / "train.py"), "task=carracing_paper", "algo=ppo", "steps=64",
           "ppo.num_steps=16", "ppo.minibatch_size=8", "ppo.update_epochs=1", "eval_every=64", "eval_episodes=1",
           "vector=sync", "progress=false", "logger.mode=off", "+task.env_kwargs.max_frames=200",
           f"hydra.run.dir={tmp_path}"]  # fmt: skip
    subprocess.run(cmd, check=True, cwd=root, capture_output=True, timeout=600)
    train = pd.read_csv(tmp_path / "train.csv")
    assert len(train) == 2 and np.isfinite(train["train/true_episode_reward"].iloc[-1])
    loaded = load_policy(tmp_path / "checkpoints" / "last.pt")
    assert any(isinstance(m, torch.nn.ReLU) for m in loaded.policy.modules())
    assert not any(isinstance(m, torch.nn.Tanh) for m in loaded.policy.modules())
