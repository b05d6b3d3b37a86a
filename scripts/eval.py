"""Evaluate a saved policy (HRTC or PPO) with the distribution's mean, and record the episodes.

    python scripts/eval.py checkpoint=<path> [episodes=10] [seed=1] [out=DIR] [logger=save|off|spawn]
        [frames=true] [frame_every=5] [frame_episodes=1]

Episode seeds are the trainer's evaluation seeds for ``seed`` (1_000_000 + 1000 seed + k): with the training run's
seed the first episodes are the ones its evaluations used. Writes DIR/recording.rrd (default: <run dir>/eval/<name>)
and prints the returns, each skill's mean weight and dominant share, and the skills' solver statistics.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc.cli import fail, parse_options  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

DEFAULTS = {"checkpoint": None, "episodes": 10, "seed": 1, "out": None, "logger": "save", "frames": True,
            "frame_every": 5, "frame_episodes": 1}  # fmt: skip


def main(argv: list[str]) -> None:
    opts = parse_options(argv, DEFAULTS, __doc__ or "")
    if not opts["checkpoint"]:
        fail("checkpoint=<path> is required (e.g. runs/.../checkpoints/best.pt)")
    try:
        summary = run(opts)
    except HRTCError as error:
        fail(str(error))
    print(summary)


def run(opts: dict) -> str:
    import numpy as np

    from hrtc.logging.trace import (
        RecordingConfig,
        TraceCollector,
        format_returns,
        format_skill_statistics,
        skill_statistics,
        weight_summary,
    )
    from hrtc.trainer import eval_seeds, evaluate, frame_source, load_policy, make_env

    path = Path(str(opts["checkpoint"]))
    policy, normalizer, meta = load_policy(path)
    if "skills_cfg" not in meta:
        raise HRTCError(f"{path} predates checkpoints that describe their task's skills; re-save it with this version")
    env = make_env(meta["task"], meta["algo"], meta["skills_cfg"], meta["action_filter"], meta["env_kwargs"],
                   int(meta["decision_every"]))  # fmt: skip
    episodes, seed = int(opts["episodes"]), int(opts["seed"])
    run_dir = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    out = Path(opts["out"]) if opts["out"] else run_dir / "eval" / f"{path.stem}-seed{seed}"
    names = tuple(meta["skills"]) or tuple(f"a{i}" for i in range(int(meta["out_dim"])))
    recorder, render = None, None
    if opts["logger"] != "off":
        from hrtc.cli import group_choices, task_config
        from hrtc.logging.rerun_sink import RerunSink
        from hrtc.tree import describe

        task = task_config(meta["task"]) if meta["task"] in group_choices("task") else {}
        cfg = RecordingConfig(mode=str(opts["logger"]), frames=bool(opts["frames"]),
                              frame_every=int(opts["frame_every"]), frame_episodes=int(opts["frame_episodes"]),
                              frame_evals_every=1, action_names=tuple(task.get("action_names") or ()),
                              key_state=task.get("key_state"))  # fmt: skip
        tree, paths = describe(env, f"{meta['task']}: {meta['algo']}-{meta['dist']} from {path}")
        task_action_dim = int(getattr(env, "action_dim", env.action_space.shape[0]))
        recorder = RerunSink(out, cfg, names, task_action_dim, tree, tree_paths=paths,
                             state_source=env.unwrapped.skill_state, eval_episodes=episodes)  # fmt: skip
        recorder.start_evaluation(int(meta.get("global_step", 0)), last=True)
        render = frame_source(env, cfg.frame_size) if cfg.frames else None
    collector = TraceCollector(recorder)
    try:
        returns = evaluate(policy, normalizer, env, eval_seeds(seed, episodes), meta["dist"], collector, render)
    finally:
        env.close()
        if recorder is not None:
            recorder.close()
    lines = [f"{path}: {meta['algo']}-{meta['dist']} on {meta['task']}",
             format_returns(returns),
             "per episode: " + " ".join(f"{r:.1f}" for r in returns)]  # fmt: skip
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
