"""What one SAC gradient step of the cart-pole meta-policy costs, per critic size, on this machine.

The learner of a real run (``hrtc.sac.SACLearner``: the Beta actor 64 x 64, the master critic, N critics), its buffer
filled with 5,000 random transitions of the cart-pole's shapes (5 observations, 4 skill weights), 20 warm-up steps,
then the mean of 200 timed steps. One torch thread, as ``train.py`` runs (``torch_threads: 1``). ``--bf16`` times
each setting twice, back to back: float32 critics, then ``sac.q_bf16`` (their hidden layers in bfloat16).

    PYTHONPATH=. python benchmarks/results/cartpole_swingup/learner_diagnosis/gradient_step_cost.py [--threads 1]
        [--bf16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from hrtc.policy import ActorCritic
from hrtc.sac import SACConfig, SACLearner

SETTINGS = [  # (critic hidden widths, gradient steps per decision, number of critics, LayerNorm in the critics)
    ((512, 512), 2, 2, False),  # cartpole_swingup's default until section 14
    ((512, 512), 2, 2, True),  # the same with sac.q_layer_norm: cartpole_swingup's default since section 14
    ((256, 256), 1, 2, False),  # the root config's (the default until the ninth sitting)
    ((256, 256), 2, 5, False),  # the ensemble of section 12
    ((128, 128), 2, 2, False),
    ((64, 64), 2, 2, False),
    ((256,), 2, 2, False),
    ((256, 256), 2, 2, True),  # the default's LayerNorm critics at the root's width (section 21)
    ((256, 256), 1, 2, True),  # the same, one gradient step per decision
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--first", type=int, default=len(SETTINGS), help="time only the first N settings")
    parser.add_argument("--only", type=int, nargs="+", help="time only these settings (indices into SETTINGS)")
    parser.add_argument("--bf16", action="store_true", help="also time each setting with sac.q_bf16")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    obs_dim, k, n = 5, 4, 5000
    print("| critics | steps per decision | ms per gradient step | ms per decision |")
    print("|---|---|---|---|")
    precisions = (False, True) if args.bf16 else (False,)
    chosen = [SETTINGS[i] for i in args.only] if args.only else SETTINGS[: args.first]
    runs = [(*setting, bf16) for setting in chosen for bf16 in precisions]
    for hidden, updates, critics, layer_norm, bf16 in runs:
        torch.manual_seed(0)
        cfg = SACConfig(q_hidden=hidden, updates_per_decision=updates, n_critics=critics, learning_starts=0,
                        q_layer_norm=layer_norm, q_bf16=bf16)  # fmt: skip
        learner = SACLearner(ActorCritic(obs_dim, k, "beta", hidden=(64, 64)), cfg, 0.99**5,
                             torch.Generator().manual_seed(0))  # fmt: skip
        learner.buffer.add(rng.normal(size=(n, obs_dim)).astype(np.float32), rng.random((n, k), np.float32),
                           rng.normal(size=n).astype(np.float32), rng.normal(size=(n, obs_dim)).astype(np.float32),
                           np.zeros(n, np.float32), np.full(n, 0.99**5, np.float32))  # fmt: skip
        for _ in range(20):
            learner._gradient_step()
        start = time.perf_counter()
        for _ in range(args.steps):
            learner._gradient_step()
        per_step = (time.perf_counter() - start) / args.steps
        label = f"{critics} x {list(hidden)}" + (" LayerNorm" if layer_norm else "") + (" bf16" if bf16 else "")
        print(f"| {label} | {updates} | {per_step * 1e3:.1f} | {per_step * updates * 1e3:.1f} |", flush=True)


if __name__ == "__main__":
    main()
