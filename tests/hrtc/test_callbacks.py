"""Each of the trainer's callbacks alone, against a stand-in run; then the trainer calling a callback of our own."""

import os
import signal

import gymnasium as gym
import numpy as np
import pytest
import torch

from hrtc.callbacks import (
    BaseCallback,
    Checkpoints,
    Evaluation,
    HealthCheck,
    MetricsLog,
    Progress,
    SkillFaults,
    TerminateAsInterrupt,
    TrainingSamples,
    Transition,
)
from hrtc.config import RunConfig
from hrtc.distributions import BetaDistribution
from hrtc.episodes import eval_seeds
from hrtc.errors import HRTCError, SkillError
from hrtc.logging.trace import EpisodeTrace
from hrtc.policy import ActorCritic
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer


class FakeRun:
    """What a callback sees of the trainer: counters, evaluation results and ``save`` (recorded, not written)."""

    def __init__(self, global_step: int = 0, steps: int = 1_000) -> None:
        self.global_step, self.episodes, self.steps = global_step, 0, steps
        self.best_eval, self.last_eval = -np.inf, float("nan")
        self.saved: list[tuple[str, int]] = []

    @property
    def finished(self) -> bool:
        return self.global_step >= self.steps

    def wall_seconds(self) -> float:
        return 1.5

    def save(self, name: str = "last.pt"):
        self.saved.append((name, self.global_step))


class ListSink:
    def __init__(self) -> None:
        self.rows: list[tuple[str, int, dict]] = []
        self.closed = False

    def write(self, stream, step, metrics):
        self.rows.append((stream, step, dict(metrics)))

    def close(self):
        self.closed = True


def step(global_step=0, returns=(), seconds=0.0, info=None, actions=None, distribution=None) -> Transition:
    actions = np.zeros((2, 3), np.float32) if actions is None else actions
    return Transition(global_step, actions, distribution, np.zeros(2), np.zeros(2, bool), info or {}, tuple(returns),
                      seconds)  # fmt: skip


def fault_info(faults, calls, mask=None) -> dict:
    info = {"skill_faults": np.asarray(faults, float), "skill_calls": np.asarray(calls, float)}
    if mask is not None:
        info["_skill_faults"] = np.asarray(mask)
    return info


# --------------------------------------------------------------------------------------------------- faults
def test_skill_faults_keeps_each_envs_lifetime_counts_and_sums_them():
    faults = SkillFaults(("a", "b"), num_envs=2)
    run = FakeRun()
    faults.on_step(run, step(info=fault_info([[1, 0], [2, 5]], [[10, 10], [20, 20]])))
    # Env 1 reports nothing this step (the mask): its counts stay.
    faults.on_step(run, step(info=fault_info([[3, 0], [0, 0]], [[30, 30], [0, 0]], mask=[True, False])))
    total_faults, total_calls = faults.totals()
    np.testing.assert_array_equal(total_faults, [5, 5])
    np.testing.assert_array_equal(total_calls, [50, 50])
    faults.on_step(run, step(info={}))  # a plain task: no counters
    np.testing.assert_array_equal(faults.totals()[0], [5, 5])


def test_skill_faults_of_a_replaced_worker_stay_in_the_totals():
    faults, run = SkillFaults(("a",), num_envs=2), FakeRun()
    faults.on_step(run, step(info=fault_info([[3], [1]], [[30], [10]])))
    # Env 0's worker died: its fresh worker's skills count from zero; the dead one's 3 of 30 stay counted.
    restarted = {"worker_restarted": np.array([True, False]), "_worker_restarted": np.array([True, False])}
    faults.on_step(run, step(info=restarted))
    np.testing.assert_array_equal(faults.totals()[0], [4])
    faults.on_step(run, step(info=fault_info([[1], [2]], [[5], [20]])))
    np.testing.assert_array_equal(faults.totals()[0], [6])
    np.testing.assert_array_equal(faults.totals()[1], [55])


# --------------------------------------------------------------------------------------------------- metrics
def test_metrics_log_writes_a_train_row_only_when_one_is_due_with_what_happened_since_the_last():
    sink, faults, run = ListSink(), SkillFaults(("a",), 1), FakeRun()
    log = MetricsLog([sink], faults)
    log.on_start(run)
    faults.on_step(run, step(info=fault_info([[2]], [[40]])))
    log.on_step(run, step(returns=(10.0, 20.0), seconds=0.25))
    log.on_step(run, step(returns=(30.0,), seconds=0.5))
    run.global_step, run.episodes = 200, 3
    log.on_update(run, None)  # SAC between rows: nothing due
    log.on_update(run, {})
    assert sink.rows == []
    log.on_update(run, {"losses/value_loss": 1.0})
    ((stream, at, row),) = sink.rows
    assert (stream, at) == ("train", 200)
    assert row["losses/value_loss"] == 1.0 and row["episodes"] == 3 and row["faults/a"] == 2.0
    assert row["faults/worker_restarts"] == 0.0  # a run without a restarting vector env
    assert row["train/episode_reward"] == 20.0 and row["charts/update_seconds"] == 0.75
    assert row["charts/SPS"] > 0 and row["charts/rollout_SPS"] >= row["charts/SPS"]
    run.global_step, run.vec = 400, type("Vec", (), {"restarts": 2})()
    log.on_update(run, {"losses/value_loss": 2.0})  # no episode ended since: no training return
    assert sink.rows[-1][2]["faults/worker_restarts"] == 2.0
    assert np.isnan(sink.rows[-1][2]["train/episode_reward"]) and sink.rows[-1][2]["charts/update_seconds"] == 0.0
    log.write("eval", 400, {"episode_reward": 1.0})
    assert sink.rows[-1] == ("eval", 400, {"episode_reward": 1.0})
    log.on_end(run, interrupted=False)
    assert sink.closed


# --------------------------------------------------------------------------------------------------- health
def test_health_check_saves_and_stops_when_a_skill_faults_too_often():
    faults, run = SkillFaults(("solver", "hold"), 1), FakeRun(global_step=300)
    check = HealthCheck(faults, max_fault_rate=0.05, max_skipped_updates=3)
    faults.on_step(run, step(info=fault_info([[30, 0]], [[199, 199]])))
    check.on_update(run, None)  # 15% of 199 calls: too few calls to judge
    assert run.saved == []
    faults.on_step(run, step(info=fault_info([[30, 0]], [[200, 200]])))
    with pytest.raises(SkillError, match="skill 'solver' faulted in 30 of 200 calls"):
        check.on_update(run, None)
    assert run.saved == [("last.pt", 300)]


def test_health_check_stops_after_updates_that_skipped_every_minibatch_in_a_row():
    run = FakeRun()
    check = HealthCheck(SkillFaults((), 1), max_fault_rate=0.05, max_skipped_updates=2)
    skipped, fine = {"losses/skipped": 4, "losses/minibatches": 4}, {"losses/skipped": 1, "losses/minibatches": 4}
    check.on_update(run, skipped)
    check.on_update(run, fine)  # a good update resets the count
    check.on_update(run, skipped)
    check.on_update(run, None)  # no row: no update to count
    with pytest.raises(HRTCError, match="not finite in 2 updates in a row"):
        check.on_update(run, skipped)
    assert run.saved == []  # the last checkpoint is kept, not overwritten with the broken weights


# --------------------------------------------------------------------------------------------------- evaluation
class Constant(gym.Env):
    """One-step episodes whose reward the test sets."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)

    def __init__(self, true_reward: float | None = None) -> None:
        self.reward, self.seeds, self.true_reward = 0.0, [], true_reward

    def reset(self, *, seed=None, options=None):
        self.seeds.append(seed)
        return np.zeros(2, np.float32), {}

    def step(self, action):
        info = {} if self.true_reward is None else {"true_reward": self.true_reward}  # a shaping env's own reward
        return np.zeros(2, np.float32), self.reward, True, False, info


class ListRecorder:
    def __init__(self) -> None:
        self.evaluations: list[tuple[int, bool]] = []
        self.traces: list[EpisodeTrace] = []

    def start_evaluation(self, global_step, last=False):
        self.evaluations.append((global_step, last))

    def begin(self, episode_in_eval, seed, render):
        return EpisodeTrace(episode_in_eval, seed, ())

    def end(self, trace):
        self.traces.append(trace)


def test_evaluation_runs_on_its_schedule_writes_rows_and_saves_the_best():
    torch.manual_seed(0)
    env, sink, recorder, run = Constant(), ListSink(), ListRecorder(), FakeRun(steps=1_000)
    evaluation = Evaluation(ActorCritic(2, 1), None, env, "beta", every=500, episodes=2, seed=3, write=sink.write,
                            recorder=recorder)  # fmt: skip
    env.reward = 1.0
    evaluation.on_start(run)  # a fresh run: the untrained policy is evaluated at step 0
    assert env.seeds == eval_seeds(3, 2)
    run.global_step, env.reward = 400, 5.0
    evaluation.on_update(run, None)  # not due
    run.global_step, env.reward = 520, 0.5
    evaluation.on_update(run, None)  # due (the first update past 500), but worse: no best.pt
    run.global_step, env.reward = 1_000, 2.0
    evaluation.on_update(run, None)  # the last
    assert [(at, row["episode_reward"], row["episodes"]) for _, at, row in sink.rows] == [(0, 1.0, 2), (520, 0.5, 2),
                                                                                        (1_000, 2.0, 2)]  # fmt: skip
    assert sink.rows[0][2]["wall_seconds"] == 1.5
    assert [row["true_episode_reward"] for _, _, row in sink.rows] == [1.0, 0.5, 2.0]  # no shaping: the same
    assert run.saved == [("best.pt", 0), ("best.pt", 1_000)] and run.best_eval == 2.0 and run.last_eval == 2.0
    assert recorder.evaluations == [(0, False), (520, False), (1_000, True)] and len(recorder.traces) == 6
    assert recorder.traces[0].values is not None  # the master critic's value of each traced decision


def test_evaluation_of_a_shaping_env_writes_the_true_return_beside_the_shaped_one():
    sink, run = ListSink(), FakeRun(steps=1_000)
    env = Constant(true_reward=-3.0)
    env.reward = 7.0
    Evaluation(ActorCritic(2, 1), None, env, "beta", every=500, episodes=2, seed=1, write=sink.write).on_start(run)
    ((_, _, row),) = sink.rows
    assert row["episode_reward"] == 7.0 and row["true_episode_reward"] == -3.0


def test_evaluation_of_a_resumed_run_waits_for_its_next_multiple():
    sink, run = ListSink(), FakeRun(global_step=700)
    evaluation = Evaluation(ActorCritic(2, 1), None, Constant(), "beta", every=500, episodes=1, seed=1,
                            write=sink.write)  # fmt: skip
    evaluation.on_start(run)
    assert sink.rows == [] and evaluation.next == 1_000


# --------------------------------------------------------------------------------------------------- checkpoints
def test_checkpoints_on_schedule_at_the_end_and_when_interrupted():
    run, checkpoints = FakeRun(global_step=250, steps=1_000), Checkpoints(every=300)
    checkpoints.on_start(run)
    for at in (290, 310, 500, 610, 1_000):
        run.global_step = at
        checkpoints.on_update(run, None)
    assert run.saved == [("last.pt", 310), ("last.pt", 610), ("last.pt", 1_000)]
    checkpoints.on_end(run, interrupted=False)
    assert len(run.saved) == 3
    checkpoints.on_end(run, interrupted=True)
    assert run.saved[-1] == ("last.pt", 1_000)


# --------------------------------------------------------------------------------------------------- progress
def test_progress_follows_the_step_count():
    run, progress = FakeRun(global_step=100, steps=1_000), Progress(1_000, "test")
    progress.on_start(run)
    assert progress.bar.n == 100
    run.global_step, run.last_eval = 400, 12.0
    progress.on_update(run, {"train/episode_reward": 3.0, "charts/SPS": 50.0})
    assert progress.bar.n == 400
    assert sorted(progress.bar.postfix.split(", ")) == ["SPS=50", "eval=12", "train_return=3"]
    progress.on_end(run, interrupted=False)


# --------------------------------------------------------------------------------------------------- signals
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_interrupts_like_ctrl_c_until_the_run_ends(signum):
    previous = signal.getsignal(signum)
    callback = TerminateAsInterrupt()
    callback.on_start(FakeRun())
    try:
        with pytest.raises(KeyboardInterrupt, match=f"signal {int(signum)}"):
            os.kill(os.getpid(), signum)
            signal.sigtimedwait([], 1.0)  # the handler runs at the next bytecode boundary
    finally:
        callback.on_end(FakeRun(), interrupted=True)
    assert signal.getsignal(signum) == previous


def test_a_signal_whose_interrupt_a_library_swallowed_stops_the_run_at_the_end_of_its_step():
    """What CasADi does to 5-20 % of interrupts inside a solve: catches the KeyboardInterrupt and returns normally. The
    signal was remembered, so the step's end raises it again; a new run starts with nothing pending."""
    callback = TerminateAsInterrupt()
    callback.on_start(FakeRun())
    try:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            signal.sigtimedwait([], 1.0)
        except KeyboardInterrupt:
            pass  # swallowed
        with pytest.raises(KeyboardInterrupt, match="signal 15"):
            callback.on_step(FakeRun(), None)
    finally:
        callback.on_end(FakeRun(), interrupted=True)
    callback.on_start(FakeRun())
    try:
        callback.on_step(FakeRun(), None)  # nothing pending
    finally:
        callback.on_end(FakeRun(), interrupted=False)


# --------------------------------------------------------------------------------------------------- recording
class SampleSink:
    def __init__(self) -> None:
        self.samples: list = []

    def sample(self, global_step, weights, alpha, beta):
        self.samples.append((global_step, weights, alpha, beta))


def test_training_samples_record_the_first_envs_decision_every_n_steps():
    sink = SampleSink()
    samples = TrainingSamples(sink, every=2)
    samples.on_start(FakeRun())
    alpha, beta = torch.tensor([[2.0, 3.0], [4.0, 5.0]]), torch.tensor([[1.5, 1.0], [1.0, 1.0]])
    distribution = BetaDistribution(alpha, beta)
    for k in range(5):
        actions = np.full((2, 2), k, np.float32)
        samples.on_step(FakeRun(), step(global_step=10 * k, actions=actions, distribution=distribution))
    assert [s[0] for s in sink.samples] == [0, 20, 40]
    np.testing.assert_array_equal(sink.samples[1][1], [2.0, 2.0])  # env 0's weights
    np.testing.assert_array_equal(sink.samples[0][2], [2.0, 3.0])
    np.testing.assert_array_equal(sink.samples[0][3], [1.5, 1.0])
    normal = TrainingSamples(sink, every=1)
    normal.on_step(FakeRun(), step(global_step=60, distribution=None))  # a Normal policy has no alpha and beta
    assert sink.samples[-1][0] == 60 and sink.samples[-1][2:] == (None, None)


# --------------------------------------------------------------------------------------------------- the trainer
class Counting(BaseCallback):
    """Counts the trainer's calls; asks it to stop after ``stop_after`` points with nothing pending."""

    def __init__(self, stop_after: int) -> None:
        self.calls = {"start": 0, "step": 0, "update": 0, "rows": 0}
        self.ended: list[bool] = []
        self.stop_after = stop_after

    def on_start(self, run):
        self.calls["start"] += 1

    def on_step(self, run, step):
        self.calls["step"] += 1

    def on_update(self, run, stats):
        self.calls["update"] += 1
        self.calls["rows"] += bool(stats)
        return self.calls["update"] >= self.stop_after

    def on_end(self, run, interrupted):
        self.ended.append(interrupted)


def test_the_trainer_calls_the_callbacks_it_is_given_and_stops_when_one_asks(tmp_path):
    cfg = RunConfig(task="cartpole_swingup", skills={}, algo="ppo", seed=1, steps=1_000, num_envs=2, vector="sync",
                    progress=False, ppo=PPOConfig(num_steps=25))  # fmt: skip
    counting = Counting(stop_after=3)
    result = Trainer(cfg, tmp_path, callbacks=[counting]).train()
    assert counting.calls == {"start": 1, "step": 75, "update": 3, "rows": 3} and counting.ended == [False]
    assert result["steps"] == 150  # 3 rollouts of 25 steps of 2 envs: stopped before its budget
    assert not (tmp_path / "train.csv").exists()  # no standard callbacks: nothing written
