"""The viewer's UI state by role, each a typed object the panels read and write: the paths typed in the Scene panel,
the one-line messages, what the edit tools, the gizmo, the Colour panel's controls, the extra selections and the
measure tools hold, the export dialog's settings, the video of the camera path, the training runs' settings and
outputs, the New from photos dialog and the photos pipeline it starts, the project file, and the window's own (where
the 3D view is, frame timing, what is shown). ``Ui`` holds one of each; panels get it with the document and the
session, and nothing adds attributes to it.

What is edited (the models, their edits, the dataset, the painting, the camera path) is the document's
(document.py), not here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from training.scene.sfm import DEFAULT_MAX_SIZE

TOOLS = ("orbit", "rect", "brush", "lasso", "surface brush", "colour pick")  # the last two: select_tools_panel
REGIONS = ("all", "selection", "unselected")


@dataclass
class Paths:
    """What the Scene panel's path fields hold (opened when their button is pressed), and the output folder."""

    model: str = ""
    data: str = ""
    style: str = ""
    out: str = "viewer_out"


class Messages:
    """One-line messages for the user, newest last (the Messages panel), and the last error (the status bar)."""

    def __init__(self, keep: int = 50):
        self.lines: list[str] = []
        self.error = ""
        self._keep = keep

    def say(self, line: str) -> None:
        self.lines.append(line)
        del self.lines[:-self._keep]

    def fail(self, line: str) -> None:
        self.error = line
        self.say(f"error: {line}")

    def guarded(self, what: str, fn, *args, **kwargs):
        """Run a user action; a failure becomes one line in the window, never an exception out of the UI."""
        from training.core.errors import InputError

        try:
            return fn(*args, **kwargs)
        except InputError as exc:
            self.fail(str(exc))
        except Exception as exc:  # noqa: BLE001  (the session goes on whatever the action hit)
            text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            self.fail(f"{what}: {type(exc).__name__}: {text}")
        return None


@dataclass
class EditTools:
    tool: str = "orbit"  # what a left drag in the 3D view does: orbit | rect | brush | lasso
    select_mode: str = "set"
    brush_radius: float = 30.0
    gesture: list[tuple[float, float]] = field(default_factory=list)  # the drag under way (window coordinates)
    box: list | None = None  # [[x0, y0, z0], [x1, y1, z1]] typed in the panel (world units)
    box_typed_from: tuple | None = None  # the box when typing in its fields began (for the undo step)
    sphere: list | None = None  # [[x, y, z], radius]
    region: str = "all"  # which Gaussians a stylization may change: all | selection | unselected
    shown_version: int | None = None  # the editor version the view shows


@dataclass
class AlignState:
    """A three-point alignment under way (align_points.py)."""

    active: bool = False  # left clicks on the view pick points
    moving: list = field(default_factory=list)  # world points on the model to move
    fixed: list = field(default_factory=list)  # where each of them belongs

    def next_is_moving(self) -> bool:
        return len(self.moving) == len(self.fixed)

    def clear(self) -> None:
        self.moving, self.fixed = [], []


@dataclass
class GizmoState:
    op: str = ""  # "" (no gizmo) | translate | rotate | scale
    target: str = "selection"  # selection | box | model:<index in the document's model files>
    dragging: bool = False
    start: np.ndarray | None = None  # the gizmo's matrix when the drag began
    delta: np.ndarray | None = None  # the similarity dragged so far
    mask: np.ndarray | None = None  # the editor rows the drag moves
    matrix: object = None  # the imguizmo Matrix16 the gizmo edits during a drag
    add_path: str = ""  # the model to add, typed (the file dialog needs zenity or kdialog)
    drawn: bool = False  # the gizmo was drawn in the last frame (ImGuizmo answers "over" from its last pose)
    align: AlignState = field(default_factory=AlignState)
    box_before: tuple | None = None  # the crop box when its drag began
    box_shown: tuple | None = None  # the editor's "crop_box" extra that the edit tools' box was last set from


@dataclass
class ColourState:
    """The Colour panel's controls (the edits and the paired original are the document's)."""

    original_input: str = ""  # what the panel's "original model" field holds (paired by its button)
    region: str = "selection"  # what a slider applies to: selection | all
    drag: int = 0  # counts slider drags: changes within one drag are one undo step


@dataclass
class SelectToolSettings:
    """The Edit panel's more selections (select_tools_panel.py)."""

    colour_tolerance: float = 0.12  # RGB distance (0..1 per channel)
    picked: tuple[float, float, float] | None = None  # the last picked Gaussian's base colour
    opacity: list[float] = field(default_factory=lambda: [0.0, 0.5])
    size: list[float] | None = None  # [lo, hi] world units; the model's span at first use
    neighbours: int = 8
    surface_tolerance: float = 0.1  # fraction of the depth at the pixel
    neighbour_cache: Any = None  # select_tools.Neighbours, made at first use


@dataclass
class WorldTools:
    """The measure and up tools' picks (world_edit.py)."""

    tool: str = ""  # "" | one of world_edit.PICK_TOOLS: what a click (not a drag) in the 3D view picks
    points: list = field(default_factory=list)  # picked world points, (3,) arrays, in the scene's current frame
    length: float = 1.0  # the known length the user types
    fit_radius: float = 0.0  # world units around the picked point whose Gaussians the fitted plane goes through
    pressed: bool = False  # the left button went down on the view with a pick tool on


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
class VideoSettings:
    """The Camera path panel's file and video fields (the path itself is the document's)."""

    file: str = "viewer_out/camera_path.json"
    size: list[int] = field(default_factory=lambda: [640, 360])
    video: str = "viewer_out/path.mp4"
    split: bool = False
    job: Any = None  # the video being rendered (path_video.VideoJob)


@dataclass
class TrainingState:
    preset: str = "quick"  # reconstruction preset
    recon_iters: int | None = None
    downscale: int | None = None
    stylize: Any = None  # StylizeConfig of the next run (validated; the running one's live settings)
    refresh_s: float = 1.0  # how often the view takes the trainer's model
    pause_at: int = 0
    base_model: str = ""  # the model as opened or reconstructed: what a stylization starts from
    runs: list[Path] = field(default_factory=list)  # each stylization's saved model, in order
    claimed: list[Path] = field(default_factory=list)  # the run folders the last run made as it started (runs.py)
    continue_last_run: bool = False
    pending: list = field(default_factory=list)  # (what, Future, on done) handed to the running trainer
    shown_step: int | None = None  # the trainer step whose model the view shows
    before: Any = None  # the model before stylization (ModelSnapshot): the split view's left side
    order_preview: list | None = None  # (camera index, centre, is_virtual) the next stylization would follow
    # what a finished run writes besides its model (the demo's window: what the headless demo writes): an object
    # with .reconstruction and .stylization, each a Stage.outputs (session.py); None: the model alone
    outputs: Any = None


@dataclass
class PhotosState:
    """The New from photos dialog (photos_panel.py) and the photos pipeline it starts (photos.py): structure from
    motion, reconstruction, and with a painting, stylization, into one output folder."""

    dialog: bool = False  # the dialog is open
    folder: str = ""  # the photos
    painting: str = ""  # optional: without one the pipeline ends after the reconstruction
    max_size: int = DEFAULT_MAX_SIZE  # the photos' long side at most, for SfM (`splatstyler sfm --max-size`)
    camera_model: str = "SIMPLE_RADIAL"
    # the pipeline under way or last run: its output folder ("" before any), its stages' folders, and whether its
    # end has been taken care of (the model opened, the project written)
    out: str = ""
    folders: dict = field(default_factory=dict)
    ended: bool = True
    ending: str = ""  # the state the run ended in (finished, stopped, error), until its thread is gone


@dataclass
class ProjectState:
    path: str = ""  # the project file this session was opened from or last saved to
    layout_to_load: str = ""  # a project's dock layout, applied before the next frame


@dataclass
class Question:
    """A question the window asks before it goes on (layout.py draws it as a modal): ``title`` (the modal's name),
    ``text``, and the answers in order, each a button label and what it does (None: nothing, the question goes)."""

    title: str
    text: str
    answers: list[tuple[str, Any]] = field(default_factory=list)


@dataclass
class StyleTextures:
    """The Style panel's GL textures: the painting (made once per painting) and the live capacity map."""

    painting: Any = None
    painting_of: Any = None  # the image the painting texture was made from
    capacity: Any = None

    def release(self) -> None:
        for tex in (self.painting, self.capacity):
            if tex is not None:
                tex.release()
        self.painting = self.painting_of = self.capacity = None


@dataclass
class ViewRequests:
    """What the panels ask of the 3D view; the frame loop carries it out before the view draws."""

    overlays: bool = False  # the frustums or a path changed: draw them again
    reset: bool = False  # the view as it first was (the dataset's first camera, or the model framed)
    camera: int | None = None  # go to this dataset camera
    nearest: bool = False  # go to the dataset camera nearest the view
    photo: int | None = None  # show this dataset camera's photo
    camera_to: Any = None  # go to this pinhole camera (a keyframe)


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
    order_points: list = field(default_factory=list)  # (x, y) on screen of each trajectory position, as drawn
    messages_seen: int = 0
    model_info: dict = field(default_factory=dict)  # the shown model: count, SH degree, bounds
    software_gl: bool = False  # the GL context draws on the CPU
    help_rect: tuple[int, int, int, int] | None = None  # the keys overlay on screen, while shown
    # a stylization brings the Style tab forward: "" (nothing to do) | wanted | asked (in front from the next frame)
    # | shown (in front; a tab the user picks from now on wins); style_covers: the tab to bring back at the end
    style_tab: str = ""
    style_covers: str = ""
    style_settings_h: float = 0.0  # the Style panel's height below the painting, last frame (the painting yields)
    fixed_folded: bool = False  # the Style panel's "Fixed at the start" was last folded for a run (opened after)
    title: str = "splatstyler"  # the window's title as last set ("*" at its end while edits are unsaved)
    layout_now: Callable[[], str] | None = None  # the dock layout as it is now (imgui's, set by the window)


@dataclass
class Ui:
    """Every panel's state, the messages, and the display the panels draw into and steer (View3D, set once the
    GL context exists)."""

    paths: Paths = field(default_factory=Paths)
    messages: Messages = field(default_factory=Messages)
    edit: EditTools = field(default_factory=EditTools)
    gizmo: GizmoState = field(default_factory=GizmoState)
    colour: ColourState = field(default_factory=ColourState)
    select_tools: SelectToolSettings = field(default_factory=SelectToolSettings)
    world: WorldTools = field(default_factory=WorldTools)
    export: ExportSettings = field(default_factory=ExportSettings)
    video: VideoSettings = field(default_factory=VideoSettings)
    training: TrainingState = field(default_factory=TrainingState)
    photos: PhotosState = field(default_factory=PhotosState)
    project: ProjectState = field(default_factory=ProjectState)
    window: WindowState = field(default_factory=WindowState)
    textures: StyleTextures = field(default_factory=StyleTextures)
    requests: ViewRequests = field(default_factory=ViewRequests)
    questions: list[Question] = field(default_factory=list)  # asked one at a time, the first shown
    view: Any = None  # view3d.View3D

    def out_dir(self) -> Path:
        return Path(self.paths.out)
