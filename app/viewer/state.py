"""The viewer's state by role, each a typed object the panels read and write: what the edit tools hold, the export
dialog's settings, the camera path being built, the training runs' settings and outputs, and the window's own
(where the 3D view is, frame timing, what is shown). ``ViewerApp`` owns one of each; nothing adds attributes to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

TOOLS = ("orbit", "rect", "brush", "lasso", "surface brush", "colour pick")  # the last two: select_tools_panel
REGIONS = ("all", "selection", "unselected")


@dataclass
class EditTools:
    tool: str = "orbit"  # what a left drag in the 3D view does: orbit | rect | brush | lasso
    select_mode: str = "set"
    brush_radius: float = 30.0
    gesture: list[tuple[float, float]] = field(default_factory=list)  # the drag under way (window coordinates)
    box: list | None = None  # [[x0, y0, z0], [x1, y1, z1]] typed in the panel (world units)
    box_typed_from: tuple | None = None  # the box when typing in its fields began (for the undo step)
    sphere: list | None = None  # [[x, y, z], radius]
    live: bool = False  # the editor edits the running trainer's model
    region: str = "all"  # which Gaussians a stylization may change: all | selection | unselected
    shown_version: int | None = None  # the editor version the view shows


@dataclass
class ExportSettings:
    format: str = "ply"  # ply | compressed-ply | splat | spz | glb
    sh_bands: int = 3
    spz_version: int = 4  # 4 (the current spec) or 3 for older readers
    selection_only: bool = False
    compact_sh: bool = False
    path: str = "viewer_out/export.ply"
    written: list[Path] = field(default_factory=list)  # files written, in order


@dataclass
class CameraPathState:
    keys: list = field(default_factory=list)  # app.camera_path.Keyframe
    seconds: float = 8.0
    fps: int = 30
    loop: bool = False
    file: str = "viewer_out/camera_path.json"
    size: list[int] = field(default_factory=lambda: [640, 360])
    video: str = "viewer_out/path.mp4"
    split: bool = False
    job: Any = None  # the video being rendered (path_panel.VideoJob)


@dataclass
class TrainingState:
    preset: str = "quick"  # reconstruction preset
    recon_iters: int | None = None
    downscale: int | None = None
    stylize: Any = None  # StylizeConfig of the next run (and the running one's live settings)
    refresh_s: float = 1.0  # how often the view takes the trainer's model
    pause_at: int = 0
    base_model: str = ""  # the model as opened or reconstructed: what a stylization starts from
    runs: list[Path] = field(default_factory=list)  # each stylization's saved model, in order
    continue_last_run: bool = False
    pending: list = field(default_factory=list)  # (what, Future, on done) handed to the running trainer
    shown_step: int | None = None  # the trainer step whose model the view shows


@dataclass
class ProjectState:
    path: str = ""  # the project file this session was opened from or last saved to
    opened: Any = None  # project_io.Opened: what the viewer does not hold itself (transform, colour, other models)
    layout_to_load: str = ""  # a project's dock layout, applied before the next frame


@dataclass
class WindowState:
    view_rect: tuple[int, int, int, int] = (0, 0, 1, 1)  # the 3D view in the window (logical pixels)
    view_hovered: bool = False
    frame_dt: float = 0.0
    fps: float = 0.0
    show_help: bool = False
    show_capacity: bool = True
    photo_index: int = 0
    painting_rect: tuple[int, int, int, int] | None = None
    drawn_order: list[int] = field(default_factory=list)  # the View order panel's cameras, as drawn
    messages_seen: int = 0
