#!/bin/bash
# $1: repo root, $2: tag, $3...: extra overrides
root=$1; tag=$2; shift 2; mkdir -p /tmp/throughput
cd $root && PYTHONPATH=$root nice -n 15 python scripts/train.py task=carracing algo=ppo seed=1 steps=5000 eval_every=100000 eval_episodes=1 checkpoint_every=100000 progress=false logger.mode=off hydra.run.dir=/tmp/throughput/$tag "$@" > /tmp/throughput/$tag.log 2>&1
