"""The paper's Table 1 and Fig. 2 for one task: every (algorithm, seed), run locally or on a Ray cluster.

    python scripts/benchmark.py task=cartpole_swingup [algos=[hrtc_beta,ppo_beta,sb3_sac,...]] [seeds=5|[1,2,3]]
        [budget=50000] [budgets.sb3_sac=N] [eval_every=N] [eval_episodes=N] [threshold=X] [solve_episodes=N]
        [collapse_window=3]
        [ray_address=ADDRESS] [backend=auto|ray|process] [cpus=N] [cpus_per_run=1]
        [out=DIR] [runs_dir=DIR] [report_only=true] [progress=true]

Writes into ``out`` (default ``benchmarks/results/benchmark_<task>``): results.json (every run's raw evaluation
curve, rewritten after each finished run; runs already in it are skipped, so a killed benchmark continues),
table.md, curves.png, command.txt, machine.txt. Training files of each run go to ``runs_dir`` (not committed).
Several invocations with disjoint ``seeds`` may share one ``out`` (more runs in parallel); ``report_only=true``
with all the seeds then writes the table of them all and prunes runs of other settings from results.json.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a clone without installing

from hrtc import cli  # noqa: E402
from hrtc.cli import fail  # noqa: E402
from hrtc.errors import ConfigError  # noqa: E402

DEFAULTS: dict[str, Any] = {
    "task": None,
    "algos": ["hrtc_beta", "hrtc_normal", "ppo_beta", "ppo_normal", "sb3_ppo", "sb3_sac", "sb3_td3", "sb3_a2c"],
    "seeds": 5,
    "budget": 50_000,  # env steps per run
    "budgets": {},  # per-algorithm budgets, e.g. budgets.sb3_sac=30000
    "eval_every": None,  # default: budget / 10
    "eval_episodes": None,  # episodes of each periodic evaluation (default: solve_episodes, at most 10)
    "threshold": None,  # default: the task's solve_threshold
    "solve_episodes": None,  # episodes the threshold is averaged over (default: the task's solve_episodes, else 3)
    "collapse_window": 3,
    "final_episodes": 10,  # episodes of a last evaluation of each run's final policy
    "references": True,  # evaluate each skill alone, the untrained blend and the task's declared rules too
    "ray_address": None,
    "backend": "auto",
    "cpus": None,  # CPUs of the local Ray or process pool (default: all of this machine's)
    "cpus_per_run": 1,
    "out": None,
    "runs_dir": None,
    "report_only": False,
    "progress": True,
}


def parse(argv: list[str]) -> dict[str, Any]:
    """``key=value`` arguments (YAML values: lists as ``[a,b]``, dotted keys for ``budgets.<algo>``)."""
    import yaml
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    bad = [a for a in argv if "=" not in a]
    if bad:
        fail(f"arguments look like key=value, got {bad[0]!r}; keys: {', '.join(DEFAULTS)}")
    try:
        given = OmegaConf.to_container(OmegaConf.from_dotlist(argv))
    except (OmegaConfBaseException, yaml.YAMLError) as error:
        fail(f"malformed argument: {str(error).splitlines()[0]}")
    unknown = sorted(set(given) - set(DEFAULTS))  # type: ignore[arg-type]
    if unknown:
        fail(f"unknown key {unknown[0]!r}; keys: {', '.join(DEFAULTS)}")
    return {**DEFAULTS, **given}  # type: ignore[dict-item]


def check(args: dict[str, Any]) -> dict[str, Any]:
    """Every argument's type and range (one ``error:`` line for the first problem), before anything is written."""
    from hrtc.benchmark.dispatch import BACKENDS, resolve_backend
    from hrtc.benchmark.runs import ALGORITHMS

    def algos(name: str, value: Any) -> list[str]:
        value = value if isinstance(value, list) else [value]
        for algo in value:
            if algo not in ALGORITHMS:
                raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
        if not value or len(set(value)) != len(value):
            raise ConfigError(f"{name} must list distinct algorithms, got {value}")
        return list(value)

    def seeds(name: str, value: Any) -> list[int]:
        if not isinstance(value, list):
            return list(range(1, cli.integer(1, 1000)(f"{name} (a count)", value) + 1))
        value = [cli.integer(0, 999)(f"every entry of {name}", seed) for seed in value]
        if not value or len(set(value)) != len(value):
            raise ConfigError(f"{name} must be a count or a list of distinct seeds, got {value}")
        return value

    def budgets(name: str, value: Any) -> dict[str, int]:
        value = cli.mapping(name, value)
        for algo, steps in value.items():
            if algo not in ALGORITHMS:
                raise ConfigError(f"unknown algorithm {algo!r} in {name}; valid: {', '.join(ALGORITHMS)}")
            cli.integer(1)(f"{name}.{algo}", steps)
        return value

    def text(name: str, value: Any) -> str:
        if not isinstance(value, str):
            raise ConfigError(f"{name} must be text, got {value!r}")
        return value

    checks = {
        "task": cli.required(cli.one_of(*cli.group_choices("task")), "name, e.g. cartpole_swingup"),
        "algos": algos,
        "seeds": seeds,
        "budget": cli.integer(1),
        "budgets": budgets,
        "eval_every": cli.optional(cli.integer(1)),
        "eval_episodes": cli.optional(cli.integer(1)),
        "threshold": cli.optional(cli.number()),
        "solve_episodes": cli.optional(cli.integer(1)),
        "collapse_window": cli.integer(1),
        "final_episodes": cli.integer(0),
        "references": cli.boolean,
        "ray_address": cli.optional(text),
        "backend": cli.one_of(*BACKENDS),
        "cpus": cli.optional(cli.integer(1)),
        "cpus_per_run": cli.integer(1),
        "out": cli.optional(cli.output_path(directory=True)),
        "runs_dir": cli.optional(cli.output_path(directory=True)),
        "report_only": cli.boolean,
        "progress": cli.boolean,
    }
    args = cli.validate(args, checks)
    try:
        resolve_backend(args["backend"], args["ray_address"])
    except ConfigError as error:
        fail(str(error))
    return args


def main(argv: list[str]) -> int:
    from hrtc.benchmark.dispatch import execute, is_same_run, load_results, save_results
    from hrtc.benchmark.report import SolveRule, machine_info, write_report
    from hrtc.benchmark.runs import RunSpec
    from hrtc.cli import task_config
    from hrtc.errors import HRTCError

    args = check(parse(argv))
    task = task_config(str(args["task"]))
    name = str(task["name"])
    algos, seeds, budget = args["algos"], args["seeds"], args["budget"]
    budgets = {a: int(args["budgets"].get(a, budget)) for a in algos}
    eval_every = int(args["eval_every"] or max(1, budget // 10))
    threshold = args["threshold"] if args["threshold"] is not None else task.get("solve_threshold")
    if threshold is None:
        fail(f"task {name!r} declares no solve_threshold: pass threshold=X")
    solve_episodes = int(args["solve_episodes"] or task.get("solve_episodes") or 3)
    episodes = int(args["eval_episodes"] or min(solve_episodes, 10))
    rule = SolveRule(float(threshold), solve_episodes, int(args["collapse_window"]))
    out = Path(args["out"] or ROOT / "benchmarks" / "results" / f"benchmark_{name}")
    runs_dir = Path(args["runs_dir"] or ROOT / "runs" / "benchmark" / name)
    cpus = int(args["cpus_per_run"])
    specs = [
        RunSpec(
            name,
            algo,
            seed,
            budgets[algo],
            eval_every,
            episodes,
            str(runs_dir / algo / f"seed{seed}"),
            cpus,
            float(threshold),
            solve_episodes,
            int(args["final_episodes"]),
        )  # fmt: skip
        for seed in seeds
        for algo in algos  # seed-major: a benchmark stopped early has every algorithm on its first seeds
    ]
    meta = {"task": name, "budget": budget, "budgets": budgets, "eval_every": eval_every, "eval_episodes": episodes,
            "seeds": seeds, "algos": algos, "rule": vars(rule),
            "final_episodes": int(args["final_episodes"])}  # fmt: skip
    results_path = out / "results.json"
    try:
        stored = load_results(results_path)  # a results.json that cannot be read stops here, before any write
    except (OSError, ValueError, KeyError, TypeError) as error:
        fail(f"cannot read {results_path} ({type(error).__name__}: {error}); move it away to start afresh")
    if args["report_only"]:
        runs = {s.key: stored[s.key] for s in specs if s.key in stored and is_same_run(stored[s.key], s)}
        if not runs:
            fail(f"no finished runs for these settings in {results_path}")
    out.mkdir(parents=True, exist_ok=True)
    if args["references"]:
        meta["references"] = references(task, results_path, int(args["final_episodes"]) or 10)
    errors: dict[str, str] = {}
    with (out / "command.txt").open("a") as handle:  # every invocation: a resumed benchmark's runs come from several
        handle.write("python scripts/benchmark.py " + " ".join(argv) + "\n")
    if not args["report_only"]:
        (out / "machine.txt").write_text(machine_info())  # first: a benchmark stopped early still says where it ran
        try:
            runs, errors = execute(specs, results_path, meta, args["backend"], args["ray_address"], args["cpus"],
                                   bool(args["progress"]))  # fmt: skip
        except HRTCError as error:
            fail(str(error))
    if not runs:
        fail(f"no finished runs for these settings in {results_path}")
    results = {**meta, "runs": runs}
    if args["report_only"]:
        # The file keeps exactly these settings' runs: runs of other settings (another budget...) are dropped.
        save_results(results_path, runs, meta, merge=False)
    print(write_report(results, out, rule))
    missing = [s.key for s in specs if s.key not in runs]
    if missing:
        print(f"missing runs ({len(missing)}): {', '.join(missing)}", file=sys.stderr)
    for key, error in errors.items():
        print(f"failed {key}: {error}", file=sys.stderr)
    return 1 if errors else 0


def references(task: dict, results_path: Path, episodes: int) -> dict[str, list[float]]:
    """Returns of every reference rule over the task's skills (:mod:`hrtc.references`) on ``episodes`` evaluation
    seeds of seed 1, reused from ``results_path`` when it holds them for as many episodes."""
    import json

    from hrtc.benchmark.runs import decision_every
    from hrtc.environments import make_env
    from hrtc.episodes import eval_seeds
    from hrtc.references import evaluate_rules, reference_rules

    stored = json.loads(results_path.read_text()).get("references", {}) if results_path.exists() else {}
    if stored and all(len(v) == episodes for v in stored.values()):
        return stored
    env = make_env(task["name"], "hrtc", task["skills"], env_kwargs=task.get("env_kwargs"),
                   decision_every=decision_every(task["name"]))  # fmt: skip
    rules = reference_rules(env.skill_names, task.get("references"))
    print(f"references: {len(rules)} rules x {episodes} episodes", file=sys.stderr)
    return {k: v.tolist() for k, v in evaluate_rules(env, rules, eval_seeds(1, episodes)).items()}


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
