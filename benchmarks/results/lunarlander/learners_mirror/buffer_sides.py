"""Where a lunarlander run's replay buffer has been, by side: does a policy that fails on hard pushes to the left
have fewer such states in its data?

usage: PYTHONPATH=. python benchmarks/results/lunarlander/learners_mirror/buffer_sides.py RUN_DIR [RUN_DIR ...]

Reads each run's ``checkpoints/last.pt`` (SAC's buffer as stored, before any mirroring; at 50k env steps with the
start search's episodes forgotten: the decisions since the search) and prints a markdown row per run: the decisions
left and right of the pad (x < 0, x > 0), those moving hard sideways (|vx| > 0.5, in the observation's scaled
units), those moving hard sideways while high (y > 0.8, where the initial push shows), and the crash ends
(terminated with a reward below -50) by side.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hrtc.checkpoint import load_checkpoint


def main(runs: list[str]) -> None:
    print(
        "| run | decisions x < 0 / x > 0 | vx < -0.5 / vx > 0.5 | the same while y > 0.8 | crash ends x < 0 / x > 0 |"
    )
    print("|---|---|---|---|---|")
    for run in runs:
        buffer = load_checkpoint(Path(run) / "checkpoints" / "last.pt")["optimizer"]["buffer"]
        obs, reward = buffer["obs"].numpy(), buffer["rewards"].numpy()
        ended = buffer["terminated"].numpy().astype(bool)
        x, y, vx = obs[:, 0], obs[:, 1], obs[:, 2]
        crash = ended & (reward < -50)
        name = "/".join(Path(run).parts[-2:])
        print(f"| {name} | {(x < 0).sum()} / {(x > 0).sum()} | {(vx < -0.5).sum()} / {(vx > 0.5).sum()} | "
              f"{((y > 0.8) & (vx < -0.5)).sum()} / {((y > 0.8) & (vx > 0.5)).sum()} | "
              f"{(crash & (x < 0)).sum()} / {(crash & (x > 0)).sum()} |")  # fmt: skip


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
