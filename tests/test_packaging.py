"""An installed copy works: the wheel built from this tree holds everything the tasks and skills read at run time
(about 15 s: a wheel build and a fresh interpreter that builds every task).

The wheel is built from a copy of the package sources (nothing is written into the repository), unpacked into a
scratch directory and imported from there by a Python started outside the repository, which builds every registered
task and composes every task's skill library.
"""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "hrtc", "envs", "skills")

# Run in the unpacked wheel, from a directory outside the repository. Exits non-zero on the first failure.
CHECK = """
import sys
from pathlib import Path

site = Path(sys.argv[1]).resolve()
import envs, hrtc, skills
from hrtc.cli import group_choices, task_config
from hrtc.environments import make_env

for module in (envs, hrtc, skills):
    assert Path(module.__file__).resolve().is_relative_to(site), f"{module.__name__} imported from {module.__file__}"
shipped = set(group_choices("task"))
built, composed = [], []
for name in envs.names():
    env = envs.make(name)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
    built.append(name)
    task = task_config(name) if name in shipped else {}
    if task.get("skills"):
        env = make_env(name, "hrtc", task["skills"], env_kwargs=task.get("env_kwargs"))
        env.reset(seed=0)
        env.step(env.action_space.sample())
        env.close()
        composed.append(name)
print("built", *built)
print("composed", *composed)
"""


def _build_wheel(tmp_path: Path) -> Path:
    """``pip wheel`` of a copy of the sources (no build isolation: offline, with this environment's setuptools)."""
    source = tmp_path / "source"
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            source.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    dist = tmp_path / "dist"
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist), "."]
    result = subprocess.run(cmd, cwd=source, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    (wheel,) = dist.glob("hrtc-*.whl")
    return wheel


def test_the_installed_wheel_builds_every_task_and_composes_every_skill_library(tmp_path):
    import envs
    from hrtc.cli import group_choices, task_config

    wheel = _build_wheel(tmp_path)
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "envs/assets/panda_reach.xml" in names and "hrtc/conf/config.yaml" in names and "hrtc/py.typed" in names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    result = subprocess.run([sys.executable, "-c", CHECK, str(site)], cwd=elsewhere, env=env, capture_output=True,
                            text=True, timeout=600)  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines() if line.startswith(("built", "composed")))
    # Other test modules register tasks of their own (test_*) in this process: the package's are the rest.
    assert lines["built"].split() == [n for n in envs.names() if not n.startswith("test_")]
    shipped = set(group_choices("task"))
    expected = [n for n in envs.names() if n in shipped and task_config(n).get("skills")]
    assert lines["composed"].split() == expected and "panda_reach" in expected
