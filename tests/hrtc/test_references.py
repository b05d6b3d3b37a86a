"""Reference rules over a task's skills: what they choose, how they are declared, and the errors."""

import numpy as np
import pytest

from hrtc.cli import task_config
from hrtc.environments import make_env
from hrtc.errors import ConfigError
from hrtc.references import UNTRAINED, FixedWeights, SwitchRule, evaluate_rules, reference_rules

SWITCH = SwitchRule("pole_angle", 0.5, above={"swingup": 1.0}, below={"balance": 1.0})


@pytest.mark.parametrize(
    ("angle", "chosen"), [(3.0, "swingup"), (-0.6, "swingup"), (0.4, "balance"), (-0.1, "balance")]
)
def test_switch_rule_uses_the_magnitude_of_the_named_quantity(angle, chosen):
    assert SWITCH({"pole_angle": np.array([angle])}) == {chosen: 1.0}
    signed = SwitchRule("x", 0.0, above={"a": 1.0}, below={"b": 1.0}, absolute=False)
    assert signed({"x": np.array([-2.0])}) == {"b": 1.0}


def test_every_task_gets_each_skill_alone_and_the_untrained_blend_then_its_declared_rules():
    rules = reference_rules(("swingup", "balance"), {"rule": {"_target_": "hrtc.references.SwitchRule", "key": "k",
                                                                "threshold": 1, "above": {}, "below": {}}})  # fmt: skip
    assert list(rules) == ["swingup alone", "balance alone", UNTRAINED, "rule"]
    assert rules[UNTRAINED].vector(("swingup", "balance")).tolist() == [0.5, 0.5]
    assert isinstance(rules["rule"], SwitchRule)


def test_a_rule_naming_a_skill_the_task_lacks_is_one_clear_error():
    bad = {"r": {"_target_": "hrtc.references.FixedWeights", "weights": {"swing": 1.0}}}
    with pytest.raises(ConfigError, match=r"reference 'r' names skills \['swing'\]"):
        reference_rules(("swingup",), bad)
    with pytest.raises(ConfigError, match="reference 'r' could not be built"):
        reference_rules(("swingup",), {"r": {"_target_": "hrtc.references.NoSuchRule"}})


def test_the_declared_cartpole_rule_beats_every_skill_alone_on_the_real_task():
    """The library's ceiling as a person writes it: ~872 where the best skill alone scores ~560 (one episode)."""
    task = task_config("cartpole_swingup")
    env = make_env("cartpole_swingup", "hrtc", task["skills"], decision_every=5)
    rules = reference_rules(env.skill_names, task["references"])
    picked = {k: v for k, v in rules.items() if k in ("swingup alone", UNTRAINED) or k.startswith("switching")}
    returns = {k: float(v[0]) for k, v in evaluate_rules(env, picked, [1_001_000]).items()}
    rule = next(v for k, v in returns.items() if k.startswith("switching"))
    assert rule > 850 and rule > returns["swingup alone"] + 250 and rule > returns[UNTRAINED] + 250
    assert isinstance(rules["hold alone"], FixedWeights)


def test_a_meta_policy_started_at_the_hand_blend_acts_it_on_the_real_task():
    """algo.init_weights: the untrained meta-policy's Beta means give the hand blend's weights exactly (weights at 0
    and 1 with the weight span's margin), so its deterministic episodes are the blend's."""
    from hrtc.episodes import eval_seeds, evaluate
    from hrtc.policy import build_policy, start_at

    task = task_config("lunarlander")
    env = make_env("lunarlander", "hrtc", task["skills"], decision_every=5, weight_margin=0.25)
    hand = {"centring": 1.0, "descent": 1.0, "touchdown": 1.0}
    space = env.action_space
    policy = build_policy(env.observation_space.shape[0], space.low, space.high, "beta", (64, 64))
    start_at(policy, {**hand, "attitude": 0.0, "hover": 0.0, "idle": 0.0}, env.skill_names, 0.25)
    seeds = eval_seeds(1, 2)
    learned = evaluate(policy, None, env, seeds, "beta")
    blend = evaluate_rules(env, {"hand": FixedWeights(hand)}, seeds)["hand"]
    np.testing.assert_allclose(learned, blend, atol=1e-3)
    with pytest.raises(Exception, match="unknown skill 'nosuch'"):
        start_at(policy, {"nosuch": 1.0}, env.skill_names, 0.25)
