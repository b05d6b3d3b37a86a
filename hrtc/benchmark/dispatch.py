"""Dispatch benchmark runs: one Ray task per run (a local Ray by default, or an existing cluster), else a process pool.

Each run declares its CPU count (``RunSpec.cpus``) as its Ray resource request, so Ray packs as many runs as the
cluster's CPUs allow. Results come back to the driver as plain dicts and are stored there, in one results file that
is rewritten after every finished run: a killed benchmark loses only the runs in flight, and the next invocation
skips every run already in the file.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from hrtc.benchmark.runs import RunSpec, run
from hrtc.errors import ConfigError

BACKENDS = ("auto", "ray", "process")
# The fields that make a stored result the same run (cpus and run_dir change where and how fast, not what).
SAME_RUN = (
    "task",
    "algo",
    "seed",
    "steps",
    "eval_every",
    "eval_episodes",
    "solve_threshold",
    "solve_episodes",
    "base",
    "overrides",
    "root_ppo",
    "final_seed_base",
    "final_best",
    "metric",
    "metric_args",
    "wall_minutes",
)
CORE = SAME_RUN[:8]  # what a screened solve rule needs stored (results of older versions lack the later fields)


def ray_available() -> bool:
    return importlib.util.find_spec("ray") is not None


def load_results(path: Path) -> dict[str, dict[str, Any]]:
    """The finished runs stored in ``path`` (``{key: result}``), empty if the file does not exist yet."""
    if not path.exists():
        return {}
    return dict(json.loads(path.read_text())["runs"])


def save_results(path: Path, runs: dict[str, dict[str, Any]], meta: dict[str, Any], merge: bool = True) -> None:
    """Merge ``runs`` into the file under a lock and replace it atomically: a kill mid-write loses nothing, and two
    benchmark processes given disjoint seeds (more parallel runs on a shared machine) may share one file.
    ``merge=False`` writes exactly ``runs`` (dropping runs of other settings)."""
    import fcntl

    with open(_lock_path(path), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        merged = {**load_results(path), **runs} if merge else dict(runs)
        ordered = dict(sorted(merged.items(), key=lambda kv: (kv[1]["algo"], kv[1]["seed"])))
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({**meta, "runs": ordered}, indent=1))
        os.replace(tmp, path)


def _lock_path(path: Path) -> Path:
    """A lock file for ``path`` in the temp folder (not beside results.json, which is committed)."""
    import hashlib
    import tempfile

    digest = hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / f"hrtc-benchmark-{digest}.lock"


def is_same_run(result: dict[str, Any], spec: RunSpec) -> bool:
    """The stored result answers ``spec``: same settings; a screened solve rule must have been run as such."""

    def plain(value: Any) -> Any:  # as JSON stores it (tuples become lists)
        return json.loads(json.dumps(value))

    same = all(result.get(k) == plain(getattr(spec, k)) for k in SAME_RUN if k in result)
    return same and (not spec.confirms or all(result.get(k) == getattr(spec, k) for k in CORE))


def resolve_backend(backend: str, ray_address: str | None = None) -> str:
    """``ray`` or ``process`` for ``backend`` (``auto``: Ray when installed); :class:`ConfigError` when it cannot be."""
    if backend not in BACKENDS:
        raise ConfigError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    if backend == "auto":
        backend = "ray" if ray_available() else "process"
    if backend == "ray" and not ray_available():
        raise ConfigError('backend=ray needs Ray: pip install "hrtc[ray]"')
    if backend == "process" and ray_address:
        raise ConfigError("ray_address needs backend=ray (or auto with Ray installed)")
    return backend


def execute(
    specs: Sequence[RunSpec],
    results_path: Path,
    meta: dict[str, Any],
    backend: str = "auto",
    ray_address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    fn: Callable[[RunSpec], dict[str, Any]] = run,
) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """Run every spec not already in ``results_path``; returns (results by key, errors by key).

    ``backend``: ``ray`` (``ray_address`` None starts a local Ray with ``num_cpus``), ``process`` (a pool of
    ``num_cpus // cpus`` processes) or ``auto`` (Ray when installed). A failed run is reported and left out; the
    others go on.
    """
    backend = resolve_backend(backend, ray_address)
    results_path.parent.mkdir(parents=True, exist_ok=True)
    stored = load_results(results_path)
    done = {s.key: stored[s.key] for s in specs if s.key in stored and is_same_run(stored[s.key], s)}
    pending = [s for s in specs if s.key not in done]
    errors: dict[str, str] = {}
    bar = _bar(len(specs), len(done), progress)
    _say(bar, f"{len(specs)} runs: {len(done)} already in {results_path}, {len(pending)} to run ({backend})")
    submit = _ray_jobs if backend == "ray" else _pool_jobs
    tic = time.perf_counter()
    for spec, result, error in submit(pending, fn, ray_address, num_cpus):
        count = f"{len(done) + len(errors) + 1}/{len(specs)}"
        if error is None:
            done[spec.key] = result
            # Merged into the file: runs stored with other settings (another budget...) stay until replaced.
            save_results(results_path, {spec.key: result}, meta)
            curve, minutes = result["curve"], (time.perf_counter() - tic) / 60
            _say(bar, f"{count} done {spec.key}: {result['env_steps']:,} env steps, "
                      f"eval {curve['episode_reward'][-1]:.1f} (best {max(curve['episode_reward']):.1f}), "
                      f"{result['wall_seconds']:.0f} s; {minutes:.1f} min since start")  # fmt: skip
        else:
            errors[spec.key] = error
            _say(bar, f"{count} FAILED {spec.key}: {error.splitlines()[-1] if error else '?'}")
        if bar is not None:
            bar.update(1)
            bar.set_postfix(failed=len(errors), elapsed=f"{(time.perf_counter() - tic) / 60:.1f} min")
    if bar is not None:
        bar.close()
    return {s.key: done[s.key] for s in specs if s.key in done}, errors


Job = Iterator[tuple[RunSpec, dict[str, Any] | None, str | None]]


def _ray_jobs(specs: Sequence[RunSpec], fn: Callable, address: str | None, num_cpus: int | None) -> Job:
    """One Ray task per run, each asking for ``spec.cpus`` CPUs; yields runs as they finish."""
    if not specs:
        return
    import ray

    started = not ray.is_initialized()
    if started:
        if address:
            # The cluster's nodes need the project's packages: Ray ships these three folders with the job (by path:
            # the core imports no skill module).
            root = Path(__file__).resolve().parents[2]
            modules = [str(root / name) for name in ("hrtc", "envs", "skills")]
            ray.init(address=address, runtime_env={"py_modules": modules}, log_to_driver=False)
        else:
            # Ray renices its workers by +15 by default; the runs are the work here, so they keep the driver's
            # niceness (start the benchmark with `nice` to yield to other jobs).
            os.environ.setdefault("RAY_worker_niceness", "0")
            # address="local": a Ray of its own, even when `ray start` left a cluster that ray.init() would join.
            ray.init(address="local", num_cpus=num_cpus or os.cpu_count(), include_dashboard=False,
                     log_to_driver=False)  # fmt: skip
    try:
        task = ray.remote(fn)
        refs = {task.options(num_cpus=s.cpus, max_retries=1, name=s.key).remote(s): s for s in specs}
        while refs:
            # A timeout, so that Ctrl-C and SIGTERM are handled between waits (a blocking wait ignores them).
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            if not ready:
                continue
            spec = refs.pop(ready[0])
            try:
                yield spec, ray.get(ready[0]), None
            except Exception as error:  # noqa: BLE001  (a run's failure is reported; the others go on)
                yield spec, None, _describe(error)
    finally:
        if started:
            ray.shutdown()


def _pool_jobs(specs: Sequence[RunSpec], fn: Callable, address: str | None, num_cpus: int | None) -> Job:
    """Without Ray: a pool of fresh (spawned) processes, as many as the CPUs hold runs of ``spec.cpus``."""
    if not specs:
        return
    import multiprocessing

    workers = max(1, (num_cpus or os.cpu_count() or 1) // max(s.cpus for s in specs))
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=die_with_parent) as pool:
        futures = {pool.submit(run_unless_orphaned, fn, s): s for s in specs}
        while futures:
            ready, _ = wait(list(futures), return_when=FIRST_COMPLETED)
            for future in ready:
                spec = futures.pop(future)
                try:
                    yield spec, future.result(), None
                except Exception as error:  # noqa: BLE001
                    yield spec, None, _describe(error)


_PARENT: int | None = None  # in a pool worker: the benchmark's pid, recorded by die_with_parent


def die_with_parent() -> None:
    """A pool worker's initializer: on Linux, the kernel sends the worker SIGTERM when the benchmark that started it
    dies, by ``kill`` or a crash as well as by Ctrl-C (``PR_SET_PDEATHSIG``). A run in progress then stops as a
    stopped run does (the trainer saves its checkpoint) and :func:`run_unless_orphaned` ends the worker, instead of
    the run going on with no one to take its result, on a CPU the next benchmark's runs would share. Elsewhere only
    the parent is recorded."""
    global _PARENT
    _PARENT = os.getppid()
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != _PARENT:  # the benchmark died before the call above: nothing will signal, so end now
        os.kill(os.getpid(), signal.SIGTERM)


def run_unless_orphaned(fn: Callable[[RunSpec], Any], spec: RunSpec) -> Any:
    """``fn(spec)`` in a pool worker; if the benchmark died meanwhile, the worker exits once the run has stopped
    (its checkpoint written): an idle worker of a dead pool would otherwise wait for work forever."""
    try:
        return fn(spec)
    finally:
        if _PARENT is not None and os.getppid() != _PARENT:
            os._exit(1)


def _describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


def _bar(total: int, initial: int, enabled: bool) -> Any:
    # A bar only on a terminal: in a log file its redraws are noise, and the numbered lines say the same.
    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc="benchmark runs", unit="run", dynamic_ncols=True)


def _say(bar: Any, message: str) -> None:
    stamp = time.strftime("%H:%M:%S")
    if bar is not None:
        bar.write(f"[{stamp}] {message}")
    else:
        print(f"[{stamp}] {message}", flush=True)
