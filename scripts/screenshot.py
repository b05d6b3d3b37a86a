"""A screenshot of Rerun's own viewer on a recording, made with no display (headless, on the CPU).

    python scripts/screenshot.py <run_dir or recording.rrd> [--out viewer.png] [--env-step N] [--settle 5]

Opens the recording on its stored layout (for a run directory: its first segment) in ``rerun --headless`` and saves
what the viewer draws. Needs a Vulkan driver: on a machine without a GPU, Mesa's lavapipe
(``apt-get install mesa-vulkan-drivers``; ``WGPU_BACKEND=vulkan`` is set for you).
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
    parser.add_argument("path", help="a run directory or one .rrd file")
    parser.add_argument("--out", default="viewer.png", help="where to write the PNG (default: viewer.png)")
    parser.add_argument("--env-step", type=int, help="move the time cursor here first (default: the end)")
    parser.add_argument("--settle", type=float, default=5.0, help="seconds to let the viewer load and draw")
    args = parser.parse_args(argv)
    from hrtc.logging.rerun_sink import screenshot
    from hrtc.review import recording_paths

    try:
        out = screenshot(recording_paths(args.path)[0], args.out, settle_s=args.settle, env_step=args.env_step)
    except HRTCError as error:
        fail(str(error))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
