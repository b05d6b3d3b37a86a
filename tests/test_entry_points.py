"""Every entry point answers bad input as a user meets it: run as a subprocess, each case of a per-script corpus
(types, ranges, shapes, missing and unreadable files, wrong kinds of file) must exit non-zero with exactly one
``error:`` line on stderr, no traceback, and leave the file system as it was (nothing created, nothing changed).

Cases that take seconds (they load a checkpoint or build a task in a fresh interpreter) are marked ``slow`` beyond a
few representatives; ``pytest -m slow tests/test_entry_points.py`` runs them."""

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from hrtc.checkpoint import load_checkpoint, save_checkpoint
from hrtc.config import RunConfig
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
SKILLS = ["swingup", "balance", "tracker", "hold"]
ROOT_USER = os.geteuid() == 0  # root reads a chmod 000 file: that case cannot be made here


# --------------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Real inputs and wrong kinds of input, built once: checkpoints of a real (untrained) HRTC and PPO policy, a
    checkpoint from before ``skills_cfg``, a truncated one, a torch file that is no checkpoint, a text file, a folder,
    a named pipe, a real recording and a truncated one."""
    from hrtc.cli import task_config

    base = tmp_path_factory.mktemp("inputs")
    skills = task_config("cartpole_swingup")["skills"]
    small = dict(task="cartpole_swingup", skills=skills, steps=250, num_envs=1, vector="sync", decision_every=5,
                 progress=False, env_kwargs={"time_limit": 0.5}, ppo=PPOConfig(num_steps=25))  # fmt: skip
    hrtc = Trainer(RunConfig(**small), base / "hrtc").save("best.pt")
    ppo = Trainer(RunConfig(**{**small, "algo": "ppo", "skills": {}}), base / "ppo").save("best.pt")
    state = load_checkpoint(hrtc)
    del state["meta"]["skills_cfg"]
    old = save_checkpoint(base / "old" / "best.pt", {k: v for k, v in state.items() if k != "format"})
    trunc = base / "truncated.pt"
    trunc.write_bytes(hrtc.read_bytes()[: hrtc.stat().st_size // 2])
    foreign = base / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    text = base / "notes.txt"
    text.write_text("not a checkpoint\n")
    unreadable = base / "unreadable.pt"
    shutil.copy(hrtc, unreadable)
    unreadable.chmod(0)
    fifo = base / "pipe"
    os.mkfifo(fifo)
    (base / "folder").mkdir()
    (base / "empty_run").mkdir()
    rec_run = base / "rec_run"
    result = _run("eval.py", [f"checkpoint={hrtc}", "episodes=1", "frames=false", f"out={rec_run}"], base)
    assert result.returncode == 0, result.stderr
    rrd = rec_run / "recording.rrd"
    trunc_rrd = base / "trunc_run" / "recording.rrd"
    trunc_rrd.parent.mkdir()
    trunc_rrd.write_bytes(rrd.read_bytes()[:300])
    bad_results = base / "bad_results"
    bad_results.mkdir()
    (bad_results / "results.json").write_text("{not json")
    return {"hrtc": hrtc, "ppo": ppo, "old": old, "trunc": trunc, "foreign": foreign, "text": text, "fifo": fifo,
            "unreadable": unreadable, "folder": base / "folder", "empty_run": base / "empty_run", "rec_run": rec_run,
            "rrd": rrd, "trunc_rrd": trunc_rrd, "trunc_run": trunc_rrd.parent, "bad_results": bad_results,
            "missing": base / "missing" / "best.pt", "base": base}  # fmt: skip


def _run(script: str, args: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """``scripts/<script> args`` from ``cwd``; the whole process group is killed if it outlives ``timeout`` (a case
    that wrongly passed validation must not go on to train)."""
    cmd = [sys.executable, str(ROOT / "scripts" / script), *args]
    process = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)  # fmt: skip
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, err = process.communicate()
        pytest.fail(f"{script} {' '.join(args)} ran past {timeout} s instead of refusing its input")
    return subprocess.CompletedProcess(cmd, process.returncode, out, err)


def _tree(*roots: Path) -> dict[str, tuple[int, int]]:
    """Every path under ``roots`` with its size and modification time (ns)."""
    out = {}
    for root in roots:
        for path in [root, *root.rglob("*")]:
            stat = path.lstat()
            out[str(path)] = (stat.st_size if path.is_file() else 0, stat.st_mtime_ns)
    return out


def _refused(script: str, args: list[str], expected: str, files: dict[str, Path], tmp_path: Path) -> None:
    args = [a.format(tmp=tmp_path, **files) for a in args]
    before = _tree(tmp_path, files["base"])
    result = _run(script, args, tmp_path)
    after = _tree(tmp_path, files["base"])
    assert result.returncode != 0, result.stdout[-1000:]
    assert "Traceback" not in result.stderr + result.stdout, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert expected in lines[0], lines[0]
    assert after == before, f"changed: {sorted(set(after) ^ set(before)) or 'modification times'}"


SLOW = "slow"  # a third element: the case takes seconds (it loads a checkpoint, builds a task): run with -m slow


def _cases(corpus: list[tuple]) -> list:
    out = []
    for args, expected, *flags in corpus:
        marks = [pytest.mark.slow] if SLOW in flags else []
        if "{unreadable}" in " ".join(args):
            marks.append(pytest.mark.skipif(ROOT_USER, reason="root reads any file"))
        out.append(pytest.param(args, expected, id=" ".join(args) or "(none)", marks=marks))
    return out


# --------------------------------------------------------------------------------------------------- eval.py
EVAL = [
    ([], "checkpoint=<path, e.g. runs/.../checkpoints/best.pt> is required"),
    (["checkpoint="], "checkpoint=<path"),
    (["checkpoint={missing}"], "checkpoint: no such file"),
    (["checkpoint={folder}"], "is not a regular file (a directory)"),
    (["checkpoint={fifo}"], "is not a regular file (a named pipe)"),
    (["checkpoint={unreadable}"], "is not readable"),
    (["checkpoint={text}"], "notes.txt was refused by the safe loader (not plain tensors and containers): Unsupported"),
    (["checkpoint={trunc}"], "truncated.pt is not a readable checkpoint"),
    (["checkpoint={rrd}"], "recording.rrd is not a readable checkpoint", SLOW),
    (["checkpoint={foreign}"], "foreign.pt is not an hrtc checkpoint", SLOW),
    (["checkpoint={old}"], "predates checkpoints that describe their task's skills", SLOW),
    (["checkpoint={hrtc}", "episodes=-1"], "episodes must be an integer in [1, 100000], got -1"),
    (["checkpoint={hrtc}", "episodes=0"], "episodes must be an integer in [1, 100000], got 0"),
    (["checkpoint={hrtc}", "episodes=abc"], "cannot parse episodes='abc' (expected int)"),
    (["checkpoint={hrtc}", "episodes=1.5"], "cannot parse episodes='1.5' (expected int)"),
    (["checkpoint={hrtc}", "seed=-1"], "seed must be an integer in [0, 4000000], got -1"),
    (["checkpoint={hrtc}", "seed=99999999999"], "seed must be an integer in [0, 4000000]"),
    (["checkpoint={hrtc}", "logger=disk"], "unknown logger 'disk'; valid loggers: off, save, spawn"),
    (["checkpoint={hrtc}", "frames=maybe"], "cannot parse frames='maybe' (expected true or false)"),
    (["checkpoint={hrtc}", "frame_every=0"], "frame_every must be an integer >= 1, got 0"),
    (["checkpoint={hrtc}", "frame_episodes=-1"], "frame_episodes must be an integer >= 0, got -1"),
    (["checkpoint={hrtc}", "out={text}"], "notes.txt exists and is a file, not a directory"),
    (["checkpoint={hrtc}", "out={text}/eval"], "notes.txt is a file, not a directory"),
    (
        ["checkpoint={hrtc}", "task=cartpol"],
        "unknown task 'cartpol'; valid tasks: acrobot_swingup, carracing, carracing_paper",
    ),
    (["checkpoint={hrtc}", "task=[cartpole_swingup]"], "unknown task \"['cartpole_swingup']\""),
    (["checkpoint={hrtc}", "task=lunarlander"], "cannot evaluate", SLOW),
    (
        ["checkpoint={ppo}", "task=lunarlander"],
        "was trained with skills [] (obs 5, out 1); this environment has [] (obs 8, out 2)",
    ),
    (
        ["checkpoint={hrtc}", "env_kwargs.pole_mass_scale=1.5"],
        "task 'cartpole_swingup' cannot be built with env_kwargs",
    ),
    (["checkpoint={hrtc}", "env_kwargs={{colour: red}}"], "unexpected keyword argument 'colour'", SLOW),
    (["checkpoint={hrtc}", "env_kwargs=[1,2]"], "env_kwargs must be a mapping like {key: value}, got [1, 2]"),
    (["checkpoint={hrtc}", "env_kwargs={{a: 1"], "cannot parse env_kwargs='{a: 1'"),
    (["checkpoint={hrtc}", "env_kwargs.time_limit=abc"], "cannot be built with env_kwargs", SLOW),
    (
        ["checkpoint={hrtc}", "task=cartpole_swingup_heavy", "env_kwargs.pole_mass_scale=100"],
        "pole_mass_scale must lie in [0.1, 10], got 100",
        SLOW,
    ),
    (["checkpoint={hrtc}", "bogus=1"], "unknown option 'bogus'; valid keys: checkpoint, episodes"),
    (["checkpoint={hrtc}", "episodes"], "malformed argument 'episodes': options look like key=value"),
]


@pytest.mark.parametrize("args,expected", _cases(EVAL))
def test_eval_refuses_bad_input(files, tmp_path, args, expected):
    _refused("eval.py", args, expected, files, tmp_path)


def test_eval_on_changed_physics(files, tmp_path):
    """The corpus' counterpart: a checkpoint evaluated on another task with a changed pole, in one line each."""
    args = [
        f"checkpoint={files['hrtc']}",
        "episodes=1",
        "logger=off",
        "task=cartpole_swingup_heavy",
        "env_kwargs={time_limit: 0.5}",
        "env_kwargs.pole_mass_scale=1.5",
    ]  # a whole mapping, then one entry
    result = _run("eval.py", args, tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    first = result.stdout.splitlines()[0]
    assert "(trained on cartpole_swingup) on cartpole_swingup_heavy" in first
    assert "with env_kwargs {'time_limit': 0.5, 'pole_mass_scale': 1.5}" in first


# --------------------------------------------------------------------------------------------------- eval_skill.py
SKILL = [
    ([], "task=<name, e.g. cartpole_swingup> is required"),
    (
        ["task=cartpol", "skill=hold"],
        "unknown task 'cartpol'; valid tasks: acrobot_swingup, carracing, carracing_paper, cartpole_energy",
    ),
    (["task=cartpole_swingup"], "skill=<name> or weights=[...] is required; the skills are swingup, balance"),
    (["task=cartpole_swingup", "skill=nope"], "unknown skill 'nope'; valid skills: balance, hold, list"),
    (
        ["task=cartpole_swingup", "weights=[a,b,c,d]"],
        "every entry of weights (one per skill ['swingup', 'balance', "
        "'tracker', 'hold']) must be a finite number, got 'a'",
    ),
    (["task=cartpole_swingup", "weights=[1,1]"], "must be 4 numbers like [0.5, 1], got [1, 1]"),
    (["task=cartpole_swingup", "weights=[1,0,0,0,0]"], "must be 4 numbers like [0.5, 1]"),
    (["task=cartpole_swingup", "weights=[0.5,0.5,0,2]"], "must be in [0.0, 1.0], got 2"),
    (["task=cartpole_swingup", "weights=[0,0,0,-1]"], "must be in [0.0, 1.0], got -1"),
    (["task=cartpole_swingup", "weights=[.nan,0,0,0]"], "must be a finite number, got nan"),
    (["task=cartpole_swingup", "weights=[[1],0,0,0]"], "must be a finite number, got [1]"),
    (["task=cartpole_swingup", "weights=0.5"], "must be 4 numbers like [0.5, 1], got 0.5"),
    (["task=cartpole_swingup", "weights={{a: 1}}"], "must be 4 numbers like [0.5, 1], got {'a': 1}"),
    (["task=cartpole_swingup", "weights=[1,0,0"], "cannot parse weights='[1,0,0'"),
    (["task=cartpole_swingup", "skill=hold", "weights=[1,0,0,0]"], "give skill=<name> or weights=[...], not both"),
    (["task=cartpole_swingup", "skill=hold", "episodes=0"], "episodes must be an integer in [1, 100000], got 0"),
    (["task=cartpole_swingup", "skill=hold", "episodes=x"], "cannot parse episodes='x' (expected int)"),
    (["task=cartpole_swingup", "skill=hold", "seed=-1"], "seed must be an integer in [0, 4000000], got -1"),
    (["task=cartpole_swingup", "skill=hold", "logger=disk"], "unknown logger 'disk'"),
    (["task=cartpole_swingup", "skill=hold", "frames=2"], "cannot parse frames='2' (expected true or false)"),
    (["task=cartpole_swingup", "skill=hold", "frame_every=0"], "frame_every must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "skill=hold", "out={text}"], "notes.txt exists and is a file, not a directory"),
    (["task=cartpole_swingup", "skill=hold", "out={text}/x"], "notes.txt is a file, not a directory"),
    (["task=cartpole_swingup", "colour=red"], "unknown option 'colour'; valid keys: task, skill"),
    (["cartpole_swingup"], "malformed argument 'cartpole_swingup': options look like key=value"),
]


@pytest.mark.parametrize("args,expected", _cases(SKILL))
def test_eval_skill_refuses_bad_input(files, tmp_path, args, expected):
    _refused("eval_skill.py", args, expected, files, tmp_path)


# --------------------------------------------------------------------------------------------------- review.py
REVIEW = [
    ([], "the following arguments are required: path"),
    (["{missing}"], "path: no such file"),
    (["{fifo}"], "is not a regular file (a named pipe)"),
    (["{unreadable}"], "is not readable"),
    (["{text}"], "cannot read"),
    (["{hrtc}"], "cannot read"),
    (["{trunc_rrd}"], "cannot read"),
    (["{trunc_run}"], "cannot read"),
    (["{empty_run}"], "no recording*.rrd in"),
    (["{rec_run}", "--panels", "0"], "--panels must be an integer in [1, 100], got 0"),
    (["{rec_run}", "--panels", "x"], "argument --panels: invalid int value: 'x'"),
    (["{rec_run}", "--panels"], "argument --panels: expected one argument"),
    (["{rec_run}", "--out", "{folder}"], "folder exists and is a directory, not a file"),
    (["{rec_run}", "--out", "{tmp}/plot.txt"], "plot.txt must end in .png or .pdf or .svg or .jpg or .jpeg"),
    (["{rec_run}", "--out", "{text}/plot.png"], "notes.txt is a file, not a directory"),
    (["{rec_run}", "--colour", "red"], "unrecognized arguments: --colour red"),
    (["{rec_run}", "{rec_run}"], "unrecognized arguments:"),
]


@pytest.mark.parametrize("args,expected", _cases(REVIEW))
def test_review_refuses_bad_input(files, tmp_path, args, expected):
    _refused("review.py", args, expected, files, tmp_path)


# --------------------------------------------------------------------------------------------------- benchmark.py
# Every case names out= and runs_dir= in its scratch folder (the defaults are in the repository) and backend=process
# (no Ray started should a case wrongly pass).
BENCH = [
    ([], "task=<name, e.g. cartpole_swingup> is required"),
    (["task=cartpol"], "unknown task 'cartpol'; valid tasks: acrobot_swingup, carracing"),
    (["task=cartpole_swingup", "budget=abc"], "budget must be an integer, got 'abc'"),
    (["task=cartpole_swingup", "budget=1.5"], "budget must be an integer, got 1.5"),
    (["task=cartpole_swingup", "budget=-1"], "budget must be an integer >= 1, got -1"),
    (["task=cartpole_swingup", "seeds=0"], "seeds (a count) must be an integer in [1, 1000], got 0"),
    (["task=cartpole_swingup", "seeds=[1,1]"], "seeds must be a count or a list of distinct seeds, got [1, 1]"),
    (["task=cartpole_swingup", "seeds=[a]"], "every entry of seeds must be an integer, got 'a'"),
    (["task=cartpole_swingup", "seeds=[-1]"], "every entry of seeds must be an integer in [0, 999], got -1"),
    (["task=cartpole_swingup", "seeds=[1"], "malformed argument"),
    (["task=cartpole_swingup", "algos=[hrtc_beta,sac]"], "unknown algorithm 'sac'; valid: hrtc_beta, hrtc_beta_sac"),
    (["task=cartpole_swingup", "algos=[]"], "algos must list distinct algorithms, got []"),
    (["task=cartpole_swingup", "budgets.sac=5"], "unknown algorithm 'sac' in budgets; valid: hrtc_beta"),
    (["task=cartpole_swingup", "budgets.sb3_sac=0"], "budgets.sb3_sac must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "budgets=5"], "budgets must be a mapping like {key: value}, got 5"),
    (["task=cartpole_swingup", "eval_every=0"], "eval_every must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "eval_episodes=-2"], "eval_episodes must be an integer >= 1, got -2"),
    (["task=cartpole_swingup", "threshold=abc"], "threshold must be a finite number, got 'abc'"),
    (["task=cartpole_swingup", "threshold=.inf"], "threshold must be a finite number, got inf"),
    (["task=cartpole_swingup", "solve_episodes=0"], "solve_episodes must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "collapse_window=x"], "collapse_window must be an integer, got 'x'"),
    (["task=cartpole_swingup", "backend=gpu"], "unknown backend 'gpu'; valid backends: auto, process, ray"),
    (["task=cartpole_swingup", "ray_address=abc"], "ray_address needs backend=ray"),
    (["task=cartpole_swingup", "cpus=0"], "cpus must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "cpus_per_run=0"], "cpus_per_run must be an integer >= 1, got 0"),
    (["task=cartpole_swingup", "report_only=maybe"], "report_only must be true or false, got 'maybe'"),
    (["task=cartpole_swingup", "progress=2"], "progress must be true or false, got 2"),
    (["task=cartpole_swingup", "out={text}"], "notes.txt exists and is a file, not a directory"),
    (["task=cartpole_swingup", "runs_dir={text}/runs"], "notes.txt is a file, not a directory"),
    (["task=cartpole_swingup", "report_only=true"], "no finished runs for these settings in"),
    (["task=cartpole_swingup", "out={bad_results}"], "results.json (JSONDecodeError"),
    (["task=cartpole_swingup", "seedz=3"], "unknown key 'seedz'; keys: task, algos, seeds"),
    (["task=cartpole_swingup", "cartpole_swingup"], "arguments look like key=value, got 'cartpole_swingup'"),
]


@pytest.mark.parametrize("args,expected", _cases(BENCH))
def test_benchmark_refuses_bad_input(files, tmp_path, args, expected):
    given = {a.split("=", 1)[0] for a in args}
    defaults = [f"{key}={{tmp}}/{key}" for key in ("out", "runs_dir") if key not in given]
    _refused("benchmark.py", [*defaults, *([] if "backend" in given else ["backend=process"]), *args], expected,
             files, tmp_path)  # fmt: skip


# --------------------------------------------------------------------------------------------------- train.py
# Beyond test_reliability's in-process corpus: the real script, whose Hydra would write .hydra/ and a log into the
# run directory if a check came after it.
TRAIN = [
    (["task=cartpol"], "unknown task 'cartpol'; valid tasks: ", SLOW),
    (["steps=-3"], "steps must be a positive integer, got -3"),
    (["steps=abc"], "steps must be a positive integer, got 'abc'", SLOW),
    (["steps=[1"], "malformed override", SLOW),
    (["seed=-1"], "seed must be a non-negative integer", SLOW),
    (["resume=maybe"], "resume must be true or false, got 'maybe'", SLOW),
    (["logger.mode=disk"], "unknown logger mode 'disk'", SLOW),
    (["algo.decision_every=0"], "algo.decision_every must be a positive integer", SLOW),
    (["hydra.run.dir={text}"], "notes.txt exists and is a file, not a directory"),
    (["hydra.run.dir={text}/run"], "notes.txt is a file, not a directory", SLOW),
    (["init_from={missing}"], "no checkpoint at", SLOW),
    (["init_from={text}"], "notes.txt was refused by the safe loader", SLOW),
    (["init_from={trunc}"], "truncated.pt is not a readable checkpoint", SLOW),
    (["init_from={folder}"], "no checkpoint at", SLOW),
    (
        ["init_from={ppo}"],
        "was trained with skills [] (obs 5, out 1); this environment has ['swingup', 'balance', "
        "'tracker', 'hold'] (obs 5, out 4)",
        SLOW,
    ),
    (
        ["+task.env_kwargs.colour=red"],
        "task 'cartpole_swingup' cannot be built with env_kwargs {'colour': 'red'}",
        SLOW,
    ),
    (["task.skills.hold.skill._target_=skills.static.Nope"], "skill 'hold' could not be built"),
    (
        ["task.skills.hold.skill.action=[0.0,0.0]"],
        "skill 'hold' proposed an action of shape (2,); the task's is (1,)",
        SLOW,
    ),
    (["+task.skills.hold.state=[cart_acceleration]"], "unknown state key 'cart_acceleration'", SLOW),
    (["resume=true", "<corrupt last.pt>"], "last.pt was refused by the safe loader"),
    (["resume=true", "<ppo last.pt>"], "last.pt was trained with skills []", SLOW),
]


@pytest.mark.parametrize("args,expected", _cases(TRAIN))
def test_train_refuses_bad_input(files, tmp_path, args, expected):
    run_dir = tmp_path / "run"
    if "<corrupt last.pt>" in args or "<ppo last.pt>" in args:  # an existing run directory: nothing in it changes
        (run_dir / "checkpoints").mkdir(parents=True)
        last = run_dir / "checkpoints" / "last.pt"
        if "<corrupt last.pt>" in args:
            last.write_bytes(b"\x80\x04garbage")
        else:
            shutil.copy(files["ppo"], last)
    args = [a for a in args if not a.startswith("<")]
    if not any(a.startswith("hydra.run.dir=") for a in args):
        args.append(f"hydra.run.dir={run_dir}")
    _refused("train.py", args, expected, files, tmp_path)


def test_the_corpora_are_wide():
    assert (len(EVAL), len(SKILL), len(REVIEW), len(BENCH), len(TRAIN)) >= (30, 20, 15, 30, 20)
