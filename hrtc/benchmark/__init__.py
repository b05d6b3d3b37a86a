"""The paper's Table 1 and Fig. 2 as one command: every (algorithm, seed) trained under a task's solve rule.

- :mod:`hrtc.benchmark.runs`: one run of any algorithm (HRTC and our PPO through :class:`~hrtc.trainer.Trainer`,
  stable-baselines3's PPO, SAC, TD3 and A2C) into a plain result dict with its evaluation curve.
- :mod:`hrtc.benchmark.dispatch`: runs dispatched as Ray tasks (local or an existing cluster) or, without Ray, to a
  process pool; finished runs are cached and skipped.
- :mod:`hrtc.benchmark.report`: solutions, collapses, robust statistics (IQM, bootstrap CIs), ``table.md`` and
  ``curves.png``.
- :mod:`hrtc.benchmark.metrics`: metric plug-ins beyond the evaluation curve (final and best policies on seeds of
  their own, success on unseen targets, training episodes for a wall-time budget) and the reference rules.
- :mod:`hrtc.benchmark.studies`: the ``table.md`` sections a benchmark config asks for.
- :mod:`hrtc.benchmark.main`: ``scripts/benchmark.py``: arguments over a benchmark config
  (``hrtc/conf/benchmark/<name>.yaml``), checks, runs, report.
"""
