"""One task's benchmark, every (algorithm, seed), locally or on a Ray cluster: ``hrtc.benchmark.main``.

python scripts/benchmark.py benchmark=<name> [key=value ...]      # a committed study (hrtc/conf/benchmark/)
python scripts/benchmark.py task=cartpole_swingup [algos=[...]] [seeds=5] [budget=50000] [key=value ...]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc.benchmark.main import entry  # noqa: E402

if __name__ == "__main__":
    entry()
