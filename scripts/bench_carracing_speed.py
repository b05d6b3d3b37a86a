"""Speed and frame equivalence of the fast CarRacing against gymnasium's, side by side in one process.

    python scripts/bench_carracing_speed.py [--tracks 6] [--steps 300] [--out benchmarks/results/carracing/speed]

On each track gymnasium's ``CarRacing`` and :class:`~envs.carracing.FastCarRacing` (both drawing a 96x96 RGB frame
every step) take the same actions in interleaved timed blocks (``--block`` steps of gymnasium's, then the same steps
of the fast env), so both see the same machine load within seconds, and each runs with its own caches warm as in use
(stepped one call apart, whichever runs second pays for the other's cache footprint). The speed ratio is
gymnasium's total step time over the fast one's, in wall time and in the stepping thread's CPU time (on a crowded
machine wall time also counts waits in the run queue). Outside the
timed calls every frame pair is compared (mean absolute difference of the RGB frames, and of gymnasium's frame in
grey against the grey rasteriser's; the share of pixels more than 16 levels apart) and rewards and termination are
checked for equality. Then the ``carracing`` task as trained (grey, 4-frame stack, action repeat 8: one frame drawn
per 8 physics frames) runs the same number of frames, timed, for its frames per second. Writes speed.json, speed.md,
command.txt and machine.txt into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FAR_PIXELS = 16


def run(args: argparse.Namespace) -> dict:
    from gymnasium.envs.box2d.car_racing import CarRacing

    import envs
    from envs.car_raster import GREY_WEIGHTS
    from envs.carracing import FastCarRacing
    from envs.carracing import pursuit_driver as driver

    ref, fast, fast_grey = CarRacing(), FastCarRacing(), FastCarRacing(grey=True)
    task = envs.make("carracing", action_repeat=8)
    fast.reset(seed=999)  # load the compiled rasteriser before timing
    task.reset(seed=999)
    tracks = []
    for k in range(args.tracks):
        seed, mode = 100 + k, ("road", "wild")[k % 3 == 2]
        rng = np.random.default_rng(seed)
        t0, c0 = time.perf_counter(), time.thread_time()
        ref_frame = ref.reset(seed=seed)[0]
        t1, c1 = time.perf_counter(), time.thread_time()
        fast_frame = fast.reset(seed=seed)[0]
        t2, c2 = time.perf_counter(), time.thread_time()
        gym_cpu, fast_cpu = c1 - c0, c2 - c1
        grey_frame = fast_grey.reset(seed=seed)[0]
        gym_time, fast_time = t1 - t0, t2 - t1
        driver_time = driver_cpu = 0.0
        rgb, grey, far, mismatches = [], [], [], 0
        done = False
        while len(rgb) < args.steps and not done:
            # A block of gymnasium's steps, then the same actions through the fast env: each runs warm, as in use.
            block = min(args.block, args.steps - len(rgb))
            actions, ref_out = [], []
            t0, c0 = time.perf_counter(), time.thread_time()
            for _ in range(block):
                d0, e0 = time.perf_counter(), time.thread_time()
                action = driver(ref, rng, mode)
                d1, e1 = time.perf_counter(), time.thread_time()
                driver_time, driver_cpu = driver_time + d1 - d0, driver_cpu + e1 - e0  # not gymnasium's: taken off
                actions.append(action)
                ref_out.append(ref.step(action))
                if ref_out[-1][2]:
                    break
            t1, c1 = time.perf_counter(), time.thread_time()
            fast_out = [fast.step(action) for action in actions]
            t2, c2 = time.perf_counter(), time.thread_time()
            gym_time, gym_cpu = gym_time + t1 - t0 - driver_time, gym_cpu + c1 - c0 - driver_cpu
            driver_time = driver_cpu = 0.0
            fast_time, fast_cpu = fast_time + t2 - t1, fast_cpu + c2 - c1
            for action, (ref_frame, r1, term1, trunc1, _), (fast_frame, r2, term2, trunc2, _) in zip(
                actions, ref_out, fast_out, strict=True
            ):
                grey_frame = fast_grey.step(action)[0]  # the grey rasteriser the task uses (untimed)
                diff = np.abs(ref_frame.astype(int) - fast_frame)
                rgb.append(diff.mean())
                grey.append(np.abs(np.floor(ref_frame @ GREY_WEIGHTS + 0.5) - grey_frame).mean())
                far.append((diff.max(-1) > FAR_PIXELS).mean())
                mismatches += int((r1, term1, trunc1) != (r2, term2, trunc2))
                done = done or term1 or term2
        # The task as trained, the same number of frames, right after gymnasium's steps on this track.
        t0 = time.perf_counter()
        task.reset(seed=seed)
        task_frames = 0
        while task_frames < args.steps:
            _, _, terminated, truncated, info = task.step(driver(task, rng, mode))
            task_frames = info["frames"]
            if terminated or truncated:
                break
        task_time = time.perf_counter() - t0
        steps = len(rgb)
        tracks.append({
            "seed": seed, "driver": mode, "steps": steps, "tiles_visited": int(ref.tile_visited_count),
            "gym_steps_per_s": (steps + 1) / gym_time, "fast_steps_per_s": (steps + 1) / fast_time,
            "ratio": gym_time / fast_time, "cpu_ratio": gym_cpu / fast_cpu,
            "gym_cpu_s": gym_cpu, "fast_cpu_s": fast_cpu, "task_frames_per_s": task_frames / task_time,
            "reward_or_termination_mismatches": mismatches,
            "rgb_mean_abs": float(np.mean(rgb)), "rgb_worst_frame": float(np.max(rgb)),
            "grey_mean_abs": float(np.mean(grey)), "grey_worst_frame": float(np.max(grey)),
            "far_pixel_share_worst_frame": float(np.max(far)), "loadavg_1min": os.getloadavg()[0],
        })  # fmt: skip
        print(f"  track {seed} ({mode}): ratio {tracks[-1]['ratio']:.1f}, rgb diff {tracks[-1]['rgb_mean_abs']:.3f}",
              flush=True)  # fmt: skip
    gym_total = sum((t["steps"] + 1) / t["gym_steps_per_s"] for t in tracks)
    fast_total = sum((t["steps"] + 1) / t["fast_steps_per_s"] for t in tracks)
    steps_total = sum(t["steps"] + 1 for t in tracks)
    return {
        "tracks": tracks,
        "ratio": gym_total / fast_total,
        "cpu_ratio": sum(t["gym_cpu_s"] for t in tracks) / sum(t["fast_cpu_s"] for t in tracks),
        "cpu_ratio_per_track_min": float(np.min([t["cpu_ratio"] for t in tracks])),
        "ratio_per_track_median": float(np.median([t["ratio"] for t in tracks])),
        "ratio_per_track_min": float(np.min([t["ratio"] for t in tracks])),
        "gym_steps_per_s": steps_total / gym_total,
        "fast_steps_per_s": steps_total / fast_total,
        "task_frames_per_s_median": float(np.median([t["task_frames_per_s"] for t in tracks])),
        "rgb_mean_abs": float(np.mean([t["rgb_mean_abs"] for t in tracks])),
        "rgb_worst_frame": float(np.max([t["rgb_worst_frame"] for t in tracks])),
        "grey_mean_abs": float(np.mean([t["grey_mean_abs"] for t in tracks])),
        "grey_worst_frame": float(np.max([t["grey_worst_frame"] for t in tracks])),
        "far_pixel_share_worst_frame": float(np.max([t["far_pixel_share_worst_frame"] for t in tracks])),
        "mismatches": int(sum(t["reward_or_termination_mismatches"] for t in tracks)),
        "samples_per_pixel": fast.raster.samples**2,
        "block": args.block,
    }


def write(result: dict, out: Path, command: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.json").write_text(json.dumps(result, indent=1))
    (out / "command.txt").write_text(command + "\n")
    from hrtc.benchmark.report import machine_info

    (out / "machine.txt").write_text(machine_info())
    lines = [
        "# CarRacing: fast frames against gymnasium's, side by side",
        "",
        f"{len(result['tracks'])} tracks, the same actions, timed in interleaved blocks of {result['block']} steps "
        "(1-minute load "
        f"average {min(t['loadavg_1min'] for t in result['tracks']):.1f}-"
        f"{max(t['loadavg_1min'] for t in result['tracks']):.1f} on 2 cores: absolute rates are this shared "
        "machine's, the ratio is the figure). Frames 96x96, values 0-255.",
        "",
        "| figure | value |",
        "|---|---|",
        f"| speed ratio, fast / gymnasium, every step drawn (all tracks' time) | **{result['ratio']:.1f}x** "
        f"(per track: median {result['ratio_per_track_median']:.1f}x, lowest {result['ratio_per_track_min']:.1f}x) |",
        f"| the same in CPU time of the stepping thread (no run-queue waits) | **{result['cpu_ratio']:.1f}x** "
        f"(lowest track {result['cpu_ratio_per_track_min']:.1f}x) |",
        f"| gymnasium `CarRacing` steps/s | {result['gym_steps_per_s']:.0f} |",
        f"| `FastCarRacing` steps/s | {result['fast_steps_per_s']:.0f} |",
        f"| `carracing` task (grey, 4-stack, action repeat 8) physics frames/s | "
        f"{result['task_frames_per_s_median']:.0f} |",
        f"| reward or termination mismatches | {result['mismatches']} |",
        f"| mean abs pixel difference, RGB / grey | {result['rgb_mean_abs']:.3f} / {result['grey_mean_abs']:.3f} |",
        f"| worst frame's mean abs difference, RGB / grey | {result['rgb_worst_frame']:.3f} / "
        f"{result['grey_worst_frame']:.3f} |",
        f"| largest share of a frame's pixels more than {FAR_PIXELS} levels apart | "
        f"{100 * result['far_pixel_share_worst_frame']:.2f}% |",
        f"| rasteriser samples per pixel | {result['samples_per_pixel']} |",
        "",
        "| track | driver | steps | tiles | gym steps/s | fast steps/s | ratio | CPU ratio | task frames/s | RGB diff "
        "| grey diff |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in result["tracks"]:
        lines.append(
            f"| {t['seed']} | {t['driver']} | {t['steps']} | {t['tiles_visited']} | {t['gym_steps_per_s']:.0f} | "
            f"{t['fast_steps_per_s']:.0f} | {t['ratio']:.1f} | {t['cpu_ratio']:.1f} | {t['task_frames_per_s']:.0f} | "
            f"{t['rgb_mean_abs']:.3f} | {t['grey_mean_abs']:.3f} |"
        )
    (out / "speed.md").write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", type=int, default=6)
    parser.add_argument("--steps", type=int, default=300, help="steps per track (from each track's start)")
    parser.add_argument("--block", type=int, default=25, help="steps per timed block (gymnasium's, then the fast)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "carracing" / "speed")
    args = parser.parse_args()
    result = run(args)
    write(result, args.out, "python scripts/bench_carracing_speed.py " + " ".join(sys.argv[1:]))
    print((args.out / "speed.md").read_text())


if __name__ == "__main__":
    main()
