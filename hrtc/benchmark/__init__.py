"""The paper's Table 1 and Fig. 2 as one command: every (algorithm, seed) trained under a task's solve rule.

- :mod:`hrtc.benchmark.runs`: one run of any algorithm (HRTC and our PPO through :class:`~hrtc.trainer.Trainer`,
  stable-baselines3's PPO, SAC, TD3 and A2C) into a plain result dict with its evaluation curve.
- :mod:`hrtc.benchmark.dispatch`: runs dispatched as Ray tasks (local or an existing cluster) or, without Ray, to a
  process pool; finished runs are cached and skipped.
- :mod:`hrtc.benchmark.report`: solutions, collapses, robust statistics (IQM, bootstrap CIs), ``table.md`` and
  ``curves.png``.
"""
