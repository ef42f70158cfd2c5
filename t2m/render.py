"""``python -m t2m.render IN.npy OUT.mp4|gif|png``: render a motion file with the project's renderer.

The renderer itself is :mod:`dataset_tools.viz` (torch-free, shared with the dataset tools); its
names are re-exported here for existing callers.
"""

from __future__ import annotations

from dataset_tools.humanml3d import read_joints
from dataset_tools.viz import (
    FORMATS,
    RenderConfig,
    render_animation,
    render_contact_sheet,
    render_frames,
    render_keyframes,
)

__all__ = [
    "FORMATS",
    "RenderConfig",
    "main",
    "render_animation",
    "render_contact_sheet",
    "render_frames",
    "render_keyframes",
]


def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.render IN.npy OUT.mp4|gif|png [--caption TEXT]``: render a motion file
    (joints (T, J, 3) or features (T, D)); PNG gives a key-frame strip."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(
        prog="python -m t2m.render",
        description="Render joints (T, J, 3) or features (T, D) from a .npy file as an mp4 or "
        "gif stick-figure animation, or a PNG strip of key frames.",
    )
    parser.add_argument("input", help=".npy joints (T, J, 3), metres, y-up, or features (T, D)")
    parser.add_argument("output", help="output file: .mp4, .gif or .png (key-frame strip)")
    parser.add_argument("--caption", default="", help="title shown above the figure")
    parser.add_argument("--fps", type=float, default=20.0, help="frames per second (default 20)")
    parser.add_argument("--keyframes", type=int, default=6, help="panels of a PNG strip")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        joints = read_joints(args.input)
        if args.output.lower().endswith(".png"):
            render_keyframes(joints, args.output, args.caption, args.keyframes, args.fps)
        else:
            render_animation(joints, args.output, args.caption, args.fps)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
