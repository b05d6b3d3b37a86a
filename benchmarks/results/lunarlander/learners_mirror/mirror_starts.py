"""A learned lunarlander policy on given starts and on their mirror images, on the same terrain.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners_mirror/mirror_starts.py CHECKPOINT SEED [SEED ...]
        [--hand]

For each reset seed (e.g. the final episodes a policy failed: ``../learners/crashes.py`` lists them): the episode's
start re-placed as drawn (``set_state`` with the drawn state, so both runs start the same way) and its mirror image
under the task's declared map (``sac.mirror_index``, ``sac.mirror_sign`` of ``hrtc/conf/task/lunarlander.yaml``), on
the terrain that seed drew, and the mirror image on that terrain mirrored too (its ground rebuilt as x -> W - x: the
whole episode's mirror image, so a mirror-equivariant policy scores there what it scores as drawn); deterministic
(Beta means). The engines' random impulse offsets are not mirrored, so even the last is not the exact mirror of the
episode: ``--hand`` plays the hand blend, an exactly mirror-equivariant policy, to show how far that alone moves a
return. Then the terrain's height above the pad at each chunk's left end (world units; the pad spans x 8-12).
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import torch
import yaml
from Box2D.b2 import edgeShape
from gymnasium.envs.box2d import lunar_lander as ll

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import mode_decider  # noqa: E402
from hrtc.references import rule_decider  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "learners"))
from hand import declared_hand_blend  # noqa: E402  (../learners)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("seeds", type=int, nargs="+")
    parser.add_argument(
        "--hand",
        action="store_true",
        help="play the hand blend instead (an exactly mirror-"
        "equivariant policy: how far a start and its mirrored episode differ without any policy)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    sac = yaml.safe_load((resources.files("hrtc.conf") / "task" / "lunarlander.yaml").read_text())["sac"]
    index, sign = list(sac["mirror_index"]), np.asarray(sac["mirror_sign"], float)
    loaded = load_policy(args.checkpoint)
    env = checkpoint_env(loaded.meta)
    decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])
    if args.hand:  # the task's declared hand blend (its reference), whatever the checkpoint learnt
        decide = rule_decider(env, declared_hand_blend(loaded.meta["skills"])[1])

    def mirror_ground(task: object) -> None:
        """Rebuild gymnasium's ground (the static ``moon`` body's edges) as its mirror image about the pad's centre."""
        width, top = ll.VIEWPORT_W / ll.SCALE, ll.VIEWPORT_H / ll.SCALE
        edges = [(poly[0], poly[1]) for poly in task.sky_polys]
        task.world.DestroyBody(task.moon)
        task.moon = task.world.CreateStaticBody(shapes=edgeShape(vertices=[(0, 0), (width, 0)]))
        task.sky_polys = []
        for p1, p2 in reversed(edges):
            a, b = (width - p2[0], p2[1]), (width - p1[0], p1[1])
            task.moon.CreateEdgeFixture(vertices=[a, b], density=0, friction=0.1)
            task.sky_polys.append([a, b, (b[0], top), (a[0], top)])
        task.moon.color1, task.moon.color2 = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)

    def play(seed: int, mirrored: bool, ground: bool = False) -> float:
        obs, _ = env.reset(seed=seed)
        if ground:
            mirror_ground(env.unwrapped)
        state = np.asarray(obs, float)
        state = state[index] * sign if mirrored else state
        obs = env.unwrapped.set_state(*state[:6]).astype(np.float32)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(decide(obs).action)
            total, done = total + float(reward), terminated or truncated
        return total

    for seed in args.seeds:
        print(f"seed {seed}: as drawn (re-placed) {play(seed, False):.0f}; its mirror image {play(seed, True):.0f}; "
              f"its mirror image on the mirrored ground {play(seed, True, ground=True):.0f}")  # fmt: skip
    for seed in args.seeds:
        env.reset(seed=seed)
        task = env.unwrapped
        heights = np.array([poly[0][1] for poly in task.sky_polys]) - task.helipad_y
        print(f"seed {seed}: terrain above the pad at x = 0, 2, ..., 18: {np.round(heights, 2).tolist()}")
    env.close()


if __name__ == "__main__":
    main()
