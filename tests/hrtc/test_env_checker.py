"""The composed environment is a gymnasium environment any agent can act on: on every registered task that declares
a skill library it passes gymnasium's and stable-baselines3's environment checkers (among them: the same seed and
action give the same observation, reward and info)."""

from importlib import resources

import numpy as np
import pytest
from omegaconf import OmegaConf

import envs
from hrtc.cli import CONFIG_MODULE, group_choices, task_config
from hrtc.environments import make_env

# The checkers are meant for the raw env and say so for a wrapper; checking the wrapper is the point here.
pytestmark = pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")


def _composed_tasks() -> list[str]:
    """Registered tasks whose shipped config declares skills (carracing included: ~7 s through both checkers)."""
    shipped = set(group_choices("task"))
    return [n for n in envs.names() if n in shipped and task_config(n).get("skills")]


def _composed(name: str, diagnostics: bool = False):
    """The env the meta-policy acts in, at the task's own decision rate."""
    text = (resources.files(CONFIG_MODULE) / "task" / f"{name}.yaml").read_text()
    decision_every = int(OmegaConf.create(text).get("algo", {}).get("decision_every", 1))
    task = task_config(name)
    return make_env(name, "hrtc", task["skills"], env_kwargs=task.get("env_kwargs"), decision_every=decision_every,
                    diagnostics=diagnostics)  # fmt: skip


def test_every_task_with_skills_is_checked():
    assert {"cartpole_swingup", "lunarlander", "panda_reach", "carracing"} <= set(_composed_tasks())


@pytest.mark.parametrize("name", _composed_tasks())
def test_composed_env_passes_gymnasiums_check_env(name):
    from gymnasium.utils.env_checker import check_env

    env = _composed(name)
    try:
        check_env(env, skip_render_check=True)
    finally:
        env.close()


@pytest.mark.parametrize("name", _composed_tasks())
def test_composed_env_passes_stable_baselines3s_check_env(name):
    from stable_baselines3.common.env_checker import check_env

    env = _composed(name)
    try:
        check_env(env, warn=False, skip_render_check=True)
    finally:
        env.close()


def test_diagnostics_are_opt_in_and_what_the_checker_rejects():
    """With ``diagnostics=True`` the info carries timings and lifetime counters (the trainer's fault health check and
    the recordings read them), and exactly those make two runs under one seed differ."""
    from gymnasium.utils.env_checker import data_equivalence

    infos = {}
    for diagnostics in (False, True):
        env = _composed("cartpole_swingup", diagnostics)
        weights = np.full(env.action_space.shape, 0.5, np.float32)
        runs = []
        for _ in range(2):
            _, reset_info = env.reset(seed=3)
            runs.append((reset_info, env.step(weights)[4]))
        env.close()
        infos[diagnostics] = runs
    (reset_a, step_a), (reset_b, step_b) = infos[False]
    assert data_equivalence(step_a, step_b) and "skill_faults" not in step_a and "skill_calls" not in reset_a
    assert not any(k.endswith("_ms") for skill in step_a["skills"].values() for k in skill)
    (_, step_a), (_, step_b) = infos[True]
    assert step_b["skill_calls"].sum() > step_a["skill_calls"].sum()  # lifetime counters go on across resets
    assert "compute_ms" in step_a["skills"]["hold"] and "solve_ms" in step_a["skills"]["balance"]
    assert not data_equivalence(step_a, step_b)
