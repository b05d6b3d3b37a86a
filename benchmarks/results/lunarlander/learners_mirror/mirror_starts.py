"""A learned lunarlander policy on given starts and on their mirror images, on the same terrain.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners_mirror/mirror_starts.py CHECKPOINT SEED [SEED ...]

For each reset seed (e.g. the final episodes a policy failed: ``../learners/crashes.py`` lists them): the episode's
start re-placed as drawn (``set_state`` with the drawn state, so both runs start the same way) and its mirror image
under the task's declared map (``sac.mirror_index``, ``sac.mirror_sign`` of ``hrtc/conf/task/lunarlander.yaml``), on
the terrain that seed drew; deterministic (Beta means). Then the terrain's height above the pad at each chunk's left
end (world units; the pad spans x 8-12), so that a terrain difference between the sides can be seen.
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import mode_decider  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("seeds", type=int, nargs="+")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sac = yaml.safe_load((resources.files("hrtc.conf") / "task" / "lunarlander.yaml").read_text())["sac"]
    index, sign = list(sac["mirror_index"]), np.asarray(sac["mirror_sign"], float)
    loaded = load_policy(args.checkpoint)
    env = checkpoint_env(loaded.meta)
    decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])

    def play(seed: int, mirrored: bool) -> float:
        obs, _ = env.reset(seed=seed)
        state = np.asarray(obs, float)
        state = state[index] * sign if mirrored else state
        obs = env.unwrapped.set_state(*state[:6]).astype(np.float32)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(decide(obs).action)
            total, done = total + float(reward), terminated or truncated
        return total

    for seed in args.seeds:
        print(f"seed {seed}: as drawn (re-placed) {play(seed, False):.0f}; its mirror image {play(seed, True):.0f}")
    for seed in args.seeds:
        env.reset(seed=seed)
        task = env.unwrapped
        heights = np.array([poly[0][1] for poly in task.sky_polys]) - task.helipad_y
        print(f"seed {seed}: terrain above the pad at x = 0, 2, ..., 18: {np.round(heights, 2).tolist()}")
    env.close()


if __name__ == "__main__":
    main()
