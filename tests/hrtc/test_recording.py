"""The Rerun recording, read back with rerun-sdk's own reader: what was logged is what is found, the stored layout
(blueprint) is the one a person should open on, and the offline review reproduces the summary from the recording
alone."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from hrtc import review
from hrtc.callbacks import Evaluation
from hrtc.cli import compose, group_choices
from hrtc.config import ROOT_CONF, RunConfig
from hrtc.environments import make_env
from hrtc.episodes import Decision, eval_seeds, evaluate, run_episodes
from hrtc.errors import ConfigError, HRTCError, UnknownNameError
from hrtc.logging.palette import NEUTRAL, skill_colors
from hrtc.logging.rerun_sink import RerunSink, entity_paths, read_blueprint, read_recording, segment_paths, stores
from hrtc.logging.trace import RecordingConfig, TraceCollector, weight_summary
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

ROOT = Path(__file__).resolve().parents[2]
SKILLS = OmegaConf.to_container(OmegaConf.load(ROOT_CONF / "task" / "cartpole_swingup.yaml"))["task"]["skills"]
NAMES = list(SKILLS)
EPISODE_STEPS = 100  # env_kwargs time_limit 1 s of 0.01 s steps
LOGGER = RecordingConfig(mode="save", frame_every=20, frame_size=(48, 64), frame_episodes=1, frame_evals_every=2,
                         train_sample_every=10, action_names=("cart_force",), key_state="pole_angle")  # fmt: skip


def _cfg(steps: int, **kwargs) -> RunConfig:
    base = dict(task="cartpole_swingup", skills=SKILLS, seed=5, steps=steps, num_envs=2, vector="sync",
                eval_every=500, eval_episodes=2, progress=False, decision_every=5, env_kwargs={"time_limit": 1.0},
                ppo=PPOConfig(num_steps=50, learning_rate=1e-3), logger=LOGGER)  # fmt: skip
    return RunConfig(**{**base, **kwargs})


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("run")
    trainer = Trainer(_cfg(1000), run_dir)
    (evaluation,) = [c for c in trainer.callbacks if isinstance(c, Evaluation)]
    tee = TraceCollector(evaluation.recorder)  # keeps what the evaluations hand over and passes it on to the recording
    evaluation.recorder = tee
    trainer.train()
    return run_dir, tee.traces


def test_recording_holds_every_evaluation_step_with_its_names_and_ranges(trained):
    run_dir, traces = trained
    (path,) = segment_paths(run_dir)
    steps = read_recording([path], contents="/meta/**", index="env_step")
    evaluations = len(pd.read_csv(run_dir / "eval.csv"))  # at 0, 500, 1000
    decisions = evaluations * 2 * EPISODE_STEPS // 5
    assert len(traces) == evaluations * 2
    assert len(steps) == decisions
    assert list(steps["/meta/weights:SeriesLines:names"].dropna().iloc[0]) == NAMES
    weights = np.stack(steps["/meta/weights"])
    alpha, beta = np.stack(steps["/meta/alpha"]), np.stack(steps["/meta/beta"])
    assert weights.shape == (decisions, len(NAMES))
    assert np.all((weights >= 0) & (weights <= 1))
    assert np.all(alpha >= 1) and np.all(beta >= 1)
    np.testing.assert_allclose(np.stack(steps["/meta/confidence"]), alpha + beta, rtol=1e-12)
    # Exactly the values the evaluations produced, in order.
    np.testing.assert_array_equal(weights, np.concatenate([np.asarray(t.weights) for t in traces]))
    np.testing.assert_array_equal(alpha, np.concatenate([np.asarray(t.alpha) for t in traces]))
    # The Beta mean is what acted.
    np.testing.assert_allclose(weights, alpha / (alpha + beta), rtol=1e-6)


def test_recording_holds_proposals_actions_rewards_values_diagnostics_and_frames(trained):
    run_dir, traces = trained
    paths = segment_paths(run_dir)
    table = read_recording(paths, contents="/**", index="env_step")
    rows = table[table["/reward"].notna()]
    rewards = np.concatenate([t.reward for t in traces])
    np.testing.assert_array_equal(np.stack(rows["/reward"])[:, 0], rewards)
    values = np.concatenate([t.values for t in traces])
    np.testing.assert_allclose(np.stack(rows["/value"])[:, 0], values, rtol=1e-6)
    proposals = np.concatenate([np.asarray(t.proposals) for t in traces])  # (T, K, A)
    for k, name in enumerate(NAMES):
        np.testing.assert_array_equal(np.stack(rows[f"/skills/{name}/action"]), proposals[:, k, :])
    blended = np.stack(rows["/action/blended"])
    assert np.all(np.abs(blended) <= 1.0)
    np.testing.assert_array_equal(blended, np.concatenate([np.asarray(t.action) for t in traces]))
    # Solver diagnostics of the MPC skills, and each skill's measured compute time.
    for column in ("/skills/balance/status", "/skills/tracker/solve_ms", "/skills/hold/compute_ms"):
        assert rows[column].notna().all(), column
    # Frames: the last episode of the 2nd evaluation and of the last (not of the first, at step 0), one every 20 env
    # steps.
    camera = read_recording(paths, contents="/world/**", index="env_step")
    blobs = camera["/world/camera:EncodedImage:blob"]
    frames = camera[[v is not None and len(v) > 0 for v in blobs]]
    with_frames = [t for t in traces if t.frames]
    assert [t.episode for t in with_frames] == [3, 5]  # evaluations 1 and 2 of 0..2, two episodes each
    assert all(len(t.frames) == EPISODE_STEPS // 20 for t in with_frames)
    assert len(frames) == sum(len(t.frames) for t in with_frames)
    assert set(frames["episode"]) == {3, 5}
    assert with_frames[0].frames[0][1].shape == (48, 64, 3)
    # Every episode starts by clearing the camera: an episode without frames shows none, not an older episode's.
    starts = rows.groupby("episode")["env_step"].min() - 5  # the first decision is 5 env steps in
    clears = camera[[v is not None and len(v) == 0 for v in blobs]]
    assert list(clears["env_step"]) == list(starts) and list(clears["episode"]) == list(starts.index)
    # The task's key state after every decision: the pole angle, near hanging (pi) just after each reset.
    keys = np.stack(rows["/state/pole_angle"])[:, 0]
    np.testing.assert_array_equal(keys, np.concatenate([t.key for t in traces]))
    first = rows.groupby("episode")["/state/pole_angle"].first()
    assert all(abs(v[0]) > 2.5 for v in first) and np.all(np.abs(keys) <= np.pi)


def test_recording_holds_training_metrics_samples_and_the_tree(trained):
    run_dir, _ = trained
    paths = segment_paths(run_dir)
    train = pd.read_csv(run_dir / "train.csv")
    updates = read_recording(paths, contents="/train/**", index="update")
    assert list(updates["update"]) == list(range(1, len(train) + 1))
    np.testing.assert_allclose(np.stack(updates["/train/losses/approx_kl"])[:, 0], train["losses/approx_kl"])
    samples = read_recording(paths, contents="/meta/weights", index="global_step").dropna(subset=["global_step"])
    assert len(samples) == len(train) * 50 // 10  # every 10th of 50 decisions per rollout
    assert stores(paths[0]) == {"recording": 1, "blueprint": 1}  # `rerun recording.rrd` opens on our layout
    tree = read_recording(paths, contents="/tree", index=None)
    text = str(tree["/tree:TextDocument:text"].iloc[0])
    assert all(name in text for name in NAMES)


def _rgb(packed: int) -> tuple[int, int, int]:
    """Rerun's packed 0xRRGGBBAA colour as (r, g, b)."""
    return (int(packed) >> 24 & 255, int(packed) >> 16 & 255, int(packed) >> 8 & 255)


def test_blueprint_opens_on_env_step_with_one_scale_per_view_and_only_what_was_logged(trained):
    run_dir, _ = trained
    (path,) = segment_paths(run_dir)
    layout = read_blueprint(path)
    assert layout["timeline"] == "env_step" and layout["play_state"] == "following"
    views = layout["views"]
    # The weights: a fixed [0, 1] axis; every evaluation plot shows the last episode before the cursor (the end).
    assert views["skill weights"]["y_range"] == [0.0, 1.0]
    last_episode = {"start": {"CursorRelative": -EPISODE_STEPS}, "end": {"CursorRelative": 0}}
    for name in ("skill weights", "pole_angle", "confidence: alpha + beta", "proposals and blended action",
                 "reward per decision", "value (critic)", "tracker: cost"):  # fmt: skip
        assert views[name]["x_range"] == last_episode, name
    # Training views show their whole timeline when it is picked.
    whole = {"start": {"Infinite": None}, "end": {"Infinite": None}}
    assert views["training return"]["x_range"] == whole and views["learning rate"]["x_range"] == whole
    # Views only for what the recording holds: no skill-tree panel for a flat library; a camera, the key state.
    assert "effective weights (skill tree)" not in views
    assert views["camera"]["class"] == "2D" and views["pole_angle"]["contents"] == ["state/pole_angle"]
    recorded = entity_paths(segment_paths(run_dir))
    for name, view in views.items():
        for entity in view["contents"]:
            assert entity.removesuffix("/**") in recorded, (name, entity)
    contents = {name: set(view["contents"]) for name, view in views.items()}
    # One quantity per axis scale: counts apart from losses, SPS apart from the learning rate, each skill's cost
    # apart, evaluation returns apart from their metadata (lengths, seeds, steps).
    assert contents["minibatches (count)"] == {"train/losses/minibatches", "train/losses/skipped"}
    assert contents["steps per second"] == {"train/charts/SPS", "train/charts/rollout_SPS"}
    assert contents["policy_loss"] == {"train/losses/policy_loss"} and contents["value_loss"] == {
        "train/losses/value_loss"}  # fmt: skip
    assert contents["balance: cost"] == {"skills/balance/cost"} and contents["tracker: cost"] == {"skills/tracker/cost"}
    assert contents["evaluation return"] == {"eval/episode/return", "eval/episode_reward", "eval/episode_reward_std"}
    assert not any("eval/episode/seed" in c or "eval/episode/global_step" in c for c in contents.values())
    assert contents["reward per decision"] == {"reward"} and contents["value (critic)"] == {"value"}
    assert len(views) == len(contents)  # view names are unique


def test_every_skill_keeps_its_colour_in_every_view_and_actions_carry_the_task_names(trained):
    run_dir, _ = trained
    static = read_recording(segment_paths(run_dir), contents="/**", index=None).iloc[0]
    colors = skill_colors(NAMES)
    assert len(set(colors)) == len(NAMES)
    for entity in ("meta/weights", "meta/alpha", "meta/beta", "meta/confidence"):
        assert [_rgb(c) for c in static[f"/{entity}:SeriesLines:colors"]] == colors, entity
        assert list(static[f"/{entity}:SeriesLines:names"]) == NAMES
    for name, color in zip(NAMES, colors, strict=True):
        assert [_rgb(c) for c in static[f"/skills/{name}/action:SeriesLines:colors"]] == [color]
        assert list(static[f"/skills/{name}/action:SeriesLines:names"]) == [f"{name}/cart_force"]
        assert [_rgb(c) for c in static[f"/skills/{name}/compute_ms:SeriesLines:colors"]] == [color]
        assert [_rgb(c) for c in static[f"/train/faults/{name}:SeriesLines:colors"]] == [color]
    assert list(static["/action/blended:SeriesLines:names"]) == ["blended/cart_force"]
    assert [_rgb(c) for c in static["/action/blended:SeriesLines:colors"]] == [NEUTRAL]
    # No other series borrows a skill's colour (reward, value, key state, training and evaluation metrics).
    others = [c for c in static.index if c.endswith(":SeriesLines:colors") and not c.startswith(("/meta/", "/skills/"))
              and not c.startswith("/train/faults/")]  # fmt: skip
    assert len(others) > 20 and {"/reward:SeriesLines:colors", "/state/pole_angle:SeriesLines:colors"} <= set(others)
    assert not {_rgb(c) for column in others for c in static[column]} & set(colors)


def test_layout_of_an_empty_recording_has_no_empty_views(tmp_path):
    sink = RerunSink(tmp_path, RecordingConfig(key_state="pole_angle"), NAMES, 1, "# a tree")
    sink.close()
    layout = read_blueprint(sink.path)
    assert set(layout["views"]) == {"skill tree"}
    assert stores(sink.path) == {"recording": 1, "blueprint": 1}


@pytest.mark.parametrize("task", group_choices("task"))
def test_every_task_declares_its_action_names_and_a_scalar_key_state(task):
    import envs

    cfg = RunConfig.from_mapping(OmegaConf.to_container(compose([f"task={task}"]), resolve=True))
    env = envs.make(cfg.task, **dict(cfg.env_kwargs))
    try:
        env.reset(seed=0)
        assert len(cfg.logger.action_names) == env.action_space.shape[0]
        value = np.asarray(env.unwrapped.skill_state()[cfg.logger.key_state])
        assert value.shape == (1,) and np.isfinite(value).all()
    finally:
        env.close()


def test_review_reproduces_the_summary_from_the_recording_alone(trained, tmp_path):
    run_dir, traces = trained
    data = review.load(run_dir)
    summary = review.summarize(data)
    assert data.skill_names == tuple(NAMES)
    assert len(summary) == len(traces)
    for (_, row), trace in zip(summary.iterrows(), traces, strict=True):
        expected = weight_summary(np.asarray(trace.weights), np.asarray(trace.alpha), np.asarray(trace.beta), NAMES)
        for name, stats in expected.items():
            for key, value in stats.items():
                assert row[f"{name}/{key}"] == pytest.approx(value, rel=1e-9), (name, key)
        assert row["return"] == pytest.approx(trace.episode_return)
    evals = pd.read_csv(run_dir / "eval.csv")
    np.testing.assert_allclose(summary.groupby("global_step")["return"].mean(), evals["episode_reward"], rtol=1e-6)
    assert data.key_state == "pole_angle"
    np.testing.assert_array_equal(data.steps["key"].to_numpy(), np.concatenate([t.key for t in traces]))
    out = review.plot_activations(data, tmp_path / "activations.png")
    assert out.stat().st_size > 10_000
    # The plot draws each skill in its palette colour (the same as the recording's).
    import matplotlib.image

    pixels = (matplotlib.image.imread(out)[..., :3] * 255).round().astype(int).reshape(-1, 3)
    for color in skill_colors(NAMES):
        assert (np.abs(pixels - color).max(axis=1) <= 2).sum() > 50, color
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "review.py"), str(run_dir), "--out",
                             str(tmp_path / "cli.png")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert f"{len(traces)} evaluation episodes" in result.stdout
    assert (tmp_path / "cli.png").exists()


def test_resume_writes_a_new_segment_and_review_reads_both(tmp_path):
    Trainer(_cfg(500, eval_episodes=1), tmp_path).train()
    Trainer(_cfg(1000, eval_episodes=1), tmp_path, resume=True).train()
    assert [p.name for p in segment_paths(tmp_path)] == ["recording.rrd", "recording.1.rrd"]
    data = review.load(tmp_path)
    assert list(data.episodes["episode"]) == [0, 1, 2]  # evaluations at 0 and 500, then (resumed) at 1000
    assert list(data.episodes["global_step"]) == [0, 500, 1000]
    assert data.steps["env_step"].is_monotonic_increasing


def test_review_reads_a_run_killed_mid_training(tmp_path):
    run_dir = tmp_path / "killed"
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), "task=cartpole_swingup", "steps=200000",
           "eval_every=500", "eval_episodes=1", "progress=false", "vector=sync", "+task.env_kwargs.time_limit=1.0",
           "logger.frames=false", f"hydra.run.dir={run_dir}"]  # fmt: skip
    process = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline:
            eval_csv = run_dir / "eval.csv"
            if eval_csv.exists() and len(eval_csv.read_text().splitlines()) >= 4:  # header + 3 evaluations
                break
            time.sleep(0.5)
        else:
            pytest.fail("the training run wrote no evaluations within 120 s")
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    data = review.load(run_dir)
    assert len(data.episodes) >= 3
    summary = review.summarize(data)
    assert np.isfinite(summary.filter(like="mean_weight").to_numpy()).all()


def test_eval_skill_records_one_skill_alone(tmp_path):
    sys.path.insert(0, str(ROOT / "scripts"))
    import eval_skill

    text = eval_skill.run({**eval_skill.DEFAULTS, "task": "cartpole_swingup", "skill": "balance", "episodes": 1,
                           "out": str(tmp_path), "frames": False})  # fmt: skip
    assert "balance" in text and "median ms" in text
    data = review.load(tmp_path)
    weights = np.stack(data.steps["weights"])
    assert weights.shape == (1000, 4)
    np.testing.assert_array_equal(weights, np.tile([0.0, 1.0, 0.0, 0.0], (1000, 1)))
    assert data.steps["alpha"].isna().all()  # a fixed blend has no Beta parameters


def test_evaluation_recorder_does_not_change_returns(trained):
    run_dir, _ = trained
    from hrtc.checkpoint import load_policy
    from hrtc.environments import make_env

    policy, normalizer, meta = load_policy(run_dir / "checkpoints" / "last.pt")
    env = make_env(meta["task"], meta["algo"], meta["skills_cfg"], meta["action_filter"], meta["env_kwargs"], 5)
    seeds = eval_seeds(5, 2)
    plain = evaluate(policy, normalizer, env, seeds, "beta")
    collector = TraceCollector()
    traced = evaluate(policy, normalizer, env, seeds, "beta", collector)
    np.testing.assert_array_equal(plain, traced)
    assert [t.episode_return for t in collector.traces] == list(traced)


@pytest.mark.parametrize(
    "cfg,error,match",
    [
        ({"mode": "disk"}, UnknownNameError, "valid logger modes"),
        ({"frame_every": 0}, ConfigError, "frame_every"),
        ({"frame_size": [4, 4]}, ConfigError, "frame_size"),
        ({"mode": "connect"}, ConfigError, "logger.url"),
        ({"colour": "red"}, ConfigError, "unknown logger keys"),
        ({"window": 0}, ConfigError, "logger.window"),
        ({"action_names": ["x", "x"]}, ConfigError, "distinct"),
    ],
)
def test_logger_config_validation(cfg, error, match):
    with pytest.raises(error, match=match):
        RecordingConfig.from_mapping(cfg)


def test_dominant_spans_cover_the_episode_in_runs_of_one_skill():
    weights = np.array([[0.9, 0.1], [0.8, 0.3], [0.2, 0.7], [0.6, 0.6], [0.1, 0.2]])
    x = np.array([5, 10, 15, 20, 25])
    assert review.dominant_spans(weights, x) == [(0.0, 10.0, 0), (10.0, 15.0, 1), (15.0, 20.0, 0), (20.0, 25.0, 1)]


def test_plain_ppo_recording_names_the_policy_outputs_by_the_task_and_leaves_their_axis_free(tmp_path):
    import envs

    env = envs.make("cartpole_swingup", time_limit=0.1)
    cfg = RecordingConfig(frames=False, action_names=("cart_force",), key_state="pole_angle")
    sink = RerunSink(tmp_path, cfg, ["a0"], 1, state_source=env.unwrapped.skill_state)
    u = np.array([0.25], np.float32)
    run_episodes(env, lambda obs: Decision(obs, u, u), [1, 2], sink)
    sink.close()
    env.close()
    static = read_recording([sink.path], contents="/**", index=None).iloc[0]
    assert list(static["/meta/weights:SeriesLines:names"]) == ["cart_force"]
    views = read_blueprint(sink.path)["views"]
    assert "skill weights" not in views and views["policy output u (plain PPO, no skills)"]["y_range"] is None
    assert views["pole_angle"]["x_range"] == {"start": {"CursorRelative": -10}, "end": {"CursorRelative": 0}}
    assert not any(name.endswith(("time (ms)", "status, faults")) for name in views)  # no skills, no diagnostics
    assert "camera" not in views  # frames off


def test_action_names_must_match_the_task_and_the_key_state_must_exist(tmp_path):
    with pytest.raises(ConfigError, match="task's action has 1"):
        RerunSink(tmp_path / "a", RecordingConfig(action_names=("x", "y")), NAMES, 1)
    env = make_env("cartpole_swingup", "hrtc", SKILLS, env_kwargs={"time_limit": 0.1}, decision_every=5)
    sink = RerunSink(tmp_path / "b", RecordingConfig(frames=False, key_state="pole_angel"), NAMES, 1,
                     state_source=env.unwrapped.skill_state)  # fmt: skip
    weights = np.full(len(NAMES), 0.5, np.float32)
    with pytest.raises(ConfigError, match="'pole_angel' is not in the task's named state; it has .*pole_angle"):
        run_episodes(env, lambda obs: Decision(obs, weights, weights), [1], sink)
    sink.close()
    env.close()


def test_review_of_a_directory_without_recording_is_a_clear_error(tmp_path):
    with pytest.raises(HRTCError, match="no recording"):
        review.load(tmp_path)
    sink = RerunSink(tmp_path / "empty", RecordingConfig(), NAMES, 1)
    sink.close()
    with pytest.raises(HRTCError, match="no finished evaluation episode"):
        review.load(tmp_path / "empty")
