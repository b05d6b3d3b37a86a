"""Run one skill of a task alone (weight 1, the others 0), or a fixed blend, and record it.

    python scripts/eval_skill.py task=cartpole_swingup skill=<name>|list [episodes=3] [seed=1]
        [weights=[0.5,0.5,0,0]] [out=DIR] [logger=save|off] [frames=true] [frame_every=5]

``skill=list`` lists the task's skills. ``weights=[...]`` (one per skill, in the task's order) runs a fixed blend
instead of one skill. Prints the returns and, per skill with a non-zero weight, its solver statistics (median and
99th-percentile solve time, failed solves, faults); writes DIR/recording.rrd (default: runs/skills/<task>/<name>).
The skills act at every env step, as in training with the task's rates (``every``).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc import cli  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

DEFAULTS = {"task": None, "skill": None, "episodes": 3, "seed": 1, "weights": None, "out": None, "logger": "save",
            "frames": True, "frame_every": 5}  # fmt: skip
CHECKS = {
    "task": cli.required(cli.one_of(*cli.group_choices("task")), "name, e.g. cartpole_swingup"),
    "episodes": cli.integer(1, 100_000),
    "seed": cli.integer(0, 4_000_000),  # evaluation seeds 1e6 + 1000 seed + k stay below 2**32
    "out": cli.optional(cli.output_path(directory=True)),
    "logger": cli.one_of("save", "off", "spawn"),
    "frame_every": cli.integer(1),
}


def main(argv: list[str]) -> None:
    opts = cli.parse_options(argv, DEFAULTS, __doc__ or "", CHECKS)
    try:
        print(run(opts))
    except HRTCError as error:
        cli.fail(str(error))


def run(opts: dict) -> str:
    import numpy as np

    from hrtc.cli import build_env, numbers, output_path, task_config
    from hrtc.errors import ConfigError, UnknownNameError

    task = task_config(str(opts["task"]))
    skills = task.get("skills") or {}
    names = tuple(skills)
    if not names:
        raise ConfigError(f"task {task['name']!r} declares no skills")
    if opts["skill"] == "list":
        return "\n".join(f"{n:<12} {skills[n]['skill'].get('_target_')}  every={skills[n].get('every', 1)}"
                         for n in names)  # fmt: skip
    if opts["weights"] is not None:
        if opts["skill"] is not None:
            raise ConfigError("give skill=<name> or weights=[...], not both")
        weights = numbers(len(names), 0.0, 1.0)(f"weights (one per skill {list(names)})", opts["weights"])
        label = "blend-" + "-".join(f"{w:g}" for w in weights)
    elif opts["skill"] is None:
        raise ConfigError(f"skill=<name> or weights=[...] is required; the skills are {', '.join(names)}")
    elif opts["skill"] in names:
        weights = np.array([1.0 if n == opts["skill"] else 0.0 for n in names])
        label = str(opts["skill"])
    else:
        raise UnknownNameError("skill", str(opts["skill"]), (*names, "list"))
    episodes, seed = int(opts["episodes"]), int(opts["seed"])
    out = opts["out"] or output_path(directory=True)("out", Path("runs") / "skills" / task["name"] / label)

    from hrtc.environments import frame_source
    from hrtc.episodes import Decision, eval_seeds, run_episodes
    from hrtc.logging.trace import (  # the heavy imports (torch) after the checks: bad input is answered at once
        RecordingConfig,
        TraceCollector,
        format_returns,
        format_skill_statistics,
        skill_statistics,
    )

    env = build_env(task["name"], "hrtc", skills, "sum", task.get("env_kwargs"), 1, eval_seeds(seed, 1)[0])
    recorder, render = None, None
    if opts["logger"] != "off":
        from hrtc.logging.rerun_sink import RerunSink

        cfg = RecordingConfig(
            mode=str(opts["logger"]),
            frames=bool(opts["frames"]),
            frame_every=int(opts["frame_every"]),
            frame_episodes=episodes,
            frame_evals_every=1,
            action_names=tuple(task.get("action_names") or ()),
            key_state=task.get("key_state"),
        )
        recorder = RerunSink.for_env(out, cfg, env, f"{task['name']}: {label}", eval_episodes=episodes)
        recorder.start_evaluation(0, last=True)
        render = frame_source(env, cfg.frame_size) if cfg.frames else None
    collector = TraceCollector(recorder)
    action = weights.astype(np.float32)
    try:
        returns = run_episodes(env, lambda obs: Decision(obs, weights, action), eval_seeds(seed, episodes),
                               collector, render)  # fmt: skip
    finally:
        env.close()
        if recorder is not None:
            recorder.close()
    lines = [f"{task['name']}: {label} (weights {dict(zip(names, weights.round(3).tolist(), strict=True))})",
             format_returns(returns)]  # fmt: skip
    used = [name for name, w in zip(names, weights, strict=True) if w != 0.0]
    lines += format_skill_statistics(skill_statistics(collector.traces), only=used)
    if recorder is not None:
        lines.append(f"recording: {recorder.path}")
    return "\n".join(lines)


if __name__ == "__main__":
    main(sys.argv[1:])
