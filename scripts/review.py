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

from hrtc import cli  # noqa: E402
from hrtc.errors import HRTCError  # noqa: E402

PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def main(argv: list[str] | None = None) -> None:
    parser = cli.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("path", help="a run directory (all its recording segments) or one .rrd file")
    parser.add_argument("--out", help="where to write the plot (default: activations.png beside the recording)")
    parser.add_argument("--panels", type=int, default=6, help="episodes to plot (first, best, last, spaced)")
    parsed = parser.parse_args(argv)
    args = cli.validate({"path": parsed.path, "--out": parsed.out, "--panels": parsed.panels},
                        {"path": _existing, "--out": cli.optional(cli.output_path(False, PLOT_SUFFIXES)),
                         "--panels": cli.integer(1, 100)})  # fmt: skip
    from hrtc import review

    try:
        data = review.load(args["path"])
        out = args["--out"] or cli.output_path(False, PLOT_SUFFIXES)("--out", data.paths[0].parent / "activations.png")
    except HRTCError as error:
        cli.fail(str(error))
    summary = review.summarize(data)
    print(f"{len(summary)} evaluation episodes in {', '.join(str(p) for p in data.paths)}")
    print(review.format_summary(summary, data.skill_names))
    review.plot_activations(data, out, args["--panels"])
    print(f"wrote {out}")


def _existing(name: str, value: str) -> Path:
    """A run directory or a readable recording file."""
    path = Path(value)
    return path if path.is_dir() else cli.input_file(name, path)


if __name__ == "__main__":
    main()
