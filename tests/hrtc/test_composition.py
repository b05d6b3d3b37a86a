"""The action filter, state filters and the composed environment on the real cartpole."""

import gymnasium as gym
import numpy as np
import pytest

from envs import make
from hrtc.composition import (
    ActionFilter,
    ComposedEnv,
    Composition,
    KeysFilter,
    SkillLibrary,
    SkillSlot,
    blend,
    build_library,
)
from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from hrtc.skill import Skill, SkillOutput
from skills.static import StaticIntent

PROPOSALS = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.8], [0.3, -0.2, 0.1]])


@pytest.mark.parametrize("k", range(4))
@pytest.mark.parametrize("mode", ["sum", "convex"])
def test_one_hot_weights_give_exactly_that_skill(k, mode):
    weights = np.eye(4)[k]
    np.testing.assert_array_equal(blend(weights, PROPOSALS, mode), PROPOSALS[k])


def test_sum_mode_is_the_papers_weighted_sum():
    w = np.array([0.2, 0.5, 0.1, 0.9])
    np.testing.assert_allclose(blend(w, PROPOSALS, "sum"), sum(w[k] * PROPOSALS[k] for k in range(4)))


def test_convex_mode_is_a_convex_combination():
    rng = np.random.default_rng(0)
    for _ in range(100):
        w = rng.random(4)
        a = blend(w, PROPOSALS, "convex")
        assert np.all(a >= PROPOSALS.min(0) - 1e-12) and np.all(a <= PROPOSALS.max(0) + 1e-12)
    np.testing.assert_array_equal(blend(np.zeros(4), PROPOSALS, "convex"), np.zeros(3))


def test_action_filter_respects_bounds_for_any_weights():
    f = ActionFilter(np.array([-1.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]), "sum")
    rng = np.random.default_rng(1)
    for _ in range(200):
        w = rng.normal(0.5, 2.0, size=4)  # Normal weights stray outside [0, 1]
        a = f(w, PROPOSALS * rng.uniform(-5, 5))
        assert np.all(a >= f.low) and np.all(a <= f.high)


def test_weights_outside_unit_interval_are_clipped():
    np.testing.assert_array_equal(blend(np.array([2.0, -1.0, 0.0, 0.0]), PROPOSALS), PROPOSALS[0])


def test_unknown_blend_mode():
    with pytest.raises(UnknownNameError, match="convex, sum"):
        ActionFilter(np.zeros(1), np.ones(1), "max")  # type: ignore[arg-type]


def test_keys_filter_selects_in_order_and_names_missing_keys():
    state = {"a": np.array([1.0]), "b": np.array([2.0, 3.0])}
    np.testing.assert_array_equal(KeysFilter(("b", "a"))(state), [2.0, 3.0, 1.0])
    with pytest.raises(UnknownNameError, match="valid state keys: a, b"):
        KeysFilter(("c",))(state)


class _Counter:
    """A skill that counts its calls and proposes the count (to observe rates)."""

    state_keys = ("cart_position",)

    def __init__(self) -> None:
        self.calls = 0

    def reset(self, rng: np.random.Generator) -> None:
        self.calls = 0

    def act(self, state: np.ndarray) -> SkillOutput:
        self.calls += 1
        return SkillOutput(np.array([self.calls / 100.0]), {})


def test_counter_is_a_skill():
    assert isinstance(_Counter(), Skill)


def _composed(*slots: SkillSlot, mode: str = "sum", diagnostics: bool = False) -> ComposedEnv:
    library = SkillLibrary(list(slots))
    return ComposedEnv(make("cartpole_swingup"), library, mode, diagnostics=diagnostics)  # type: ignore[arg-type]


def test_composed_env_applies_the_blend_and_reports_it():
    push = SkillSlot("push", StaticIntent([0.6]), KeysFilter(()))
    pull = SkillSlot("pull", StaticIntent([-0.2]), KeysFilter(()))
    env = _composed(push, pull)
    assert env.action_space == gym.spaces.Box(0.0, 1.0, (2,), np.float32)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5, 1.0]))
    assert info["action"] == pytest.approx([0.5 * 0.6 - 0.2])
    np.testing.assert_allclose(info["proposals"], [[0.6], [-0.2]])
    assert set(info["skills"]) == {"push", "pull"}


def test_a_weight_margin_widens_the_action_space_and_clips_the_weights_to_the_unit_interval():
    slots = [
        SkillSlot("push", StaticIntent([0.6]), KeysFilter(())),
        SkillSlot("pull", StaticIntent([-0.2]), KeysFilter(())),
    ]
    env = ComposedEnv(make("cartpole_swingup"), SkillLibrary(slots), weight_margin=0.25)  # type: ignore[arg-type]
    assert env.action_space == gym.spaces.Box(-0.25, 1.25, (2,), np.float32)
    plain = _composed(*[SkillSlot(s.name, s.skill, s.state_filter) for s in slots])
    env.reset(seed=4)
    plain.reset(seed=4)
    # Beyond the unit interval a weight acts as 0 or 1 exactly (the switch a rule makes); inside it, as without margin.
    for wide, unit in (([1.25, -0.25], [1.0, 0.0]), ([1.1, 0.3], [1.0, 0.3]), ([0.5, -0.01], [0.5, 0.0])):
        obs, reward, *_, info = env.step(np.array(wide))
        obs_p, reward_p, *_, info_p = plain.step(np.array(unit))
        np.testing.assert_array_equal(obs, obs_p)
        assert reward == reward_p
        np.testing.assert_array_equal(info["weights"], unit)
        np.testing.assert_array_equal(info["action"], info_p["action"])
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="weight_margin"):
            ComposedEnv(make("cartpole_swingup"), SkillLibrary(slots), weight_margin=bad)  # type: ignore[arg-type]


def test_one_hot_in_the_env_equals_running_that_skill_alone():
    slot = SkillSlot("push", StaticIntent([0.7]), KeysFilter(()))
    env = _composed(slot, SkillSlot("hold", StaticIntent([0.0]), KeysFilter(())))
    raw = make("cartpole_swingup")
    obs_c, _ = env.reset(seed=3)
    obs_r, _ = raw.reset(seed=3)
    for _ in range(50):
        obs_c, rc, *_ = env.step(np.array([1.0, 0.0]))
        obs_r, rr, *_ = raw.step(np.array([0.7], np.float32))
    np.testing.assert_array_equal(obs_c, obs_r)


def test_skill_rate_holds_the_action_between_solves():
    counter = _Counter()
    env = _composed(SkillSlot("counter", counter, KeysFilter(("cart_position",)), every=5))
    env.reset(seed=0)
    actions = [env.step(np.array([1.0]))[4]["action"][0] for _ in range(12)]
    assert counter.calls == 3  # steps 0, 5, 10
    assert actions[:5] == [0.01] * 5 and actions[5:10] == [0.02] * 5


def test_wrong_weight_shape_and_wrong_proposal_shape_are_clear_errors():
    env = _composed(SkillSlot("hold", StaticIntent([0.0]), KeysFilter(())))
    env.reset(seed=0)
    with pytest.raises(ShapeError, match="expected 1 skill weights"):
        env.step(np.array([0.5, 0.5]))
    with pytest.raises(ShapeError, match="'wide'"):
        _composed(SkillSlot("wide", StaticIntent([0.0, 0.0]), KeysFilter(()))).reset(seed=0)


class _NaNSkill:
    state_keys = ()

    def reset(self, rng):
        pass

    def act(self, state):
        return SkillOutput(np.array([np.nan]), {"status": 1.0})


def test_non_finite_proposal_falls_back_and_is_counted():
    env = _composed(SkillSlot("bad", _NaNSkill(), KeysFilter(())), diagnostics=True)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0]))
    assert np.all(np.isfinite(info["action"])) and info["action"][0] == 0.0
    assert info["skill_faults"][0] >= 1 and info["skills"]["bad"]["fault"] == 1.0


class _RaisingSkill:
    """Raises what a solver library raises when Ctrl-C lands inside it, or a plain failure."""

    state_keys = ()

    def __init__(self, error):
        self.error = error

    def reset(self, rng):
        pass

    def act(self, state):
        raise self.error


def _system_error_from_an_interrupt() -> SystemError:
    try:
        try:
            raise KeyboardInterrupt("signal 15")
        except KeyboardInterrupt as interrupt:
            raise SystemError("<function DM.__array__> returned a result with an exception set") from interrupt
    except SystemError as error:
        return error


@pytest.mark.parametrize(
    "error",
    [
        RuntimeError("Error in Function::call for 'mpc' [Sqpmethod] at function.cpp:514:\nKeyboardInterrupt: signal 2"),
        _system_error_from_an_interrupt(),
    ],
    ids=["casadi_runtime_error", "system_error_caused_by_it"],
)
def test_an_interrupt_a_library_wrapped_stops_the_run_and_a_failure_falls_back(error):
    """The skill isolation turns a failing skill into a logged fallback, but Ctrl-C or SIGTERM inside a skill's solver
    (wrapped by the library into another exception) still reaches the trainer as KeyboardInterrupt."""
    env = _composed(SkillSlot("mpc", _RaisingSkill(error), KeysFilter(())), diagnostics=True)
    with pytest.raises(KeyboardInterrupt):  # the first proposals are asked at reset
        env.reset(seed=0)
        env.step(np.array([1.0]))
    failure = _RaisingSkill(RuntimeError("QP infeasible"))
    failing = _composed(SkillSlot("mpc", failure, KeysFilter(())), diagnostics=True)
    failing.reset(seed=0)
    _, _, _, _, info = failing.step(np.array([1.0]))
    assert info["skills"]["mpc"]["fault"] == 1.0 and info["action"][0] == 0.0


def test_build_library_from_config_and_its_errors():
    lib = build_library({"hold": {"skill": {"_target_": "skills.static.StaticIntent", "action": [0.0]}}})
    assert lib.names == ("hold",)
    with pytest.raises(ConfigError, match="expected keys"):
        build_library({"hold": {"_target_": "skills.static.StaticIntent"}})
    with pytest.raises(ConfigError, match="could not be built"):
        build_library({"x": {"skill": {"_target_": "skills.nope.Missing"}}})
    with pytest.raises(ConfigError, match="at least one"):
        build_library({})


def test_the_composition_holds_its_weights_between_decisions_and_asks_each_skill_once_a_step():
    """The one composition (ComposedEnv and a learned HRTC skill both act through it): new weights at steps 0, k,
    2k... (the meta-policy is asked only then), the skills' proposals for each step's state asked once."""
    counter = _Counter()
    library = SkillLibrary([SkillSlot("counter", counter, KeysFilter(("cart_position",))),
                            SkillSlot("push", StaticIntent([0.5]), KeysFilter(()))])  # fmt: skip
    composition = Composition(library, ActionFilter(np.array([-1.0]), np.array([1.0])), decision_every=3)
    composition.reset(np.random.default_rng(0))
    decisions, states = [], []

    def decide() -> np.ndarray:
        decisions.append(composition.step)
        return np.array([1.0, 2.0 if len(decisions) == 1 else 0.0])  # clipped to [0, 1]

    def state() -> dict:
        states.append(composition.step)
        return {"cart_position": np.zeros(1)}

    composition.propose(state)  # asked ahead (as ComposedEnv does at reset): not asked again at step 0
    actions = [composition.act(state, decide)[0][0] for _ in range(7)]
    assert decisions == [0, 3, 6] and states == list(range(7)) and counter.calls == 7
    np.testing.assert_allclose(actions, [0.01 * (t + 1) + (0.5 if t < 3 else 0.0) for t in range(7)])
    np.testing.assert_array_equal(composition.weights, [1.0, 0.0])
    with pytest.raises(ConfigError, match="decision_every must be >= 1"):
        Composition(library, ActionFilter(np.array([-1.0]), np.array([1.0])), decision_every=0)


def test_a_decision_sums_the_shaped_tasks_true_reward_as_it_sums_the_reward():
    """Over a decision of several env steps, info["true_reward"] is the sum of the task's own rewards, as the reward
    is the sum of the shaped ones (carracing with the reference's +100 at its end)."""
    library = SkillLibrary([SkillSlot("gas", StaticIntent([0.0, 0.5, 0.0]), KeysFilter(()))])
    composed = ComposedEnv(make("carracing", action_repeat=1, max_frames=4, end_bonus=100.0), library,
                           decision_every=2)  # fmt: skip
    plain = make("carracing", action_repeat=1, max_frames=4)
    composed.reset(seed=3)
    plain.reset(seed=3)
    for decision in range(2):
        _, reward, _, truncated, info = composed.step(np.array([1.0]))
        true = sum(plain.step(np.array([0.0, 0.5, 0.0], np.float32))[1] for _ in range(2))
        assert info["true_reward"] == pytest.approx(true, abs=1e-12)
        assert reward == pytest.approx(true + 100.0 * (decision == 1), abs=1e-12) and truncated == (decision == 1)
