"""The renderer: stick-figure mp4 / gif animations, key-frame PNG strips and contact sheets.

This is the project's one renderer (numpy + matplotlib, no torch): ``t2m.render`` is its command
line, and the demo corpus' contact sheets (``dataset_tools.synth.contact_sheet``) use it too.

Joints are ``(T, J, 3)`` arrays in metres, y-up, a person facing +Z has their left side at +X
(the HumanML3D convention). Matplotlib draws z up, so world ``(x, y, z)`` is drawn at
``(x, -z, y)`` (:func:`dataset_tools.rotations.y_up_to_z_up`): a proper rotation, so left and
right are never mirrored on screen.

Figures are drawn on an Agg canvas directly (no pyplot, no GUI backend), so rendering works on
headless machines and never changes the user's matplotlib backend; mp4 goes through the ffmpeg binary bundled with
``imageio-ffmpeg`` and gif through Pillow. Files are written atomically (temp file, then rename).
"""

from __future__ import annotations

import logging
import os
import textwrap
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from dataset_tools.io import atomic_output
from dataset_tools.rotations import y_up_to_z_up
from dataset_tools.skeleton import SkeletonSpec, skeleton_for

logger = logging.getLogger(__name__)

FORMATS = ("mp4", "gif")


@dataclass(frozen=True)
class RenderConfig:
    """How a motion is drawn.

    Attributes:
        size_px: width and height of each frame in pixels (even, for the H.264 encoder).
        elevation / azimuth: camera angles in degrees; azimuth -90 looks at a +Z-facing person
            from the front.
        view_radius: half-width in metres of the cube the camera shows around the root.
        follow_root: centre every frame on the root (ground and trajectory scroll beneath it);
            otherwise one fixed view holds the whole motion.
        left_color / right_color / center_color: colours of the left, right and middle chains.
        line_width: width of the bones in points.
        grid_step: spacing of the ground grid in metres.
        caption_width: characters per line of the wrapped caption.
        mp4_quality: ffmpeg quality knob passed to imageio-ffmpeg (0..10, 10 is best).
        zoom: how much of the frame the 3D box fills (matplotlib leaves wide margins at 1).
        highlight_color: colour of the bones a ``highlight`` mask marks (an edit's kept parts).
    """

    size_px: int = 480
    elevation: float = 20.0
    azimuth: float = -70.0
    view_radius: float = 1.1
    follow_root: bool = True
    left_color: str = "#1f6fd1"
    right_color: str = "#d6402b"
    center_color: str = "#333333"
    line_width: float = 3.0
    grid_step: float = 0.5
    caption_width: int = 44
    mp4_quality: float = 7.0
    zoom: float = 1.5
    highlight_color: str = "#2ca02c"


def _check_joints(joints: np.ndarray) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[-1] != 3 or joints.shape[0] < 1:
        raise ValueError(f"joints must be (T, J, 3) with T >= 1, got shape {joints.shape}")
    if not np.isfinite(joints).all():
        raise ValueError("joints contain NaN or infinite values")
    return joints


def _chain_side(chain: Sequence[int], skeleton: SkeletonSpec) -> str:
    """'left', 'right' or 'center' from the joint names of a chain (its first joint is shared)."""
    names = [skeleton.joint_names[j] for j in chain[1:]]
    for side in ("left", "right"):
        # SMPL spells the side out (left_knee); KIT prefixes L / R (LS, LE, RK, ...).
        if all(name.lower().startswith(side) or name[:1] == side[0].upper() for name in names):
            return side
    return "center"


def _wrap(caption: str, width: int) -> str:
    return "\n".join(textwrap.wrap(caption.strip(), width=width)) if caption.strip() else ""


def _grid_segments(center_xz: np.ndarray, radius: float, step: float) -> np.ndarray:
    """Ground grid lines (N, 2, 3) in plot coordinates covering [center - radius, center + radius]."""
    lo = center_xz - radius
    hi = center_xz + radius
    xs = np.arange(np.ceil(lo[0] / step), np.floor(hi[0] / step) + 1) * step
    zs = np.arange(np.ceil(lo[1] / step), np.floor(hi[1] / step) + 1) * step
    segments = [[[x, 0.0, lo[1]], [x, 0.0, hi[1]]] for x in xs]
    segments += [[[lo[0], 0.0, z], [hi[0], 0.0, z]] for z in zs]
    if not segments:
        return np.zeros((0, 2, 3))
    return y_up_to_z_up(np.asarray(segments, dtype=np.float64))


class _StickFigure:
    """One 3D axes holding a skeleton, its ground grid and the root trajectory; updated per frame."""

    def __init__(
        self,
        ax,
        joints: np.ndarray,
        skeleton: SkeletonSpec,
        config: RenderConfig,
        show_trajectory: bool = True,
        highlight: np.ndarray | None = None,
    ) -> None:
        self.ax = ax
        self.highlight = highlight
        self.joints = joints
        self.config = config
        self.floor = float(joints[..., 1].min())
        root_xz = joints[:, 0, [0, 2]]
        if config.follow_root:
            self.radius = config.view_radius
            self.centers = root_xz
        else:
            lo, hi = (
                joints[..., [0, 2]].reshape(-1, 2).min(0),
                joints[..., [0, 2]].reshape(-1, 2).max(0),
            )
            self.radius = max(config.view_radius, 0.55 * float((hi - lo).max()))
            self.centers = np.repeat(((lo + hi) / 2)[None], len(joints), axis=0)
        colors = {
            "left": config.left_color,
            "right": config.right_color,
            "center": config.center_color,
        }
        ax.set_axis_off()
        ax.view_init(elev=config.elevation, azim=config.azimuth)
        ax.set_box_aspect((1, 1, 1), zoom=config.zoom)
        self.grid = Line3DCollection(np.zeros((0, 2, 3)), colors="#b0b0b0", linewidths=0.6)
        ax.add_collection3d(self.grid, autolim=False)
        self.trajectory = None
        if show_trajectory:
            (self.trajectory,) = ax.plot([], [], [], color="#7a7a7a", linewidth=1.2, alpha=0.8)
        self.chains = []
        for chain in skeleton.chains:
            side = _chain_side(chain, skeleton)
            (line,) = ax.plot(
                [],
                [],
                [],
                color=colors[side],
                linewidth=config.line_width,
                solid_capstyle="round",
                marker="o",
                markersize=2.5,
            )
            self.chains.append((np.asarray(chain), line))
        self.highlighted = []
        if highlight is not None:
            for _ in skeleton.chains:
                (line,) = ax.plot(
                    [],
                    [],
                    [],
                    color=config.highlight_color,
                    linewidth=config.line_width,
                    solid_capstyle="round",
                    marker="o",
                    markersize=2.5,
                )
                self.highlighted.append(line)

    def update(self, frame: int) -> None:
        center = self.centers[frame]
        radius = self.radius
        pose = self.joints[frame].copy()
        pose[:, 1] -= self.floor
        for index, (chain, line) in enumerate(self.chains):
            pts = y_up_to_z_up(pose[chain])
            if self.highlight is None:
                line.set_data_3d(pts[:, 0], pts[:, 1], pts[:, 2])
                continue
            # A bone is highlighted when both its ends are; each set is drawn as separate
            # bones (NaN rows break the line between them).
            kept = self.highlight[frame][chain]
            bone_kept = kept[:-1] & kept[1:]
            for lines, chosen in ((line, ~bone_kept), (self.highlighted[index], bone_kept)):
                bones = np.flatnonzero(chosen)
                segments = np.full((len(bones), 3, 3), np.nan)
                segments[:, 0], segments[:, 1] = pts[bones], pts[bones + 1]
                flat = segments.reshape(-1, 3)
                lines.set_data_3d(flat[:, 0], flat[:, 1], flat[:, 2])
        self.grid.set_segments(_grid_segments(center, radius, self.config.grid_step))
        if self.trajectory is not None:
            past = self.joints[: frame + 1, 0].copy()
            past[:, 1] = 0.0
            inside = np.abs(past[:, [0, 2]] - center).max(axis=1) <= radius
            past[~inside] = np.nan  # matplotlib 3D does not clip to the axes box
            pts = y_up_to_z_up(past)
            self.trajectory.set_data_3d(pts[:, 0], pts[:, 1], pts[:, 2])
        plot_center = y_up_to_z_up(np.array([center[0], 0.0, center[1]]))
        self.ax.set_xlim(plot_center[0] - radius, plot_center[0] + radius)
        self.ax.set_ylim(plot_center[1] - radius, plot_center[1] + radius)
        # Lift the box so a standing body fills the middle of the frame rather than its bottom.
        self.ax.set_zlim(-0.55 * radius, 1.45 * radius)


def _check_highlight(highlight: np.ndarray | None, joints: np.ndarray) -> np.ndarray | None:
    """A (T, J) bool mask of the joints to draw in the highlight colour, or None."""
    if highlight is None:
        return None
    highlight = np.asarray(highlight, dtype=bool)
    if highlight.shape != joints.shape[:2]:
        raise ValueError(f"highlight must be (T, J) = {joints.shape[:2]}, got {highlight.shape}")
    return highlight


def _prepare(joints: np.ndarray, skeleton: SkeletonSpec | None) -> tuple[np.ndarray, SkeletonSpec]:
    joints = _check_joints(joints)
    skeleton = skeleton or skeleton_for(joints.shape[1])
    if joints.shape[1] != skeleton.num_joints:
        raise ValueError(
            f"joints have {joints.shape[1]} joints but skeleton {skeleton.name!r} has "
            f"{skeleton.num_joints}"
        )
    return joints, skeleton


def render_frames(
    joints: np.ndarray,
    caption: str = "",
    fps: float = 20.0,
    skeleton: SkeletonSpec | None = None,
    config: RenderConfig | None = None,
    highlight: np.ndarray | None = None,
) -> Iterator[np.ndarray]:
    """Yield the animation of joints (T, J, 3) frame by frame as (H, W, 3) uint8 RGB images
    (``highlight``: (T, J) bool, bones between two marked joints in ``highlight_color``)."""
    joints, skeleton = _prepare(joints, skeleton)
    highlight = _check_highlight(highlight, joints)
    config = config or RenderConfig()
    dpi = 100
    fig = Figure(figsize=(config.size_px / dpi, config.size_px / dpi), dpi=dpi)
    canvas = FigureCanvasAgg(fig)  # attaching the canvas is what lets the figure draw
    ax = fig.add_axes((0.0, 0.0, 1.0, 0.86 if caption else 0.95), projection="3d")
    figure = _StickFigure(ax, joints, skeleton, config, highlight=highlight)
    wrapped = _wrap(caption, config.caption_width)
    if wrapped:
        fig.suptitle(wrapped, fontsize=10, y=0.985, va="top")
    clock = fig.text(0.02, 0.02, "", fontsize=8, color="#555555")
    for frame in range(len(joints)):
        figure.update(frame)
        clock.set_text(f"{frame / fps:5.2f} s")
        canvas.draw()
        yield np.asarray(canvas.buffer_rgba())[..., :3].copy()


def render_animation(
    joints: np.ndarray,
    path: str | os.PathLike,
    caption: str = "",
    fps: float = 20.0,
    skeleton: SkeletonSpec | None = None,
    config: RenderConfig | None = None,
    highlight: np.ndarray | None = None,
) -> Path:
    """Render joints (T, J, 3) as a stick-figure animation; the format comes from the suffix.

    Args:
        joints: (T, J, 3) positions in metres, y-up.
        path: output file ending in ``.mp4`` or ``.gif``; written atomically.
        caption: text shown (wrapped) as the title.
        fps: frames per second of the motion and of the video.
        skeleton: the body; by default the one with J joints (SMPL for 22, KIT for 21).
        config: drawing options.
        highlight: (T, J) bool; bones between two marked joints are drawn in the config's
            ``highlight_color`` (an edit's kept parts).

    Returns:
        The path written.
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"unknown animation format {path.suffix!r}; use one of .mp4, .gif")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    joints, skeleton = _prepare(joints, skeleton)
    config = config or RenderConfig()
    if config.size_px % 2:
        raise ValueError(f"size_px must be even for video encoding, got {config.size_px}")
    highlight = _check_highlight(highlight, joints)
    frames = render_frames(joints, caption, fps, skeleton, config, highlight)
    with atomic_output(path) as tmp:
        if fmt == "mp4":
            _write_mp4(frames, str(tmp), fps, config)
        else:
            _write_gif(frames, str(tmp), fps)
    logger.debug("wrote %s (%d frames)", path, len(joints))
    return path


def _write_mp4(frames: Iterator[np.ndarray], target: str, fps: float, config: RenderConfig) -> None:
    import imageio_ffmpeg

    try:
        # The bundled binary, else $IMAGEIO_FFMPEG_EXE or the system's ffmpeg.
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:
        raise ValueError(
            "no ffmpeg found for mp4 (pip install imageio-ffmpeg, or render gif)"
        ) from None
    size = (config.size_px, config.size_px)
    writer = imageio_ffmpeg.write_frames(
        target,
        size,
        fps=fps,
        codec="libx264",
        pix_fmt_in="rgb24",
        pix_fmt_out="yuv420p",
        quality=config.mp4_quality,
        macro_block_size=1,
        # Bit-exact output for the same input: one encoder thread, no timestamp metadata.
        output_params=["-threads", "1", "-fflags", "+bitexact", "-map_metadata", "-1"],
        ffmpeg_log_level="error",
    )
    writer.send(None)  # start the generator
    try:
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()


def _write_gif(frames: Iterator[np.ndarray], target: str, fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    # One shared adaptive palette keeps the colours steady from frame to frame.
    palette = images[len(images) // 2].quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    quantized = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    quantized[0].save(
        target,
        format="GIF",
        save_all=True,
        append_images=quantized[1:],
        duration=round(1000 / fps),
        loop=0,
        optimize=False,
    )


def keyframe_indices(num_frames: int, num_keyframes: int) -> np.ndarray:
    """Up to ``num_keyframes`` evenly spaced frame indices of a ``num_frames``-frame motion."""
    if num_keyframes < 1:
        raise ValueError(f"num_keyframes must be >= 1, got {num_keyframes}")
    return np.unique(np.linspace(0, num_frames - 1, num_keyframes).round().astype(int))


def _draw_panels(
    fig: Figure,
    joints: np.ndarray,
    frames: np.ndarray,
    skeleton: SkeletonSpec,
    config: RenderConfig,
    fps: float,
    row: int = 0,
    rows: int = 1,
    highlight: np.ndarray | None = None,
) -> None:
    """One row of key-frame panels: every panel the same camera centred on that frame's root,
    with the ground grid, the root trajectory so far and the time in seconds beneath it."""
    columns = len(frames)
    for column, frame in enumerate(frames):
        ax = fig.add_subplot(rows, columns, row * columns + column + 1, projection="3d")
        _StickFigure(ax, joints, skeleton, config, highlight=highlight).update(int(frame))
        ax.set_title(f"{frame / fps:.2f} s", fontsize=9, y=0.0)


def render_keyframes(
    joints: np.ndarray,
    path: str | os.PathLike,
    caption: str = "",
    num_keyframes: int = 6,
    fps: float = 20.0,
    skeleton: SkeletonSpec | None = None,
    config: RenderConfig | None = None,
    highlight: np.ndarray | None = None,
    frames: Sequence[int] | None = None,
) -> Path:
    """Write a PNG strip of ``num_keyframes`` evenly spaced poses of joints (T, J, 3).

    Every panel uses the same camera centred on that frame's root, with the ground grid and the
    root trajectory so far, and the time in seconds beneath it. Written atomically.
    ``highlight``: (T, J) bool, drawn as in :func:`render_animation`; ``frames``: the frames to
    show instead of evenly spaced ones.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"key-frame strips are PNG files, got {path.suffix!r}")
    joints, skeleton = _prepare(joints, skeleton)
    highlight = _check_highlight(highlight, joints)
    if frames is None:
        frames = keyframe_indices(len(joints), num_keyframes)
    frames = np.asarray(frames, dtype=int)
    if frames.ndim != 1 or len(frames) == 0 or frames.min() < 0 or frames.max() >= len(joints):
        raise ValueError(f"frames must be indices into the {len(joints)} frames")
    config = config or RenderConfig()
    panel = 2.4
    fig = Figure(figsize=(panel * len(frames), panel + (0.6 if caption else 0.2)), dpi=100)
    canvas = FigureCanvasAgg(fig)
    _draw_panels(fig, joints, frames, skeleton, config, fps, highlight=highlight)
    wrapped = _wrap(caption, config.caption_width * len(frames) // 2)
    if wrapped:
        fig.suptitle(wrapped, fontsize=10)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.88 if caption else 1.0, wspace=0.0)
    with atomic_output(path) as tmp:
        canvas.print_png(str(tmp))
    return path


def render_contact_sheet(
    clips: Sequence[tuple[np.ndarray, str]],
    path: str | os.PathLike,
    frames_per_clip: int = 6,
    fps: float = 20.0,
    skeleton: SkeletonSpec | None = None,
    config: RenderConfig | None = None,
) -> Path:
    """Write a PNG grid: one row of ``frames_per_clip`` key frames per clip, its caption above.

    Args:
        clips: (joints (T, J, 3) metres y-up, caption) per row.
        path: the ``.png`` to write (atomically).
        frames_per_clip: key frames per row (evenly spaced in time).
        fps: frame rate of the clips (for the times under the panels).
        skeleton: the body; by default the one with J joints.
        config: drawing options (camera, colours).
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"contact sheets are PNG files, got {path.suffix!r}")
    if not clips:
        raise ValueError("no clips to draw")
    config = config or RenderConfig()
    prepared = [(*_prepare(joints, skeleton), caption) for joints, caption in clips]
    panel, rows = 2.0, len(prepared)
    fig = Figure(figsize=(panel * frames_per_clip, (panel + 0.45) * rows), dpi=80)
    canvas = FigureCanvasAgg(fig)
    for row, (joints, body, caption) in enumerate(prepared):
        frames = keyframe_indices(len(joints), frames_per_clip)
        _draw_panels(fig, joints, frames, body, config, fps, row, rows)
        top = 1.0 - row / rows
        text = _wrap(caption, config.caption_width * frames_per_clip // 2)
        fig.text(0.01, top - 0.005, text, fontsize=8, va="top")
    caption_space = 0.3 / (panel + 0.45) / rows  # of the figure's height, above the first row
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=1.0 - caption_space, hspace=0.25)
    fig.subplots_adjust(wspace=0.0)
    with atomic_output(path) as tmp:
        canvas.print_png(str(tmp))
    return path
