"""Train HRTC (or plain PPO) on a task.

    python scripts/train.py task=cartpole_swingup [algo=hrtc|ppo] [dist=beta|normal] [seed=N] [steps=N]
        [hydra.run.dir=DIR] [resume=true]

Writes into the run directory: train.csv, eval.csv, checkpoints/{last,best}.pt and config.yaml (resolved). One
process writes a run directory at a time (its .lock names the holder); bad input is one error line, nothing written.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc.cli import fail, prepare_run, start_run  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

log = logging.getLogger("hrtc.train")


@hydra.main(version_base=None, config_path="pkg://hrtc.conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    trainer = start_run(cfg, run_dir)
    log.info("run directory: %s", run_dir)
    if trainer.skill_names:
        from hrtc.tree import env_tree, format_tree

        log.info("skill tree:\n%s", format_tree(env_tree(trainer.eval_env)))
    try:
        result = trainer.train()
    except HRTCError as error:  # a skill faulting too often, a loss that stays NaN: the run is saved, say why
        fail(str(error), status=1)
    except KeyboardInterrupt:
        fail(f"interrupted; checkpoint saved: resume with hydra.run.dir={run_dir} resume=true", status=130)
    print(
        f"done: {result['steps']} steps in {result['wall_seconds']:.0f} s; final eval {result['final_eval']:.1f}, "
        f"best {result['best_eval']:.1f}; run directory {run_dir}"
    )
    best = run_dir / "checkpoints" / "best.pt"
    if best.exists():  # the snapshot the evaluations picked: on fresh episodes it beat the last one (README)
        print(f"the best evaluated policy: {best} (python scripts/eval.py checkpoint={best})")


if __name__ == "__main__":
    sys.argv[1:] = prepare_run(sys.argv[1:])  # every check and the run directory's lock, before Hydra writes there
    main()
