"""``scripts/benchmark.py``: one task's benchmark, every (algorithm, seed), run locally or on a Ray cluster.

    python scripts/benchmark.py benchmark=<name> [key=value ...]
    python scripts/benchmark.py task=cartpole_swingup [algos=[hrtc_beta,ppo_beta,sb3_sac,...]] [seeds=5|[1,2,3]]
        [budget=50000] [budgets.sb3_sac=N] [eval_every=N] [eval_episodes=N] [threshold=X] [solve_episodes=N]
        [collapse_window=3] [final_episodes=10] [ray_address=ADDRESS] [backend=auto|ray|process] [cpus=N]
        [cpus_per_run=1] [out=DIR] [runs_dir=DIR] [report_only=true] [progress=true]

``benchmark=<name>`` reads a benchmark config, ``hrtc/conf/benchmark/<name>.yaml``: any of the keys below (the
committed studies: the task, the algorithms and their variants, seeds, budgets, the evaluation protocol, extra
reference rules, the metric plug-in, notes), under the command line's ``key=value`` arguments.

Writes into ``out`` (default ``benchmarks/results/<task>/<benchmark name, else table1>``): results.json (every run's
raw evaluation curve, rewritten after each finished run; runs already in it are skipped, so a killed benchmark
continues), table.md, curves.png, summary.json, command.txt, machine.txt. Training files of each run go to
``runs_dir`` (not committed); a trainer run killed midway resumes there from its last evaluation's checkpoint, so
long studies can be spread over several sittings. Several invocations with disjoint ``seeds`` may share one ``out``;
``report_only=true`` with all the seeds then writes the table of them all and prunes runs of other settings from
results.json.
"""

from __future__ import annotations

import json
import sys
from importlib import resources
from pathlib import Path
from typing import Any

from hrtc import cli
from hrtc.cli import fail
from hrtc.errors import ConfigError

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
    "true_solve_episodes": 0,  # rule (c) on a shaping task: a true-return screen confirmed over this many episodes
    "collapse_window": 3,
    "final_episodes": 10,  # episodes of a last evaluation of each run's final policy
    "final_seed_base": None,  # their seeds: base + 1000 seed + k (None: the evaluation seeds)
    "final_best": False,  # evaluate the best evaluated policy on the same episodes too
    "references": True,  # evaluate each skill alone, the untrained blend and the task's declared rules too
    "rules": {},  # more reference rules than the task declares (the same form as task.references)
    "reference_episodes": None,  # default: final_episodes (10 if 0)
    "reference_seed": 1,  # the references' episodes: those of this run seed (final_seed_base's scheme), or "runs":
    # those of every run seed, the episodes the final policies are measured on (where episodes differ a lot)
    "variants": {},  # name: {base: <algorithm>, task, overrides: [...], root_ppo, seeds, budget, export}
    "metric": "returns",  # a plug-in of hrtc.benchmark.metrics, or {name: <plug-in>, <its arguments>}
    "wall_minutes": None,  # stop each run's training after so many minutes (the runs side by side: cpus)
    "thresholds": [],  # more thresholds to report steps-to-threshold for (beside the solve rule's)
    "compare": [],  # [a, b] pairs: the ratio of their median steps to each threshold (transfer, reuse)
    "trace": None,  # an algorithm whose best run's skill tree is traced over one evaluation episode
    "notes": [],  # lines for table.md
    "ray_address": None,
    "backend": "auto",
    "cpus": None,  # CPUs of the local Ray or process pool (default: all of this machine's)
    "cpus_per_run": 1,
    "out": None,
    "runs_dir": None,
    "report_only": False,
    "progress": True,
    "benchmark": None,  # a benchmark config, hrtc/conf/benchmark/<name>.yaml, read under the other arguments
}
VARIANT_KEYS = ("base", "task", "overrides", "root_ppo", "seeds", "budget", "export")


def benchmark_names() -> list[str]:
    return cli.group_choices("benchmark")


def parse(argv: list[str]) -> dict[str, Any]:
    """``key=value`` arguments (YAML values: lists as ``[a,b]``, dotted keys for ``budgets.<algo>``) over the
    benchmark config ``benchmark=<name>`` names, over :data:`DEFAULTS`."""
    import yaml
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    bad = [a for a in argv if "=" not in a]
    if bad:
        fail(f"arguments look like key=value, got {bad[0]!r}; keys: {', '.join(DEFAULTS)}")
    try:
        given = OmegaConf.from_dotlist(argv)
    except (OmegaConfBaseException, yaml.YAMLError) as error:
        fail(f"malformed argument: {str(error).splitlines()[0]}")
    unknown = sorted(set(given) - set(DEFAULTS))  # type: ignore[arg-type]
    if unknown:
        fail(f"unknown key {unknown[0]!r}; keys: {', '.join(DEFAULTS)}")
    name = given.get("benchmark")
    if name is None:
        return {**DEFAULTS, **OmegaConf.to_container(given)}  # type: ignore[dict-item]
    if name not in benchmark_names():
        fail(f"unknown benchmark {name!r}; valid benchmarks: {', '.join(benchmark_names())}")
    text = (resources.files(cli.CONFIG_MODULE) / "benchmark" / f"{name}.yaml").read_text()
    try:
        study = OmegaConf.create(text)
        unknown = sorted(set(study) - set(DEFAULTS))  # type: ignore[arg-type]
        if unknown:
            fail(f"benchmark {name}: unknown key {unknown[0]!r}; keys: {', '.join(DEFAULTS)}")
        merged = OmegaConf.to_container(OmegaConf.merge(study, given), resolve=True)
    except (OmegaConfBaseException, yaml.YAMLError) as error:
        fail(f"benchmark {name}: {str(error).splitlines()[0]}")
    return {**DEFAULTS, **merged}  # type: ignore[dict-item]


def check(args: dict[str, Any]) -> dict[str, Any]:
    """Every argument's type and range (one ``error:`` line for the first problem), before anything is written."""
    from hrtc.benchmark.dispatch import BACKENDS, resolve_backend
    from hrtc.benchmark.metrics import METRIC_ARGS, METRICS
    from hrtc.benchmark.runs import ALGORITHMS

    tasks = cli.one_of(*cli.group_choices("task"))

    def seeds(name: str, value: Any) -> list[int]:
        if not isinstance(value, list):
            return list(range(1, cli.integer(1, 1000)(f"{name} (a count)", value) + 1))
        value = [cli.integer(0, 999)(f"every entry of {name}", seed) for seed in value]
        if not value or len(set(value)) != len(value):
            raise ConfigError(f"{name} must be a count or a list of distinct seeds, got {value}")
        return value

    def text(name: str, value: Any) -> str:
        if not isinstance(value, str):
            raise ConfigError(f"{name} must be text, got {value!r}")
        return value

    def texts(name: str, value: Any) -> list[str]:
        if not isinstance(value, list):
            raise ConfigError(f"{name} must be a list, got {value!r}")
        return [text(f"every entry of {name}", v) for v in value]

    def variants(name: str, value: Any) -> dict[str, dict[str, Any]]:
        out = {}
        for key, spec in cli.mapping(name, value).items():
            where = f"{name}.{key}"
            spec = dict(cli.mapping(where, spec))
            unknown = sorted(set(spec) - set(VARIANT_KEYS))
            if unknown:
                raise ConfigError(f"unknown key {unknown[0]!r} in {where}; keys: {', '.join(VARIANT_KEYS)}")
            spec["base"] = cli.one_of(*ALGORITHMS)(f"{where}.base", spec.get("base", key))
            checks = {"task": cli.optional(tasks), "overrides": texts, "root_ppo": cli.boolean,
                      "seeds": cli.optional(seeds), "budget": cli.optional(cli.integer(1)),
                      "export": cli.optional(text)}  # fmt: skip
            spec.setdefault("overrides", [])
            spec.setdefault("root_ppo", True)
            for k, check_one in checks.items():
                spec[k] = check_one(f"{where}.{k}", spec.get(k))
            out[key] = spec
        return out

    args["variants"] = cli.validate({"variants": args["variants"]}, {"variants": variants})["variants"]
    valid = [*ALGORITHMS, *(v for v in args["variants"] if v not in ALGORITHMS)]

    def algos(name: str, value: Any) -> list[str]:
        value = value if isinstance(value, list) else [value]
        for algo in value:
            if algo not in valid:
                raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(valid)}")
        if not value or len(set(value)) != len(value):
            raise ConfigError(f"{name} must list distinct algorithms, got {value}")
        return list(value)

    def budgets(name: str, value: Any) -> dict[str, int]:
        value = cli.mapping(name, value)
        for algo, steps in value.items():
            if algo not in valid:
                raise ConfigError(f"unknown algorithm {algo!r} in {name}; valid: {', '.join(valid)}")
            cli.integer(1)(f"{name}.{algo}", steps)
        return value

    def metric(name: str, value: Any) -> dict[str, Any]:
        value = {"name": value} if isinstance(value, str) else dict(cli.mapping(name, value))
        kind = cli.one_of(*METRICS)(f"{name}.name", value.pop("name", None))
        unknown = sorted(set(value) - set(METRIC_ARGS[kind]))
        if unknown:
            raise ConfigError(f"unknown key {unknown[0]!r} in {name}; the {kind} metric takes: "
                              f"{', '.join(METRIC_ARGS[kind]) or 'nothing'}")  # fmt: skip
        return {"name": kind, **value}

    def pairs(name: str, value: Any) -> list[list[str]]:
        if not isinstance(value, list) or any(not isinstance(p, list) or len(p) != 2 for p in value):
            raise ConfigError(f"{name} must be a list of [a, b] pairs of algorithms, got {value!r}")
        return [algos(f"every pair of {name}", p) for p in value]

    def thresholds(name: str, value: Any) -> list[float]:
        if not isinstance(value, list):
            raise ConfigError(f"{name} must be a list of numbers, got {value!r}")
        return [cli.number()(f"every entry of {name}", v) for v in value]

    checks = {
        "benchmark": cli.optional(text),
        "task": cli.required(tasks, "name, e.g. cartpole_swingup"),
        "algos": algos,
        "seeds": seeds,
        "budget": cli.integer(1),
        "budgets": budgets,
        "eval_every": cli.optional(cli.integer(1)),
        "eval_episodes": cli.optional(cli.integer(1)),
        "threshold": cli.optional(cli.number()),
        "solve_episodes": cli.optional(cli.integer(1)),
        "true_solve_episodes": cli.integer(0),
        "collapse_window": cli.integer(1),
        "final_episodes": cli.integer(0),
        "final_seed_base": cli.optional(cli.integer(0)),
        "final_best": cli.boolean,
        "references": cli.boolean,
        "rules": cli.mapping,
        "reference_episodes": cli.optional(cli.integer(1)),
        "reference_seed": _reference_seed,
        "metric": metric,
        "wall_minutes": cli.optional(cli.number(0.01)),
        "thresholds": thresholds,
        "compare": pairs,
        "trace": cli.optional(lambda name, value: algos(name, [value])[0]),
        "notes": texts,
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
    if args["metric"]["name"] != "returns":
        sb3 = [a for a in args["algos"] if ALGORITHMS[args["variants"].get(a, {}).get("base", a)][0] != "trainer"]
        if sb3:
            fail(f"the {args['metric']['name']} metric measures trainer runs only, not {sb3[0]}")
    try:
        resolve_backend(args["backend"], args["ray_address"])
    except ConfigError as error:
        fail(str(error))
    return args


def specs_of(args: dict[str, Any], threshold: float, solve_episodes: int, episodes: int, eval_every: int,
             runs_dir: Path) -> list[Any]:  # fmt: skip
    """The runs: seed-major (a benchmark stopped early has every algorithm on its first seeds); a variant with its own
    ``seeds`` runs on those of them only."""
    from hrtc.benchmark.runs import RunSpec

    metric = dict(args["metric"])
    kind = metric.pop("name")
    specs = []
    for seed in sorted({s for a in args["algos"] for s in args["variants"].get(a, {}).get("seeds") or args["seeds"]}):
        for algo in args["algos"]:
            variant = args["variants"].get(algo, {})
            if seed not in (variant.get("seeds") or args["seeds"]):
                continue
            export = variant.get("export")
            specs.append(RunSpec(
                variant.get("task") or args["task"], algo, seed,
                int(variant.get("budget") or args["budgets"].get(algo, args["budget"])), eval_every, episodes,
                str((runs_dir / algo / f"seed{seed}").resolve()), int(args["cpus_per_run"]), threshold,
                solve_episodes, int(args["final_episodes"]), base=variant.get("base", ""),
                overrides=tuple(variant.get("overrides") or ()), root_ppo=bool(variant.get("root_ppo", True)),
                final_seed_base=args["final_seed_base"], final_best=bool(args["final_best"]), metric=kind,
                metric_args=metric, export=str(Path(export).resolve()) if export else None,
                wall_minutes=args["wall_minutes"], true_solve_episodes=int(args["true_solve_episodes"]),
            ))  # fmt: skip
    return specs


def main(argv: list[str]) -> int:
    from hrtc.benchmark.dispatch import execute, is_same_run, load_results, save_results
    from hrtc.benchmark.report import SolveRule, machine_info, write_report
    from hrtc.cli import task_config
    from hrtc.errors import HRTCError

    args = check(parse(argv))
    task = task_config(str(args["task"]))
    name = str(task["name"])
    budget = args["budget"]
    eval_every = int(args["eval_every"] or max(1, budget // 10))
    threshold = args["threshold"] if args["threshold"] is not None else task.get("solve_threshold")
    if threshold is None:
        fail(f"task {name!r} declares no solve_threshold: pass threshold=X")
    solve_episodes = int(args["solve_episodes"] or task.get("solve_episodes") or 3)
    episodes = int(args["eval_episodes"] or min(solve_episodes, 10))
    rule = SolveRule(float(threshold), solve_episodes, int(args["collapse_window"]))
    out = Path(args["out"] or Path("benchmarks") / "results" / name / (args["benchmark"] or "table1"))
    runs_dir = Path(args["runs_dir"] or Path("runs") / "benchmark" / (args["benchmark"] or name))
    specs = specs_of(args, float(threshold), solve_episodes, episodes, eval_every, runs_dir)
    budgets = {a: max(s.steps for s in specs if s.algo == a) for a in args["algos"]}
    meta = {"task": name, "budget": budget, "budgets": budgets, "eval_every": eval_every, "eval_episodes": episodes,
            "seeds": sorted({s.seed for s in specs}), "algos": args["algos"], "rule": vars(rule),
            "final_episodes": int(args["final_episodes"]), "expected_runs": len(specs),
            **{k: args[k] for k in ("benchmark", "final_seed_base", "final_best", "metric", "thresholds", "compare",
                                    "trace", "notes", "wall_minutes", "reference_seed")}}  # fmt: skip
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
        try:
            meta["references"] = references(task, args, results_path, meta["seeds"])
        except HRTCError as error:
            fail(str(error))
    elif results_path.exists() and "references" in (kept := json.loads(results_path.read_text())):
        meta["references"] = kept["references"]  # none computed: the stored ones stay in the file and the table
    errors: dict[str, str] = {}
    with (out / "command.txt").open("a") as handle:  # every invocation: a resumed benchmark's runs come from several
        handle.write("python scripts/benchmark.py " + " ".join(argv) + "\n")
    if not args["report_only"]:
        with (out / "machine.txt").open("a") as handle:  # first: a benchmark stopped early still says where it ran;
            handle.write(machine_info())  # appended, like command.txt: the results of a resumed study come from several
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


def _reference_seed(name: str, value: Any) -> int | str:
    if value == "runs" or (isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 999):
        return value
    raise ConfigError(f"{name} must be an integer in [0, 999] or 'runs' (every run seed's episodes), got {value!r}")


def reference_episode_seeds(base: int | None, reference_seed: int | str, run_seeds: list[int],
                            episodes: int) -> list[int]:  # fmt: skip
    """The references' episode seeds: ``episodes`` of run seed ``reference_seed`` (the final policies' scheme,
    :func:`~hrtc.benchmark.runs.episode_seeds`), or with ``"runs"`` those of every run seed, seed after seed."""
    from hrtc.benchmark.runs import episode_seeds

    per_seed = run_seeds if reference_seed == "runs" else [int(reference_seed)]
    return [s for seed in per_seed for s in episode_seeds(base, seed, episodes)]


def references(task: dict, args: dict[str, Any], results_path: Path, run_seeds: list[int]) -> dict[str, Any]:
    """Every reference rule over the task's skills (:mod:`hrtc.references`: each alone, the untrained blend, the
    task's declared rules and the benchmark's ``rules``) measured by the benchmark's metric on the episodes of run
    seed ``reference_seed`` (``"runs"``: those of every seed in ``run_seeds``, one after the other); reused from
    ``results_path`` when it holds them all for as many episodes."""
    from hrtc.benchmark.metrics import evaluate_references
    from hrtc.benchmark.runs import decision_every
    from hrtc.environments import make_env
    from hrtc.references import reference_rules

    metric = dict(args["metric"])
    kind = metric.pop("name")
    episodes = int(args["reference_episodes"] or args["final_episodes"] or 10)
    seeds = reference_episode_seeds(args["final_seed_base"], args["reference_seed"], run_seeds, episodes)
    env = make_env(task["name"], "hrtc", task["skills"], env_kwargs=task.get("env_kwargs"))
    rules = reference_rules(env.skill_names, {**(task.get("references") or {}), **args["rules"]})
    env.close()
    stored = json.loads(results_path.read_text()).get("references", {}) if results_path.exists() else {}
    size = (lambda v: v["summary"]["all"]["targets"]) if kind == "success" else len  # noqa: E731
    wanted = int(metric.get("episodes", 1000)) if kind == "success" else len(seeds)
    if set(rules) <= set(stored) and all(size(stored[k]) == wanted for k in rules):
        return {k: stored[k] for k in rules}
    print(f"references: {len(rules)} rules x {wanted} episodes", file=sys.stderr)
    return evaluate_references(task, rules, seeds, kind, metric, decision_every(task["name"]))


def entry() -> None:
    """The script's body: exit with :func:`main`'s status."""
    raise SystemExit(main(sys.argv[1:]))
