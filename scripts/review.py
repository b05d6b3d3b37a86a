"""Review a run's skill activations offline, from its Rerun recording alone.

    python scripts/review.py <run_dir or recording.rrd> [--out activations.png] [--panels 6]

Prints, per evaluation episode, each skill's mean weight, its share of decisions as the dominant skill and its mean
alpha + beta (the meta-policy's confidence), and writes activations.png (weights over time, with the return).
Works on a run that is still going or was killed (the episodes finished so far).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a clone without installing

from hrtc.cli import fail  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("path", help="a run directory (all its recording segments) or one .rrd file")
    parser.add_argument("--out", help="where to write the plot (default: activations.png beside the recording)")
    parser.add_argument("--panels", type=int, default=6, help="episodes to plot (first, best, last, spaced)")
    args = parser.parse_args(argv)
    from hrtc import review

    try:
        data = review.load(args.path)
    except HRTCError as error:
        fail(str(error))
    summary = review.summarize(data)
    print(f"{len(summary)} evaluation episodes in {', '.join(str(p) for p in data.paths)}")
    print(review.format_summary(summary, data.skill_names))
    out = Path(args.out) if args.out else data.paths[0].parent / "activations.png"
    review.plot_activations(data, out, args.panels)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
