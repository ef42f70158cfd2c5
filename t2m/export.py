"""``python -m t2m.export IN.npy OUT.bvh``: joints or features to a BVH file of the SMPL skeleton.

The BVH writer (IK with its twist choice, the file text) is :mod:`dataset_tools.bvh`; its names
are re-exported here for existing callers.
"""

from __future__ import annotations

from dataset_tools.bvh import (
    UNITS,
    BvhMotion,
    forward_kinematics,
    motion_from_joints,
    rest_directions,
    solve_rotations,
    write_bvh,
)
from dataset_tools.humanml3d import read_joints

__all__ = [
    "UNITS",
    "BvhMotion",
    "forward_kinematics",
    "main",
    "motion_from_joints",
    "rest_directions",
    "solve_rotations",
    "write_bvh",
]


def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.export IN.npy OUT.bvh``: joints (T, 22, 3) or features (T, 263) to BVH."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(
        prog="python -m t2m.export",
        description="Write joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263) from "
        "a .npy file as a BVH file of the 22-joint SMPL skeleton.",
    )
    parser.add_argument("input", help=".npy joints (T, 22, 3) or features (T, 263)")
    parser.add_argument("output", help="output .bvh file")
    parser.add_argument("--fps", type=float, default=20.0, help="frames per second (default 20)")
    parser.add_argument("--units", choices=sorted(UNITS), default="cm", help="default cm")
    parser.add_argument("--template-rest-pose", action="store_true",
                        help="use the template hips / collars instead of fitting them")  # fmt: skip
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        write_bvh(read_joints(args.input), args.output, fps=args.fps, units=args.units,
                  fit_rest_pose=not args.template_rest_pose)  # fmt: skip
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
