"""Train HRTC (or plain PPO) on a task.

    python scripts/train.py task=cartpole_swingup [algo=hrtc|ppo] [dist=beta|normal] [seed=N] [steps=N]
        [hydra.run.dir=DIR] [resume=true]

Writes into the run directory: train.csv, eval.csv, checkpoints/{last,best}.pt and config.yaml (resolved).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc.cli import check_overrides, fail  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

log = logging.getLogger("hrtc.train")


@hydra.main(version_base=None, config_path="pkg://hrtc.conf", config_name="config")
def main(cfg: DictConfig) -> None:
    from hrtc.trainer import RunConfig, Trainer

    run_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        container = OmegaConf.to_container(cfg, resolve=True)
        run_cfg = RunConfig.from_mapping(container)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        trainer = Trainer(run_cfg, run_dir, resume=bool(cfg.get("resume", False)))
    except HRTCError as error:
        fail(str(error))
    log.info("run directory: %s", run_dir)
    result = trainer.train()
    print(
        f"done: {result['steps']} steps in {result['wall_seconds']:.0f} s; final eval {result['final_eval']:.1f}, "
        f"best {result['best_eval']:.1f}; run directory {run_dir}"
    )


if __name__ == "__main__":
    check_overrides(sys.argv[1:])
    main()
