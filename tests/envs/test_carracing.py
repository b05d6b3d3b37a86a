"""The fast CarRacing against gymnasium's own: identical rewards and termination, frames within stated bounds.

Each test drives gymnasium's ``CarRacing`` and :class:`~envs.carracing.FastCarRacing` in lockstep with the same
seed and actions (a track-following driver with noise, and a random "wild" one that spins off onto the grass), and
compares every step. Frame bounds (pixel values 0-255; measured on 5 tracks x 400 steps: RGB mean 0.11-0.17, worst
frame 0.44; grey mean 0.14-0.21, worst frame 0.58; at most 1.3% of a frame's pixels off by more than 16):
"""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.box2d.car_racing import CarRacing

import envs
from envs.car_raster import GREY_WEIGHTS
from envs.carracing import STATE_KEYS, CarRacingTask, FastCarRacing, TrackFollowRule
from envs.carracing import pursuit_driver as driver

MEAN_BOUND = 0.4  # mean absolute difference over all frames of a track, RGB
GREY_MEAN_BOUND = 0.5  # the same for greyscale frames (luma rounding adds about 0.05)
FRAME_BOUND = 1.0  # mean absolute difference of any single frame
FAR_PIXELS = 16  # a pixel "far off" differs by more than this...
FAR_FRACTION = 0.03  # ...and at most this fraction of a frame's pixels may be far off


def grey(frame: np.ndarray) -> np.ndarray:
    return np.floor(frame.astype(np.float64) @ GREY_WEIGHTS + 0.5)


@pytest.mark.parametrize(("seed", "mode", "steps"), [(0, "road", 120), (1, "wild", 100), (5, "road", 120)])
def test_frames_rewards_and_termination_match_gymnasium(seed, mode, steps):
    ref, fast, fast_grey = CarRacing(), FastCarRacing(), FastCarRacing(grey=True)
    frames = [ref.reset(seed=seed)[0], fast.reset(seed=seed)[0], fast_grey.reset(seed=seed)[0]]
    rng = np.random.default_rng(seed)
    rgb_diffs, grey_diffs = [], []
    for t in range(steps + 1):
        ref_frame, fast_frame, grey_frame = frames
        assert fast_frame.shape == (96, 96, 3) and fast_frame.dtype == np.uint8 and grey_frame.shape == (96, 96)
        diff = np.abs(ref_frame.astype(int) - fast_frame)
        grey_diff = np.abs(grey(ref_frame) - grey_frame)
        assert diff.mean() <= FRAME_BOUND and grey_diff.mean() <= FRAME_BOUND, f"step {t}"
        assert (diff.max(-1) > FAR_PIXELS).mean() <= FAR_FRACTION, f"step {t}"
        rgb_diffs.append(diff.mean())
        grey_diffs.append(grey_diff.mean())
        if t == steps:
            break
        action = driver(ref, rng, mode)
        outs = [env.step(action) for env in (ref, fast, fast_grey)]
        frames = [o[0] for o in outs]
        assert outs[0][1] == outs[1][1] == outs[2][1], f"step {t}: rewards differ"
        assert outs[0][2:4] == outs[1][2:4] == outs[2][2:4], f"step {t}: termination differs"
    assert np.mean(rgb_diffs) <= MEAN_BOUND and np.mean(grey_diffs) <= GREY_MEAN_BOUND
    if mode == "road":  # the driver really drove: tiles visited (and recoloured) along the way
        assert fast.tile_visited_count == ref.tile_visited_count > 20


def test_leaving_the_playfield_ends_both_with_minus_100():
    ref, fast = CarRacing(), FastCarRacing()
    ref.reset(seed=2)
    fast.reset(seed=2)
    outs = None
    for t in range(250):  # about 150 steps: 110 world units from the start to the edge
        car = ref.car
        pos, heading = np.array(car.hull.position), car.hull.angle
        away = pos / np.linalg.norm(pos)  # head radially out of the playfield
        forward = np.array([-math.sin(heading), math.cos(heading)])
        angle = math.atan2(forward[0] * away[1] - forward[1] * away[0], forward @ away)
        action = np.array([np.clip(-1.0 * angle, -1, 1), 0.3, 0.0], np.float32)  # full gas would spin the car
        outs = ref.step(action), fast.step(action)
        assert outs[0][1:4] == outs[1][1:4], f"step {t}"
        if outs[0][2]:
            break
    assert outs is not None and outs[0][2] and outs[1][2] and outs[0][1] == outs[1][1] == -100
    assert np.abs(outs[0][0].astype(int) - outs[1][0]).mean() <= FRAME_BOUND  # the black beyond the field


@pytest.mark.slow
def test_a_whole_lap_finishes_at_the_same_frame():
    ref, fast = CarRacing(), FastCarRacing()
    ref.reset(seed=3)
    fast.reset(seed=3)
    rng = np.random.default_rng(3)
    for t in range(1500):  # this driver, without noise, laps track 3 in 786 frames
        action = driver(ref, rng, "road", noise=0.0)
        a, b = ref.step(action), fast.step(action)
        assert a[1:4] == b[1:4] and a[4] == b[4], f"step {t}"
        assert np.abs(a[0].astype(int) - b[0]).mean() <= FRAME_BOUND
        if a[2]:
            break
    assert a[2] and a[4]["lap_finished"]


def test_domain_randomised_colours_are_drawn_too():
    ref, fast = CarRacing(domain_randomize=True), FastCarRacing(domain_randomize=True)
    frames = ref.reset(seed=4)[0], fast.reset(seed=4)[0]
    for _ in range(60):
        action = np.array([0.2, 0.5, 0.0], np.float32)
        frames = ref.step(action)[0], fast.step(action)[0]
    assert np.abs(frames[0].astype(int) - frames[1]).mean() <= FRAME_BOUND


def test_other_render_modes_are_gymnasiums():
    env = FastCarRacing(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.0, 1.0, 0.0], np.float32))
    video = env.render()
    assert video.shape == (400, 600, 3) and video.std() > 0


# --------------------------------------------------------------------------------------------------- the task
def test_task_repeats_actions_stacks_grey_frames_and_sums_rewards():
    task = CarRacingTask(action_repeat=4)
    single = FastCarRacing(grey=True)
    obs, _ = task.reset(seed=7)
    first = single.reset(seed=7)[0]
    assert task.observation_space.contains(obs) and obs.shape == (4 * 96 * 96,)
    stack = obs.reshape(task.frame_shape)
    assert all(np.array_equal(stack[k], first) for k in range(4))  # the stack starts as copies of frame one
    rng = np.random.default_rng(0)
    previous = stack
    for _ in range(5):
        action = np.array([rng.uniform(-1, 1), rng.uniform(0, 1), 0.0], np.float32)
        obs, reward, terminated, truncated, info = task.step(action)
        total = sum(single.step(action)[1] for _ in range(4))
        assert reward == pytest.approx(total, abs=1e-9) and not terminated and not truncated
        stack = obs.reshape(task.frame_shape)
        np.testing.assert_array_equal(stack[-1], single.draw_frame())  # only the last frame of a repeat is drawn
        np.testing.assert_array_equal(stack[:-1], previous[1:])
        previous = stack
    assert task.frames == 20 and info["frames"] == 20


def test_time_limit_counts_frames_and_finished_episodes_are_logged(tmp_path):
    log = tmp_path / "episodes.csv"
    task = envs.make("carracing", action_repeat=8, max_frames=20, episode_log=str(log), flatten=False)
    obs, _ = task.reset(seed=1)
    assert obs.shape == (4, 96, 96)
    flags, total = [], 0.0
    for _ in range(3):
        _, reward, terminated, truncated, info = task.step(np.array([0.0, 0.5, 0.0], np.float32))
        flags.append((terminated, truncated))
        total += reward
    assert flags == [(False, False), (False, False), (False, True)] and info["frames"] == 20
    fields = log.read_text().strip().split(",")
    assert int(fields[2]) == 1 and float(fields[3]) == pytest.approx(total, abs=1e-3) and int(fields[4]) == 20


def test_the_benchmark_reads_the_logged_training_episodes_and_leaves_out_evaluation_ones(tmp_path):
    from hrtc.benchmark.metrics import best_window_mean, running_scores, running_solved_at, solved_at, training_episodes
    from hrtc.episodes import eval_seeds

    log = tmp_path / "episodes.csv"
    task = envs.make("carracing", action_repeat=8, max_frames=16, episode_log=str(log), flatten=False)
    evaluation_seed = eval_seeds(1, 10_000)[0]
    for reset_seed in (5, evaluation_seed, 6):  # a training episode, an evaluation episode, a training episode
        task.reset(seed=int(reset_seed))
        truncated = False
        while not truncated:
            truncated = task.step(np.array([0.0, 0.5, 0.0], np.float32))[3]
    read = training_episodes(tmp_path, seed=1, started=0.0, args={})
    assert len(read["returns"]) == 2 and read["frames"] == 3 * 16 and read["train_frames"] == [16, 16]
    assert len(read["true_returns"]) == 2 and np.isfinite(read["true_returns"]).all()
    # The reference's running score: a constant score s gives s (1 - 0.99^n) after n episodes.
    np.testing.assert_allclose(
        running_scores(np.full(300, 950.0))[[0, 99, 299]], 950 * (1 - 0.99 ** np.array([1, 100, 300]))
    )
    assert running_solved_at(np.full(400, 950.0), 900.0) == int(np.ceil(np.log(1 - 900 / 950) / np.log(0.99)))
    assert running_solved_at(np.full(400, 899.0), 900.0) is None
    returns = np.array([1.0, 3.0, 5.0, 0.0, 10.0])
    assert solved_at(returns, 2, 4.0) == 3 and solved_at(returns, 2, 5.0) == 5 and solved_at(returns, 2, 5.1) is None
    assert best_window_mean(returns, 2) == 5.0 and best_window_mean(returns, 6) is None


def test_same_seed_same_observations():
    def rollout(seed):
        task = envs.make("carracing", action_repeat=2)
        trace = [task.reset(seed=seed)[0]]
        trace += [task.step(np.array([math.sin(t / 3), 0.7, 0.0], np.float32))[0] for t in range(15)]
        return np.stack(trace)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3)[-1], rollout(4)[-1])


def test_skill_state_is_the_cars_physical_state():
    task = envs.make("carracing", action_repeat=4)
    task.reset(seed=0)
    for _ in range(10):
        task.step(np.array([0.3, 1.0, 0.0], np.float32))
    state = task.unwrapped.skill_state()
    assert tuple(state) == STATE_KEYS and all(np.all(np.isfinite(v)) for v in state.values())
    speed, forward, lateral = state["speed"][0], state["forward_speed"][0], state["lateral_speed"][0]
    assert speed > 1.0 and forward > 0.0 and speed == pytest.approx(math.hypot(forward, lateral))
    assert 0.0 < state["progress"][0] < 1.0 and state["wheels_on_road"][0] in (0, 1, 2, 3, 4)


def test_track_relative_state_is_the_geometry_of_the_centre_line():
    task = envs.make("carracing").unwrapped
    task.reset(seed=3)
    centre = np.array([(t[2], t[3]) for t in task.track])
    along = math.atan2(*(centre[1] - centre[0])[::-1])  # the first segment's direction
    left = np.array([-math.sin(along), math.cos(along)])
    nose = along - math.pi / 2  # a body angle whose nose (+y) points along the centre line
    for shift, turn in ((0.0, 0.0), (1.5, 0.3), (-2.0, -0.4)):
        error, offset, _ = task._track_relative(centre[0] + 0.5 * (centre[1] - centre[0]) + shift * left, nose + turn)
        assert offset == pytest.approx(shift, abs=1e-9) and error == pytest.approx(-turn, abs=1e-9)
    # A full turn of the road ahead: on the loop, the direction changes; on the start straight of this track it
    # changes less than at its sharpest bend.
    turns = [task._track_relative(p, nose)[2] for p in centre]
    assert min(turns) >= 0.0 and max(turns) > 1.0 and turns[0] < max(turns)
    state = task.skill_state()  # just after the reset the car sits on the start line, along the road
    assert abs(state["track_offset"][0]) < 0.5 and abs(state["track_heading_error"][0]) < 0.1


def test_track_follow_rule_steers_towards_the_centre_line_and_slows_for_bends():
    rule = TrackFollowRule()

    def weights(**named):
        state = {"speed": 30.0, "track_heading_error": 0.0, "track_offset": 0.0, "yaw_rate": 0.0,
                 "track_turn_ahead": 0.0} | named  # fmt: skip
        return rule({k: np.array([float(v)]) for k, v in state.items()})

    assert weights(track_heading_error=0.5)["turn_left"] > 0 == weights(track_heading_error=0.5)["turn_right"]
    assert weights(track_heading_error=-0.5)["turn_right"] > 0 == weights(track_heading_error=-0.5)["turn_left"]
    assert weights(track_offset=2.0)["turn_right"] > 0  # left of the centre line: back to the right
    assert weights(track_heading_error=10.0)["turn_left"] == 1.0  # weights stay in [0, 1]
    straight, bend = weights(speed=60.0), weights(speed=60.0, track_turn_ahead=1.5)
    assert straight["accelerate"] == 1.0 and straight["decelerate"] == 0.0
    assert bend["accelerate"] == 0.0 and bend["decelerate"] == 1.0  # 60 is above 100 / (1 + 0.9 x 1.5) + 10
    assert weights(track_heading_error=0.5)["accelerate"] == 0.0  # no gas while steering hard


def test_track_follow_rule_drives_real_tracks_through_the_composed_env():
    from hrtc.cli import task_config
    from hrtc.environments import make_env
    from hrtc.references import evaluate_rules, reference_rules

    task = task_config("carracing")
    env = make_env("carracing", "hrtc", task["skills"], env_kwargs=task["env_kwargs"])
    rules = reference_rules(env.skill_names, task["references"])
    name = "track follower (hand-written, reads the centre line)"
    returns = evaluate_rules(env, {name: rules[name], "accelerate alone": rules["accelerate alone"]}, [5000, 5001])
    env.close()
    # Two held-out tracks (the rule was tuned on 1000-1005): most tiles within the 1000 frames, far above gas alone.
    assert returns[name].min() > 800 and returns["accelerate alone"].max() < 300


def test_static_intents_pass_check_skill():
    from hrtc.check import check_task_skills
    from hrtc.cli import task_config

    cfg = task_config("carracing")
    assert set(cfg["skills"]) == {"turn_left", "turn_right", "accelerate", "decelerate", "hold"}
    results = check_task_skills(cfg, n=40)
    assert results["turn_right"]["max"] == 1.0 and results["turn_left"]["min"] == -1.0


def test_gymnasium_env_checker_accepts_the_task():
    from gymnasium.utils.env_checker import check_env

    task = envs.make("carracing", action_repeat=2)
    check_env(task, skip_render_check=True)
    assert isinstance(task, gym.Env)


# ------------------------------------------------------------------------------------------- the reference protocol
def _drive(task, actions):
    """Step ``task`` with ``actions`` until it ends; per step (shaped reward, info, terminated, truncated)."""
    steps = []
    for action in actions:
        _, reward, terminated, truncated, info = task.step(np.asarray(action, np.float32))
        steps.append((reward, info, terminated, truncated))
        if terminated or truncated:
            break
    return steps


STRAIGHT = [[0.0, 0.4, 0.0]] * 200  # track 4's first bend is ahead: straight on leaves the road onto the grass


def test_driving_straight_onto_grass_ends_early_only_under_the_option():
    stopped_task = envs.make("carracing", action_repeat=8, early_stop=True)
    stopped_task.reset(seed=4)
    default_task = envs.make("carracing", action_repeat=8)
    default_task.reset(seed=4)
    stopped = _drive(stopped_task, STRAIGHT)
    default = _drive(default_task, STRAIGHT[: len(stopped)])
    reward, info, terminated, truncated = stopped[-1]
    assert truncated and not terminated and info["early_stop"] and info["frames"] < 400
    assert not any(t or u for _, _, t, u in default) and "early_stop" not in default[-1][1]
    # Without shaping the option changes nothing but the end (mid-repeat): the same rewards before it.
    assert [r for r, *_ in stopped[:-1]] == [r for r, *_ in default[:-1]]


def test_early_stop_is_the_first_frame_where_the_last_100_frames_average_at_most_minus_0_1():
    task = envs.make("carracing", action_repeat=1, early_stop=True, grass_penalty=0.05)
    task.reset(seed=4)
    history = []
    for t in range(1000):
        _, reward, terminated, truncated, info = task.step(np.array([0.0, 0.4, 0.0], np.float32))
        history.append(reward)
        window = np.zeros(100)
        window[: min(len(history), 100)] = history[-100:]
        assert bool(truncated) == (window.mean() <= -0.1), f"frame {t + 1}"
        if truncated:
            break
    assert info["early_stop"] and 100 < task.frames < 400


def test_shaped_reward_is_the_true_reward_plus_bonus_minus_grass_frames():
    """Per frame (action repeat 1): shaped - gymnasium's = -0.05 exactly on frames whose view is mostly grass, +100 on
    gym's end, and the true returns of the shaped and unshaped env are the same on the same actions.

    On gymnasium's frames a view of grass alone has a green mean of about 182-184 (a quarter of the grass is the
    lighter 230; the black bar is 1/8 of the frame): the reference's test (> 185) fires only when the indicator
    bars add green, a few frames of a wild drive on the grass."""
    shaped = envs.make("carracing_paper", action_repeat=1, early_stop=False)
    plain = envs.make("carracing", action_repeat=1)
    shaped.reset(seed=1)
    plain.reset(seed=1)
    rng = np.random.default_rng(0)
    grass_frames = 0
    for t in range(600):
        action = driver(shaped, rng, "wild")
        _, reward, terminated, truncated, info = shaped.step(action)
        _, true_reward, plain_end, *_ = plain.step(action)
        assert info["true_reward"] == true_reward and terminated == plain_end, f"frame {t + 1}"
        grass = shaped.green_mean() > 185.0
        grass_frames += grass
        assert reward == pytest.approx(true_reward + 100.0 * terminated - 0.05 * grass, abs=1e-12), f"frame {t + 1}"
        if terminated:
            break
    assert grass_frames >= 3
    assert shaped.true_return == pytest.approx(plain.episode_return, abs=1e-9)
    bonus = 100.0 if terminated else 0.0
    assert shaped.episode_return == pytest.approx(plain.episode_return + bonus - 0.05 * grass_frames, abs=1e-9)


@pytest.mark.parametrize("seed", [2, 4])
def test_green_mean_is_gymnasiums_frame_green_mean(seed):
    """The grass test reads the green channel of the frame gymnasium itself would draw (on the road and off it)."""
    task = FastCarRacing()
    task.reset(seed=seed)
    for t in range(120):
        task.step(np.array([0.0, 0.4, 0.0], np.float32))
        if t % 20 == 19:
            assert task.green_mean() == pytest.approx(task.gym_frame()[:, :, 1].mean(), abs=0.5), f"step {t}"


def test_end_bonus_cancels_leaving_the_playfield_and_rewards_the_time_limit(tmp_path):
    log = tmp_path / "episodes.csv"
    task = envs.make("carracing", action_repeat=1, end_bonus=100.0, episode_log=str(log))
    task.reset(seed=2)
    for _ in range(250):  # as test_leaving_the_playfield_ends_both_with_minus_100
        car = task.car
        pos, heading = np.array(car.hull.position), car.hull.angle
        away = pos / np.linalg.norm(pos)
        forward = np.array([-math.sin(heading), math.cos(heading)])
        angle = math.atan2(forward[0] * away[1] - forward[1] * away[0], forward @ away)
        _, reward, terminated, _, info = task.step(np.array([np.clip(-angle, -1, 1), 0.3, 0.0], np.float32))
        if terminated:
            break
    assert terminated and info["true_reward"] == -100 and reward == 0.0
    timed = envs.make("carracing", action_repeat=8, max_frames=20, end_bonus=100.0, episode_log=str(log))
    timed.reset(seed=1)
    steps = _drive(timed, [[0.0, 0.5, 0.0]] * 3)
    assert [u for *_, u in steps] == [False, False, True]
    assert [r - i["true_reward"] for r, i, *_ in steps] == [0.0, 0.0, 100.0]
    rows = [line.split(",") for line in log.read_text().strip().splitlines()]
    assert len(rows) == 2 and all(len(row) == 8 for row in rows)
    for row, env in zip(rows, (task, timed), strict=True):  # shaped score, then the true return
        assert float(row[3]) == pytest.approx(env.episode_return, abs=1e-3) and float(row[3]) != float(row[6])
        assert float(row[6]) == pytest.approx(env.true_return, abs=1e-3) and row[7] == "0"


def test_paper_task_is_the_reference_protocol_and_bad_options_are_config_errors():
    from hrtc.errors import ConfigError

    paper, plain = envs.make("carracing_paper"), envs.make("carracing")

    def protocol(env):
        return env.early_stop, env.grass_penalty, env.end_bonus, env.lap_complete_percent

    assert protocol(paper) == (True, 0.05, 100, 1.0) and protocol(plain) == (False, 0, 0, 0.95)
    for bad in ({"grass_penalty": "much"}, {"end_bonus": float("nan")}, {"early_stop": 1}):
        with pytest.raises(ConfigError):
            envs.make("carracing", **bad)
