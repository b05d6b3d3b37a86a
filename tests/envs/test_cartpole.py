"""The dm_control cart-pole swing-up as HRTC composes it: its left-right mirror, which ``sac.mirror_fraction`` uses."""

from __future__ import annotations

import numpy as np
import pytest

import envs


def _declared_mirror() -> tuple[list[int], np.ndarray]:
    """The mirror the benchmark row ``hrtc_beta_sac_ln_tau02_auto_mirror`` declares (``sac.mirror_index``,
    ``sac.mirror_sign`` overrides) for the observation ``[x, cos(angle), sin(angle), x_dot, angle_dot]``."""
    from importlib import resources

    import yaml

    text = (resources.files("hrtc.conf") / "benchmark" / "cartpole_swingup_ensemble.yaml").read_text()
    overrides = yaml.safe_load(text)["variants"]["hrtc_beta_sac_ln_tau02_auto_mirror"]["overrides"]
    values = dict(o.split("=", 1) for o in overrides)
    assert float(values["sac.mirror_fraction"]) > 0
    return yaml.safe_load(values["sac.mirror_index"]), np.asarray(yaml.safe_load(values["sac.mirror_sign"]), float)


@pytest.mark.parametrize("start", [([0.3, 2.5], [-0.5, 1.0]), ([-0.05, np.pi - 0.01], [0.02, -0.1])])
def test_the_declared_mirror_is_a_symmetry_of_the_composed_swingup(start) -> None:
    """Mirror augmentation holds a transition (obs, w, r, obs') and its mirror image (M obs, w, r, M obs') for one the
    task could give. Checked in closed loop on the real task and library: the composed cart-pole started at a state
    and at its mirror image (x and the angle negated, their rates too) and driven by the same 100 weight vectors (500
    env steps through swing-ups, over the rail's ends and past upright) stays the other's mirror image, with the same
    rewards and the negated blended force; the four skills (energy swing-up, LQR balance, the CasADi tracking MPC
    re-solved every 5 env steps with its warm starts, hold) are equivariant along the way."""
    from hrtc.cli import task_config
    from hrtc.composition import ComposedEnv, build_library

    index, sign = _declared_mirror()
    assert sorted(index) == list(range(5)) and len(sign) == 5
    cfg = task_config("cartpole_swingup")
    weights = np.random.default_rng(0).uniform(0, 1, (100, len(cfg["skills"])))
    runs = []
    for mirrored in (False, True):
        env = ComposedEnv(envs.make("cartpole_swingup"), build_library(cfg["skills"]), decision_every=5)
        env.reset(seed=4)
        physics = env.unwrapped.physics
        qpos, qvel = (-np.asarray(s) if mirrored else np.asarray(s) for s in start)
        with physics.reset_context():
            physics.data.qpos[:], physics.data.qvel[:] = qpos, qvel
        env.composition.reset(np.random.default_rng(0))
        env.composition.propose(env.unwrapped.skill_state)  # the proposals for the state set, not the reset's
        rows = []
        for w in weights:
            obs, reward, *_, info = env.step(w)
            rows.append(np.r_[obs, reward, info["action"]])
        runs.append(np.array(rows))
    plain, mirror = runs
    angle = np.arctan2(plain[:, 2], plain[:, 1])
    assert np.ptp(angle) > 3 and np.ptp(plain[:, 0]) > 0.5 and plain[:, 5].sum() > 10  # it moved, swung and scored
    np.testing.assert_allclose(plain[:, :5][:, index] * sign, mirror[:, :5], atol=1e-9)
    np.testing.assert_allclose(plain[:, 5], mirror[:, 5], atol=1e-9)
    np.testing.assert_allclose(plain[:, 6], -mirror[:, 6], atol=1e-9)
