"""Evaluate a saved policy (HRTC or PPO) with the distribution's mean, and record the episodes.

    python scripts/eval.py checkpoint=<path> [episodes=10] [seed=1] [out=DIR] [logger=save|off|spawn]
        [frames=true] [frame_every=5] [frame_episodes=1] [task=<task>] [env_kwargs.<key>=value ...]

Episode seeds are the trainer's evaluation seeds for ``seed`` (1_000_000 + 1000 seed + k): with the training run's
seed the first episodes are the ones its evaluations used. Writes DIR/recording.rrd (default: <run dir>/eval/<name>)
and prints the returns, each skill's mean weight and dominant share, and the skills' solver statistics.

Changed physics: ``task=`` evaluates on another registered task with the same observation and action sizes (e.g.
``cartpole_swingup_heavy``; the skills stay as trained); ``env_kwargs.<key>=value`` (or ``env_kwargs={key: value}``)
sets the task's keyword arguments over the checkpoint's own (another task: over its config's), e.g.
``task=cartpole_swingup_heavy env_kwargs.pole_mass_scale=1.5`` or ``env_kwargs.pole_length_scale=1.25``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, NamedTuple

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc import cli  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

DEFAULTS = {"checkpoint": None, "episodes": 10, "seed": 1, "out": None, "logger": "save", "frames": True,
            "frame_every": 5, "frame_episodes": 1, "task": None, "env_kwargs": {}}  # fmt: skip
CHECKS = {
    "checkpoint": cli.required(cli.input_file, "path, e.g. runs/.../checkpoints/best.pt"),
    "episodes": cli.integer(1, 100_000),
    "seed": cli.integer(0, 4_000_000),  # evaluation seeds 1e6 + 1000 seed + k stay below 2**32
    "out": cli.optional(cli.output_path(directory=True)),
    "logger": cli.one_of("save", "off", "spawn"),
    "frame_every": cli.integer(1),
    "frame_episodes": cli.integer(0),
    "task": cli.optional(cli.registered_task),
    "env_kwargs": cli.mapping,
}


def main(argv: list[str]) -> None:
    opts = cli.parse_options(argv, DEFAULTS, __doc__ or "", CHECKS)
    try:
        setup = prepare(opts)
    except HRTCError as error:
        cli.fail(str(error))
    try:
        summary = run(opts, setup)
    except HRTCError as error:
        cli.fail(str(error), status=1)
    print(summary)


class Setup(NamedTuple):
    """What :func:`prepare` checked and built: the policy, the env it acts in (``task`` with ``env_kwargs``) and the
    output directory."""

    policy: Any
    normalizer: Any
    meta: dict
    env: Any
    task: str
    env_kwargs: dict
    out: Path


def prepare(opts: dict) -> Setup:
    """Everything that can refuse the input, before anything is written: the checkpoint, the task it is evaluated on
    (built, reset, and its sizes checked against the policy's), the output directory."""
    from hrtc.checkpoint import load_policy
    from hrtc.cli import build_env, check_checkpoint_fits, output_path, task_config
    from hrtc.environments import evaluation_env_kwargs
    from hrtc.episodes import eval_seeds

    path = Path(opts["checkpoint"])
    policy, normalizer, meta = load_policy(path)
    if "skills_cfg" not in meta:
        raise HRTCError(f"{path} predates checkpoints that describe their task's skills; re-save it with this version")
    task = opts["task"] or str(meta["task"])
    if task == meta["task"]:
        base = evaluation_env_kwargs(meta["env_kwargs"])  # never the training run's episode log
    else:
        base = dict(task_config(task).get("env_kwargs") or {}) if task in cli.group_choices("task") else {}
    env_kwargs = {**base, **opts["env_kwargs"]}
    try:
        env = build_env(task, meta["algo"], meta["skills_cfg"], meta["action_filter"], env_kwargs,
                        int(meta["decision_every"]), eval_seeds(opts["seed"], 1)[0],
                        weight_margin=float(meta.get("weight_margin", 0.0)))  # fmt: skip
    except HRTCError as error:
        raise HRTCError(f"cannot evaluate {path} on task {task!r}: {error}") from None
    try:
        check_checkpoint_fits(meta, env, path)
        if opts["out"]:
            out = opts["out"]
        else:
            run_dir = path.parent.parent if path.parent.name == "checkpoints" else path.parent
            changed = [task] if task != meta["task"] else []
            changed += [f"{k}{v}" for k, v in sorted(opts["env_kwargs"].items())]
            out = output_path(directory=True)("out", run_dir / "eval" / "-".join([path.stem, f"seed{opts['seed']}",
                                                                                    *changed]))  # fmt: skip
    except BaseException:
        env.close()
        raise
    return Setup(policy, normalizer, meta, env, task, env_kwargs, out)


def run(opts: dict, setup: Setup) -> str:
    import numpy as np

    from hrtc.environments import frame_source
    from hrtc.episodes import eval_seeds, evaluate_episodes
    from hrtc.logging.trace import (
        RecordingConfig,
        TraceCollector,
        format_returns,
        format_skill_statistics,
        skill_statistics,
        weight_summary,
    )

    policy, normalizer, meta, env, task, env_kwargs, out = setup
    path = Path(opts["checkpoint"])
    episodes, seed = int(opts["episodes"]), int(opts["seed"])
    names = tuple(meta["skills"]) or tuple(f"a{i}" for i in range(int(meta["out_dim"])))
    recorder, render = None, None
    if opts["logger"] != "off":
        from hrtc.cli import group_choices, task_config
        from hrtc.logging.rerun_sink import RerunSink

        task_cfg = task_config(task) if task in group_choices("task") else {}  # the task evaluated on
        cfg = RecordingConfig(mode=str(opts["logger"]), frames=bool(opts["frames"]),
                              frame_every=int(opts["frame_every"]), frame_episodes=int(opts["frame_episodes"]),
                              frame_evals_every=1, action_names=tuple(task_cfg.get("action_names") or ()),
                              key_state=task_cfg.get("key_state"))  # fmt: skip
        title = f"{task}: {meta['algo']}-{meta['dist']} from {path}"
        recorder = RerunSink.for_env(out, cfg, env, title, eval_episodes=episodes)
        recorder.start_evaluation(int(meta.get("global_step", 0)), last=True)
        render = frame_source(env, cfg.frame_size) if cfg.frames else None
    collector = TraceCollector(recorder)
    try:
        returns, true_returns = evaluate_episodes(policy, normalizer, env, eval_seeds(seed, episodes), meta["dist"],
                                                  collector, render)  # fmt: skip
    finally:
        env.close()
        if recorder is not None:
            recorder.close()
    physics = f" with env_kwargs {env_kwargs}" if env_kwargs else ""
    lines = [f"{path}: {meta['algo']}-{meta['dist']} (trained on {meta['task']}) on {task}{physics}",
             format_returns(returns),
             "per episode: " + " ".join(f"{r:.1f}" for r in returns)]  # fmt: skip
    if not np.allclose(true_returns, returns):  # a task that shapes its reward: its own return too
        lines += [f"the task's own return: {format_returns(true_returns)}",
                  "per episode: " + " ".join(f"{r:.1f}" for r in true_returns)]  # fmt: skip
    if meta["algo"] == "hrtc":
        weights = np.concatenate([np.asarray(t.weights) for t in collector.traces])
        alpha = np.concatenate([np.asarray(t.alpha) for t in collector.traces]) if collector.traces[0].alpha else None
        beta = np.concatenate([np.asarray(t.beta) for t in collector.traces]) if alpha is not None else None
        lines.append("skill      mean weight  dominant  mean a+b")
        for name, s in weight_summary(weights, alpha, beta, names).items():
            lines.append(f"{name:<10} {s['mean_weight']:>11.2f}  {s['dominant_share']:>8.0%}  "
                         f"{s['mean_alpha_plus_beta']:>8.1f}")  # fmt: skip
        lines.extend(format_skill_statistics(skill_statistics(collector.traces)))
    if recorder is not None:
        lines.append(f"recording: {recorder.path}")
    return "\n".join(lines)


if __name__ == "__main__":
    main(sys.argv[1:])
