"""One benchmark run of any algorithm: train for a budget of env steps, evaluate on a schedule, return a plain dict.

Every algorithm is evaluated the same way: deterministic episodes (the distribution's mode: the Beta mean for HRTC,
``predict(deterministic=True)`` for stable-baselines3) on the seeds :func:`hrtc.trainer.eval_seeds` gives, which are
disjoint from the training seeds, after every ``eval_every`` env steps. The result holds the raw evaluation curve
(env step, mean and std of the evaluation returns, training episodes so far, wall time); whether and when the run
solved the task is decided afterwards, in :mod:`hrtc.benchmark.report`, so the solve rule can be re-applied to
stored results.

The result dict is JSON-serialisable: it travels back from a Ray worker or a pool process and is cached on disk.

A trainer run that was killed (a machine that went away, a sitting that ended) resumes where its run directory's
``checkpoints/last.pt`` left it when the benchmark is started again: the checkpoint is written at every evaluation,
and the evaluation curve so far (``curve.json``) and the episode log are kept up to it. Stable-baselines3 runs
restart from scratch.
"""

from __future__ import annotations

import json
import platform
import shutil
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hrtc.errors import UnknownNameError

# name -> (family, setting): "trainer" runs hrtc.trainer.Trainer with (algo, dist, learner); "sb3" a
# stable-baselines3 class on the raw task, or on the composed task (the action is the skill-weight vector).
ALGORITHMS: dict[str, tuple[str, tuple[str, ...]]] = {
    "hrtc_beta": ("trainer", ("hrtc", "beta", "ppo")),
    "hrtc_beta_sac": ("trainer", ("hrtc", "beta", "sac")),
    "hrtc_normal": ("trainer", ("hrtc", "normal", "ppo")),
    "ppo_beta": ("trainer", ("ppo", "beta", "ppo")),
    "ppo_normal": ("trainer", ("ppo", "normal", "ppo")),
    "sb3_ppo": ("sb3", ("PPO", "")),
    "sb3_sac": ("sb3", ("SAC", "")),
    "sb3_td3": ("sb3", ("TD3", "")),
    "sb3_a2c": ("sb3", ("A2C", "")),
    "sb3_sac_composed": ("sb3", ("SAC", "composed")),
}

# What each algorithm runs with, for the table's notes (kept next to the code that does it).
SETTINGS: dict[str, str] = {
    "hrtc_beta": "HRTC, Beta weights, the paper's PPO: the task config's PPO settings and decision rate",
    "hrtc_beta_sac": "HRTC, Beta weights, learned off-policy (learner=sac): the root config's SAC settings, the "
    "task's decision rate",
    "hrtc_normal": "HRTC, Normal weights clipped to [0, 1], PPO: the task config's PPO settings and decision rate",
    "ppo_beta": "our PPO on raw actions, Beta head: the root config's PPO settings (not the task's HRTC-tuned ones)",
    "ppo_normal": "our PPO on raw actions, Normal head: the root config's PPO settings",
    "sb3_ppo": "stable-baselines3 PPO, default hyperparameters (MLP 64x64, 2,048-step rollouts)",
    "sb3_sac": "stable-baselines3 SAC, defaults except actor and critics MLP 64x64 (the size of ours)",
    "sb3_td3": "stable-baselines3 TD3, defaults except MLP 64x64 and Gaussian action noise of std 0.1 (TD3 paper)",
    "sb3_a2c": "stable-baselines3 A2C, default hyperparameters (MLP 64x64, 5-step rollouts)",
    "sb3_sac_composed": "stable-baselines3 SAC with its defaults (MLP 256x256) acting on ComposedEnv (action = the "
    "weight vector, the task's decision rate): an off-the-shelf agent on our composition",
}

# true_reward: the evaluation's mean of the task's own return (None where it was not recorded: runs before it existed);
# true_solve_reward: rule (c)'s mean true return over true_solve_episodes tracks, where the evaluation passed its screen
CURVE_KEYS = ("step", "episode_reward", "episode_reward_std", "episodes", "wall_seconds", "solve_reward", "true_reward",
              "true_solve_reward")  # fmt: skip


@dataclass(frozen=True)
class RunSpec:
    """One (algorithm, seed) of a benchmark. ``run_dir`` receives the run's own files (CSVs, checkpoints) on the
    machine that executes it; ``cpus`` is what the run may use (its Ray resource request).

    A benchmark config may name variants of the built-in algorithms (``algo`` is then the variant's name and ``base``
    the algorithm it runs): ``overrides`` are appended to the trainer's Hydra overrides (trainer algorithms) or
    given to the stable-baselines3 constructor as ``key=value`` keyword arguments; ``root_ppo`` False keeps the
    task's PPO block for PPO on raw actions. After training: ``final_episodes`` deterministic episodes of the final
    policy (and of the best evaluated one with ``final_best``) on the seeds of ``final_seed_base`` (None: the
    evaluation seeds), the ``metric`` plug-in (:mod:`hrtc.benchmark.metrics`) with ``metric_args``, ``export``
    (a path: a copy of the run's best checkpoint), ``wall_minutes`` (stop training after so many minutes).

    ``true_solve_episodes`` > ``eval_episodes`` checks rule (c) on a shaping task (CarRacing's reference protocol): an
    evaluation whose mean *true* return (the task's own reward) reaches ``solve_threshold`` is a screen, and the same
    policy runs the remaining tracks at once (:func:`confirm_true_solve`). It changes no training, so results stored
    before it (without the field) still answer the spec."""

    task: str
    algo: str
    seed: int
    steps: int
    eval_every: int
    eval_episodes: int
    run_dir: str
    cpus: int = 1
    solve_threshold: float | None = None
    solve_episodes: int = 0
    final_episodes: int = 0  # episodes of a last evaluation of the final policy (0: none)
    base: str = ""  # the built-in algorithm a variant runs ("": ``algo`` itself)
    overrides: tuple[str, ...] = ()
    root_ppo: bool = True
    final_seed_base: int | None = None
    final_best: bool = False
    metric: str = "returns"
    metric_args: Mapping[str, Any] = field(default_factory=dict)
    export: str | None = None
    wall_minutes: float | None = None
    true_solve_episodes: int = 0

    def __post_init__(self) -> None:
        if self.builtin not in ALGORITHMS:
            raise UnknownNameError("algorithm", self.builtin, tuple(ALGORITHMS))

    @property
    def builtin(self) -> str:
        """The built-in algorithm (a key of :data:`ALGORITHMS`) this run trains."""
        return self.base or self.algo

    @property
    def confirms(self) -> bool:
        """Whether the solve rule averages more episodes than an evaluation runs (LunarLander: 200 over 100).

        Then an evaluation whose mean reaches the threshold is a screen: the same policy runs the rule's remaining
        episodes at once (the first ``eval_episodes`` seeds are shared), until one confirms. Running 100 episodes at
        every evaluation would cost more than the training."""
        return self.solve_threshold is not None and self.solve_episodes > self.eval_episodes

    @property
    def key(self) -> str:
        """The run's name in results.json and its cache file: ``<algo>/seed<N>``."""
        return f"{self.algo}/seed{self.seed}"


def run(spec: RunSpec) -> dict[str, Any]:
    """Train ``spec.algo`` for ``spec.steps`` env steps with evaluations on the schedule; returns the result dict."""
    family, _ = ALGORITHMS[spec.builtin]
    Path(spec.run_dir).mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    extra = _trainer_run(spec) if family == "trainer" else _sb3_run(spec)
    curve = extra.pop("curve")
    wall_before = extra.pop("wall_before", 0.0)  # a resumed run's earlier sittings
    settings = SETTINGS[spec.builtin]
    if not spec.root_ppo and ALGORITHMS[spec.builtin][1][0] == "ppo":
        settings = settings.split(":")[0] + ": the task config's PPO settings"
    settings += f"; overrides {' '.join(spec.overrides)}" if spec.overrides else ""
    return {
        **asdict(spec),
        "env_steps": int(curve["step"][-1]),
        "curve": curve,
        **extra,
        "wall_seconds": wall_before + time.perf_counter() - tic,
        "settings": settings,
        "host": platform.node(),
    }


def episode_seeds(base: int | None, seed: int, episodes: int) -> list[int]:
    """``episodes`` seeds of run seed ``seed``: ``base + 1000 seed + k``; base None: the evaluation seeds
    (:func:`hrtc.trainer.eval_seeds`). A base of 2,000,000 keeps them disjoint from training and evaluation."""
    from hrtc.episodes import eval_seeds

    return eval_seeds(seed, episodes) if base is None else [base + 1_000 * seed + k for k in range(episodes)]


# --------------------------------------------------------------------------------------------------- our trainer
class _EvalCollector:
    """A :class:`hrtc.logging.Sink` keeping the evaluation rows in memory (the same rows as eval.csv), and running
    the solve rule's confirmation episodes on the trainer's current policy when an evaluation passes the screen."""

    def __init__(self, spec: RunSpec) -> None:
        self.spec = spec
        self.trainer: Any = None  # set once the Trainer exists
        self.curve: dict[str, list[Any]] = {k: [] for k in CURVE_KEYS}
        self.sps: list[float] = []  # the training loop's env steps/s, per train.csv row
        minutes = spec.wall_minutes
        self.deadline = None if minutes is None else time.perf_counter() + 60.0 * minutes

    def restore(self, step: int, wall_before: float) -> None:
        """A resumed run's curve: the evaluations its earlier sittings saved (``curve.json``; without it, the run's
        ``eval.csv``, as for a run started by ``scripts/train.py`` in the same directory) up to the checkpoint's
        ``step``; the wall-time budget counts the ``wall_before`` seconds they trained."""
        path = Path(self.spec.run_dir) / "curve.json"
        saved = json.loads(path.read_text()) if path.exists() else self._from_eval_csv()
        keep = [i for i, s in enumerate(saved.get("step", [])) if s <= step]
        self.curve = {k: [saved[k][i] if k in saved else None for i in keep] for k in CURVE_KEYS}
        if self.deadline is not None:
            self.deadline -= wall_before

    def _from_eval_csv(self) -> dict[str, list[Any]]:
        import pandas as pd

        path = Path(self.spec.run_dir) / "eval.csv"
        if not path.exists() or not path.stat().st_size:
            return {}
        rows = pd.read_csv(path)
        rewards = rows["episode_reward"].tolist()
        true = rows["true_episode_reward"].tolist() if "true_episode_reward" in rows else [None] * len(rewards)
        return {"step": rows["step"].astype(int).tolist(), "episode_reward": rewards,
                "true_reward": [None if v is None or v != v else v for v in true],  # NaN: a row from before the column
                "episode_reward_std": rows["episode_reward_std"].tolist(),
                "episodes": rows["train_episodes"].astype(int).tolist(), "wall_seconds": rows["wall_seconds"].tolist(),
                # a confirming rule's extra episodes were not logged: those evaluations count as unconfirmed
                "solve_reward": [None if self.spec.confirms else r for r in rewards],
                "true_solve_reward": [None] * len(rewards)}  # fmt: skip

    def write(self, stream: str, step: int, metrics: Mapping[str, float]) -> None:
        if stream == "train":
            self.sps.append(float(metrics.get("charts/SPS", float("nan"))))
        elif stream == "eval":
            self._evaluation(step, metrics)
        if self.deadline is not None and time.perf_counter() > self.deadline:
            raise KeyboardInterrupt("the wall-time budget is spent")  # the trainer saves a checkpoint and stops

    def _evaluation(self, step: int, metrics: Mapping[str, float]) -> None:
        self.curve["step"].append(int(step))
        self.curve["episode_reward"].append(float(metrics["episode_reward"]))
        self.curve["episode_reward_std"].append(float(metrics["episode_reward_std"]))
        self.curve["episodes"].append(int(metrics["train_episodes"]))
        self.curve["wall_seconds"].append(float(metrics["wall_seconds"]))
        true = metrics.get("true_episode_reward")
        self.curve["true_reward"].append(None if true is None else float(true))
        self.curve["solve_reward"].append(confirm_solve(self.spec, self.curve, lambda s: self._episodes(s).returns))
        self.curve["true_solve_reward"].append(
            confirm_true_solve(self.spec, self.curve, lambda s: self._episodes(s).true_returns)
        )
        (Path(self.spec.run_dir) / "curve.json").write_text(json.dumps(self.curve))

    def _episodes(self, seeds: list[int]) -> Any:
        """Returns and true returns of the trainer's current policy, one deterministic episode per seed."""
        from hrtc.episodes import evaluate_episodes

        t = self.trainer
        return evaluate_episodes(t.policy, t.normalizer, t.eval_env, seeds, t.cfg.dist)

    def close(self) -> None:
        pass


def trainer_overrides(spec: RunSpec) -> list[str]:
    """The Hydra overrides that make ``spec`` a :class:`~hrtc.trainer.RunConfig` (what ``scripts/train.py`` takes)."""
    algo, dist, learner = ALGORITHMS[spec.builtin][1]
    overrides = [
        f"task={spec.task}", f"algo={algo}", f"dist={dist}", f"learner={learner}", f"seed={spec.seed}",
        f"steps={spec.steps}",
        f"eval_every={spec.eval_every}", f"eval_episodes={spec.eval_episodes}", "progress=false",
        # One core: the envs step in this process. With more, each env (and its skills) gets its own process.
        f"vector={'async' if spec.cpus > 1 else 'sync'}", f"torch_threads={max(1, spec.cpus // 2)}",
        f"checkpoint_every={spec.eval_every}",  # a killed run resumes from its last evaluation
    ]  # fmt: skip
    root = root_config()
    if "logger" in root:
        overrides.append("logger.mode=off")  # a Rerun recording with camera frames would cost more than the run
    if algo == "ppo" and spec.root_ppo:
        # A task's PPO block is tuned for HRTC; PPO on raw actions runs with the root config's settings.
        overrides += [f"ppo.{key}={_hydra_value(value)}" for key, value in root["ppo"].items()]
    if spec.metric == "episodes":  # every finished episode logged by the env itself (carracing's episode_log)
        overrides.append(f"++task.env_kwargs.episode_log={Path(spec.run_dir).resolve() / 'episodes.csv'}")
    return [*overrides, *spec.overrides]


def root_config() -> dict[str, Any]:
    """The root config (``hrtc/conf/config.yaml``) as written, before any task overrides it."""
    from omegaconf import OmegaConf

    text = (resources.files("hrtc.conf") / "config.yaml").read_text()
    return dict(OmegaConf.to_container(OmegaConf.create(text)))  # type: ignore[arg-type]


def _hydra_value(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def _trainer_run(spec: RunSpec) -> dict[str, Any]:
    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    from hrtc.config import RunConfig
    from hrtc.trainer import Trainer

    GlobalHydra.instance().clear()
    with initialize_config_module("hrtc.conf", version_base=None):
        cfg = compose("config", overrides=trainer_overrides(spec))
    GlobalHydra.instance().clear()
    run_cfg = RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))  # type: ignore[arg-type]
    (Path(spec.run_dir) / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    last = Path(spec.run_dir) / "checkpoints" / "last.pt"
    resume = last.exists()
    if not resume:
        (Path(spec.run_dir) / "episodes.csv").unlink(missing_ok=True)
    collector = _EvalCollector(spec)
    trainer = Trainer(run_cfg, spec.run_dir, sinks=[collector], resume=resume)
    collector.trainer = trainer
    wall_before = trainer.wall_offset  # the seconds earlier sittings trained (0 for a fresh run)
    if resume:  # the episodes that finished after the checkpoint are trained again
        keep_logged_episodes(Path(spec.run_dir) / "episodes.csv", last.stat().st_mtime, trainer.episodes, spec.seed)
        collector.restore(trainer.global_step, wall_before)
    started = time.time() - wall_before  # the run's wall time includes its earlier sittings
    try:
        trainer.train()
    except KeyboardInterrupt:
        if collector.deadline is None or time.perf_counter() < collector.deadline:
            raise  # a real Ctrl-C; a spent wall-time budget ends the run as finished
    from hrtc.benchmark import metrics

    best = Path(spec.run_dir) / "checkpoints" / "best.pt"
    out: dict[str, Any] = {"curve": collector.curve, "train_sps": _median(collector.sps), "wall_before": wall_before}
    out["final_returns"] = collector._episodes(final_seeds(spec)).returns.tolist() if spec.final_episodes else []
    if spec.final_best and spec.final_episodes:
        out["best_returns"] = metrics.checkpoint_returns(best, final_seeds(spec)).tolist()
    if spec.export:
        Path(spec.export).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(best, spec.export)
    return {**out, **metrics.after_training(spec, started)}


def keep_logged_episodes(path: Path, wall_time: float, train_episodes: int, seed: int) -> None:
    """Trim an episode log (``wall_time, pid, reset_seed, ...`` per line) to what a checkpoint holds: its first
    ``train_episodes`` training episodes and the evaluation episodes (reset seeds of :func:`hrtc.episodes.eval_seeds`
    of run seed ``seed``) that ended by ``wall_time``. An interrupted PPO run's checkpoint is rewound to its last
    update: the episodes of the rollout it redoes are logged again on resume."""
    from hrtc.episodes import eval_seeds

    if not path.exists():
        return
    evaluation = {str(s) for s in eval_seeds(seed, 10_000)}
    rows = sorted((float(line.split(",", 3)[0]), line) for line in path.read_text().splitlines(keepends=True)
                  if line.strip())  # fmt: skip
    kept, trained = [], 0
    for end, line in rows:
        if line.split(",", 3)[2] in evaluation:
            if end <= wall_time:
                kept.append(line)
        elif trained < train_episodes:
            kept.append(line)
            trained += 1
    path.write_text("".join(kept))


def _median(values: list[float]) -> float | None:
    finite = [v for v in values if np.isfinite(v)]
    return float(np.median(finite)) if finite else None


def final_seeds(spec: RunSpec) -> list[int]:
    """The final evaluation's episode seeds: ``final_episodes`` of :func:`episode_seeds` for the run's seed."""
    return episode_seeds(spec.final_seed_base, spec.seed, spec.final_episodes)


def confirm_solve(spec: RunSpec, curve: Mapping[str, list[Any]], returns_of: Any) -> float | None:
    """The solve rule's mean over ``spec.solve_episodes`` episodes for the evaluation just appended to ``curve``:
    the evaluation's own mean when it already has that many episodes; computed (the remaining seeds) when it passes
    the screen and no earlier evaluation confirmed; else None."""
    if not spec.confirms:
        return curve["episode_reward"][-1]
    return _screened_mean(spec, curve["episode_reward"][-1], curve["solve_reward"], spec.solve_episodes, returns_of)


def confirm_true_solve(spec: RunSpec, curve: Mapping[str, list[Any]], true_returns_of: Any) -> float | None:
    """Rule (c) for the evaluation just appended to ``curve``: the mean true return over ``spec.true_solve_episodes``
    tracks (its own ``eval_episodes`` and the rest, run now by ``true_returns_of(seeds)``) when its true mean reaches
    ``spec.solve_threshold`` and no earlier evaluation confirmed; else None. A screen that fails on all the tracks is
    kept too (below the threshold), so the report can say so."""
    if spec.solve_threshold is None or spec.true_solve_episodes <= spec.eval_episodes:
        return None
    screen = curve["true_reward"][-1]
    return _screened_mean(spec, screen, curve["true_solve_reward"], spec.true_solve_episodes, true_returns_of)


def _screened_mean(spec: RunSpec, screen: float | None, confirmed: list[Any], total: int,
                   returns_of: Any) -> float | None:  # fmt: skip
    """The mean over ``total`` episodes of an evaluation whose ``screen`` (its own ``eval_episodes``' mean) reaches
    the threshold, the other episodes run now by ``returns_of(seeds)``; None when it does not, or when an earlier
    evaluation already ``confirmed`` (solved already: later evaluations only watch for a collapse)."""
    from hrtc.episodes import eval_seeds

    threshold = spec.solve_threshold
    if any(v is not None and v >= threshold for v in confirmed) or screen is None or screen < threshold:  # type: ignore[operator]
        return None
    extra = returns_of(eval_seeds(spec.seed, total)[spec.eval_episodes :])
    return float((screen * spec.eval_episodes + np.sum(extra)) / total)


# --------------------------------------------------------------------------------------------------- stable-baselines3
class EpisodeCounter(gym.Wrapper):
    """Counts finished training episodes (terminated or truncated), for the episodes axis of the curves."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.episodes = 0

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.episodes += int(terminated or truncated)
        return obs, reward, terminated, truncated, info


def sb3_model(name: str, env: gym.Env, seed: int, overrides: tuple[str, ...] = ()) -> Any:
    """A stable-baselines3 model for benchmark algorithm ``name`` (``sb3_ppo``...) with the settings of SETTINGS;
    ``overrides`` (``key=value``, dotted keys for nested ones: ``policy_kwargs.net_arch=[256,256]``) replace them."""
    import stable_baselines3 as sb3
    from omegaconf import OmegaConf
    from stable_baselines3.common.noise import NormalActionNoise

    cls_name = ALGORITHMS[name][1][0]
    kwargs: dict[str, Any] = {}
    if cls_name in ("SAC", "TD3"):
        # SB3's off-policy default is 256x256 (2-5x slower here); the paper sizes every network like the PPO ones.
        kwargs["policy_kwargs"] = {"net_arch": [64, 64]}
    if cls_name == "TD3":
        # SB3's TD3 has no exploration noise by default; 0.1 of the action range is the TD3 paper's setting.
        dim = int(np.prod(env.action_space.shape))
        half_range = (env.action_space.high - env.action_space.low) / 2
        kwargs["action_noise"] = NormalActionNoise(np.zeros(dim), 0.1 * half_range)
    if overrides:
        given = OmegaConf.to_container(OmegaConf.from_dotlist(list(overrides)))
        kwargs = {
            **kwargs,
            **given,
            "policy_kwargs": {**kwargs.get("policy_kwargs", {}), **given.get("policy_kwargs", {})},
        }  # type: ignore[union-attr]
    return getattr(sb3, cls_name)("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)


def sb3_evaluate(model: Any, env: gym.Env, seeds: list[int]) -> np.ndarray:
    """Returns of one deterministic episode per seed (:func:`sb3_episodes`)."""
    return sb3_episodes(model, env, seeds).returns


def sb3_episodes(model: Any, env: gym.Env, seeds: list[int]) -> Any:
    """Returns and true returns of one deterministic episode per seed (the one episode loop:
    :func:`hrtc.episodes.play_episodes`)."""
    from hrtc.episodes import Decision, play_episodes

    def decide(obs: np.ndarray) -> Decision:
        action, _ = model.predict(obs, deterministic=True)
        return Decision(obs, action, action)

    return play_episodes(env, decide, seeds)


def sb3_train(spec: RunSpec, task: Mapping[str, Any] | None = None, decision_every: int = 1,
              weight_margin: float = 0.0) -> dict[str, Any]:  # fmt: skip
    """Train stable-baselines3 algorithm ``spec.algo`` on ``spec.task`` (``task``: its config block, for the
    env_kwargs and, for a composed algorithm, the skills acting every ``decision_every`` env steps, the weights
    spanning ``weight_margin`` beyond [0, 1]); returns its evaluation curve (CURVE_KEYS), the final evaluation's
    returns (and the best evaluated model's, kept as ``best.zip``, with ``spec.final_best``) and its training env
    steps/s.

    ``learn`` runs in chunks of ``eval_every`` env steps; on-policy algorithms finish their last rollout, so an
    evaluation may come a little after the chunk's end (SB3 PPO: the next multiple of 2,048)."""
    import torch

    import envs
    from hrtc.environments import make_env
    from hrtc.episodes import eval_seeds

    task = dict(task or {})
    torch.set_num_threads(spec.cpus)
    Path(spec.run_dir).mkdir(parents=True, exist_ok=True)
    composed = ALGORITHMS[spec.builtin][1][1] == "composed"
    per_action = decision_every if composed else 1  # env steps per agent step

    def build() -> gym.Env:
        if composed:
            return make_env(spec.task, "hrtc", task["skills"], env_kwargs=task.get("env_kwargs"),
                            decision_every=decision_every, weight_margin=weight_margin)  # fmt: skip
        return envs.make(spec.task, **dict(task.get("env_kwargs") or {}))

    env, eval_env = EpisodeCounter(build()), build()
    model = sb3_model(spec.builtin, env, spec.seed, spec.overrides)
    best_path = Path(spec.run_dir) / "best.zip"
    seeds = eval_seeds(spec.seed, spec.eval_episodes)
    curve: dict[str, list[Any]] = {k: [] for k in (*CURVE_KEYS, "train_seconds")}
    tic, train_seconds = time.perf_counter(), 0.0

    def record() -> None:
        returns, true_returns = sb3_episodes(model, eval_env, seeds)
        curve["true_reward"].append(float(true_returns.mean()))
        curve["step"].append(int(model.num_timesteps) * per_action)
        curve["episode_reward"].append(float(returns.mean()))
        curve["episode_reward_std"].append(float(returns.std()))
        curve["episodes"].append(env.episodes)
        curve["wall_seconds"].append(time.perf_counter() - tic)
        curve["train_seconds"].append(train_seconds)  # in learn() only: the training throughput
        curve["solve_reward"].append(confirm_solve(spec, curve, lambda rest: sb3_evaluate(model, eval_env, rest)))
        curve["true_solve_reward"].append(
            confirm_true_solve(spec, curve, lambda rest: sb3_episodes(model, eval_env, rest).true_returns)
        )
        _write_csv(Path(spec.run_dir) / "eval.csv", curve)  # a run's progress, as the trainer's eval.csv shows it
        if spec.final_best and curve["episode_reward"][-1] >= max(curve["episode_reward"]):
            model.save(best_path)

    record()
    while model.num_timesteps * per_action < spec.steps:
        t0 = time.perf_counter()
        remaining = spec.steps - model.num_timesteps * per_action
        model.learn(-(-min(spec.eval_every, remaining) // per_action), reset_num_timesteps=False)
        train_seconds += time.perf_counter() - t0
        record()
    out: dict[str, Any] = {"curve": curve, "train_sps": curve["step"][-1] / max(train_seconds, 1e-9)}
    out["final_returns"] = sb3_evaluate(model, eval_env, final_seeds(spec)).tolist() if spec.final_episodes else []
    if spec.final_best and spec.final_episodes:
        best = type(model).load(best_path, device="cpu")
        out["best_returns"] = sb3_evaluate(best, eval_env, final_seeds(spec)).tolist()
    env.close()
    eval_env.close()
    return out


def _write_csv(path: Path, curve: Mapping[str, list[Any]]) -> None:
    keys = list(curve)
    rows = zip(*(curve[k] for k in keys), strict=True)
    lines = [",".join(keys), *(",".join("" if v is None else str(v) for v in row) for row in rows)]
    path.write_text("\n".join(lines) + "\n")


def _sb3_run(spec: RunSpec) -> dict[str, Any]:
    from hrtc.cli import task_config

    task = task_config(spec.task)
    algo = composition_settings(spec.task)
    return sb3_train(spec, task, int(algo["decision_every"]), float(algo.get("weight_margin", 0.0)))


def composition_settings(task: str) -> dict[str, Any]:
    """The composition's settings (the ``algo`` block: decision rate, weight margin, action filter) of
    ``task=<task>`` as train.py composes it."""
    from omegaconf import OmegaConf

    from hrtc.cli import compose

    return dict(OmegaConf.to_container(compose([f"task={task}"]).algo, resolve=True))  # type: ignore[arg-type]


def decision_every(task: str) -> int:
    """The meta-policy's decision rate (env steps per decision) of ``task=<task>`` as train.py composes it."""
    return int(composition_settings(task)["decision_every"])


def last_eval_step(run_dir: Path) -> int:
    """The step of a training run's last evaluation row, -1 if it has none yet (a benchmark's skip-if-done test)."""
    import pandas as pd

    try:
        return int(pd.read_csv(Path(run_dir) / "eval.csv")["step"].iloc[-1])
    except (OSError, IndexError, KeyError, ValueError, pd.errors.EmptyDataError):  # missing, empty or cut short
        return -1
