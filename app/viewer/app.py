"""The viewer application: one window (imgui-bundle's runner, GLFW 3.5.1, GL 3.3 core) with the 3D view as the
central node of a docked layout (layout.py), a live session beside it, and the state the panels edit.

Per frame: drain the session's messages, take a new model snapshot when one is due (at most every
``refresh_s`` while training, so drawing does not starve the trainer of the GIL, and only once the last one has
been drawn), act on the shortcuts, draw the panels and the view. The 3D view redraws only when something it shows
changed (see view3d.py), and the runner idles at a low frame rate when nothing happens.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.viewer.colour_view import ColourState, displayed, show_run_colours
from app.viewer.gizmo import GizmoState
from app.viewer.runs import RunsMixin
from app.viewer.scene_models import SceneModels
from app.viewer.select_tools_panel import SelectToolSettings
from app.viewer.session import LiveSession, SessionMessage
from app.viewer.state import (CameraPathState, EditTools, ExportSettings, ProjectState, TrainingState,
                              WindowState)
from training.core.messages import ModelSnapshot, TrainerEvent

IDLE_FPS = 4.0  # frames per second while nothing happens: each frame costs a running trainer CPU time
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".exr", ".tif", ".tiff", ".webp", ".bmp")
MAX_FPS = 30.0  # while the user acts
MAX_FPS_TRAINING = 12.0  # while the user acts beside a running trainer (each frame is CPU the trainer loses)
ACTIVE_AFTER_INPUT_S = 0.5
FRUSTUM_SIZE = 0.05  # the dataset cameras' frustums in the view, as a fraction of the cameras' span


@dataclass
class Paths:
    model: str = ""
    data: str = ""
    style: str = ""
    out: str = "viewer_out"


@dataclass
class Scene:
    """What the viewer knows of the dataset: cameras (always), photos (loaded on first use)."""

    cameras: list = field(default_factory=list)
    path: str = ""
    photos: dict[int, np.ndarray] = field(default_factory=dict)
    images_scene: Any = None


def snapshot_of(gaussians, version: int = 0) -> ModelSnapshot:
    """A ModelSnapshot of a Gaussians model (a PLY the user opened)."""
    from training.core.messages import frozen_array

    g = gaussians
    return ModelSnapshot(version, version, 0, frozen_array(g.means), frozen_array(g.scales),
                         frozen_array(g.rotations), frozen_array(g.opacities), frozen_array(g.sh), g.sh_degree)


class ViewerApp(RunsMixin):
    def __init__(self, paths: Paths | None = None, start: str | None = None, preset: str = "quick",
                 recon_iters: int | None = None, stylize_overrides: dict | None = None,
                 downscale: int | None = None, project: str | None = None):
        from training.stylize.trainer import StylizeConfig

        self.paths = paths or Paths()
        self.session = LiveSession()
        self.scene = Scene()
        self.view = None  # View3D, made in post_init (needs the GL context)
        self.ctx = None
        self.style_image: np.ndarray | None = None
        self.editor = None  # selection.Editor over the opened model (shown when no trainer runs)
        self.source_gaussians = None  # the opened model as read, raw parameters (what edits index into)
        self.scene_models = SceneModels()  # which model file and transform each source row comes from
        self.gizmo = GizmoState()
        out = Path(self.paths.out)
        self.edit = EditTools()
        self.colour = ColourState()  # the Colour panel's original model and shown colours (colour_view.py)
        self.select_tools = SelectToolSettings()  # the Edit panel's more selections (select_tools_panel.py)
        self.export = ExportSettings(path=str(out / "export.ply"))
        self.path = CameraPathState(file=str(out / "camera_path.json"), video=str(out / "path.mp4"))
        self.training = TrainingState(preset=preset, recon_iters=recon_iters, downscale=downscale,
                                      stylize=StylizeConfig(preset="quick", **(stylize_overrides or {})))
        self.window = WindowState()
        self.project = ProjectState(path=project or "")
        from app.viewer.world_edit import WorldState

        self.world = WorldState()  # the measure and up tools (world_edit.py)
        self.original: ModelSnapshot | None = None  # the model before stylization (split view, right: stylized)
        self.model_info: dict[str, Any] = {}
        self.messages: list[str] = []  # one-line messages for the user, newest last
        self.error = ""
        self.frames = 0
        self.capacity_texture = None
        self.style_texture = None
        self.order_preview: list | None = None  # (camera index, is_virtual) before a run
        self.software_gl = False
        self.closed = False
        self._start = start
        self._last_snapshot_at = 0.0
        self._last_frame_time = time.perf_counter()
        self._stage = ""
        self._dropped: list[str] = []
        self._platform = "null"
        self._active_at = 0.0
        self._frame_start = 0.0
        self._frustums_hidden: frozenset[int] = frozenset()

    # ------------------------------------------------------------------ messages
    def say(self, line: str) -> None:
        self.messages.append(line)
        del self.messages[:-50]

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

    # ------------------------------------------------------------------ loading (UI thread, user actions)
    def open_model(self, path: str) -> None:
        from training.model.model_io import read_model

        p = Path(path)
        from app.viewer.selection import Editor

        if self.session.running:
            # the view shows the run's model at every refresh: an opened file would be drawn over at once
            raise ValueError("a run is going: stop it (Training panel) before opening another model")
        g = read_model(p)
        # an ended run's model was on screen until now: from here on the view shows (and edits) the opened file
        self.session.release()
        self.original = None
        self._stage = ""
        self.training.shown_step = None
        self.source_gaussians = g
        self.scene_models = SceneModels.opened(p, len(g))
        self.training.base_model = str(p)
        self.editor = Editor(snapshot_of(g, version=-int(time.time() * 1000) % 1_000_000_000))
        self.edit.shown_version = None
        self.paths.model = str(p)
        self._describe(self.static_model)
        if self.view is not None:
            self.view.show(self.static_model, 0)
            if self.view.camera is None:
                self._frame_model(self.static_model)
        self.say(f"opened {p} ({len(self.static_model)} Gaussians)")

    def open_data(self, path: str) -> None:
        from training.scene.loader import load_scene

        scene = load_scene(path, load_images=False)
        if not scene.cameras:
            raise ValueError(f"{path}: the scene has no cameras")
        self.scene = Scene(cameras=scene.cameras, path=str(path))
        self.paths.data = str(path)
        from app.viewer.world_edit import sync_world

        sync_world(self)  # the cameras in the scene's world (measure and up tools) before the view is placed
        self.order_preview = None
        if self.view is not None:
            self._place_camera()
            self.update_overlays()
        self.say(f"opened {path} ({len(scene.cameras)} cameras)")

    def open_dropped(self, path: str) -> None:
        """A file or folder dropped on the window: a model file (.ply, .splat, .spz, .glb) opens as the model, an
        image as the painting, a folder or transforms.json as the dataset."""
        from training.model.model_io import has_model_suffix

        p = Path(path)
        suffix = p.suffix.lower()
        if has_model_suffix(p) and self.source_gaussians is not None:
            # joined, not replacing: a drop beside an open model is most often a part of the same scene, and
            # Ctrl+Z takes it out again, while a replaced model's edits would be gone (File > Open model replaces)
            from app.viewer.gizmo import add_to_scene

            add_to_scene(self, path)
        elif has_model_suffix(p):
            self.open_model(path)
        elif suffix == ".splatproj":
            self.open_project(path)
        elif suffix in IMAGE_SUFFIXES:
            self.open_style(path)
        elif p.is_dir() or p.name == "transforms.json":
            self.open_data(path)
        else:
            from training.core.errors import InputError

            raise InputError(path, "not a model (.ply, .splat, .spz, .glb), a painting (an image) or a dataset (a "
                                   "folder or transforms.json)")

    def on_drop(self, _window, paths) -> None:
        """GLFW's drop callback (during its event polling): queued, opened at the next frame."""
        self._dropped.extend(str(p) for p in paths)
        self.note_input()

    def open_project(self, path: str) -> None:
        """A .splatproj: its model with the edits, the dataset, the painting, the stylization settings, the camera
        and keyframes, and the dock layout; one line for each file it could not find."""
        from app.viewer.colour_view import load_from_project
        from app.viewer.project_io import apply_project

        opened = apply_project(self, path)
        for line in opened.problems:
            self.say(line)
        load_from_project(self, opened)
        self.project.path, self.project.opened = str(path), opened
        self.project.layout_to_load = opened.layout
        self.training.base_model = self.paths.model
        self.say(f"opened project {path}")

    def save_project(self, path: str | None = None) -> Path:
        """The session as a project file (atomically): to ``path``, or where it was opened or saved, or
        OUTPUT/project.splatproj."""
        from imgui_bundle import imgui

        from app.project import save_project
        from app.viewer.colour_view import for_project
        from app.viewer.project_io import project_from_app

        target = Path(path or self.project.path or Path(self.paths.out) / "project.splatproj")
        opened = self.project.opened
        entry = opened.entry if opened is not None else None
        colour, original = for_project(self)
        project = project_from_app(self, layout=imgui.save_ini_settings_to_memory(),
                                   transform=None if entry is None else entry.transform,
                                   colour=colour, original=original,
                                   carry=[] if opened is None else opened.not_shown)
        written = save_project(target, project)
        self.project.path = str(written)
        self.say(f"saved project {written}")
        return written

    def load_pending_layout(self) -> None:
        """Before a frame begins (imgui's rule for loading settings): the layout a project brought."""
        if self.project.layout_to_load:
            from imgui_bundle import imgui

            imgui.load_ini_settings_from_memory(self.project.layout_to_load)
            self.project.layout_to_load = ""

    def open_style(self, path: str) -> None:
        from training.stylize.style_image import load_style_image

        self.style_image = load_style_image(path)
        self.paths.style = str(path)
        self._release_style_textures()
        self.say(f"opened painting {path} ({self.style_image.shape[1]}x{self.style_image.shape[0]})")

    @property
    def static_model(self) -> ModelSnapshot | None:
        return None if self.editor is None else self.editor.model

    def edited_gaussians(self, selection_only: bool = False):
        """The opened model after the edits (raw parameters, as read), or only its selected Gaussians."""
        import torch

        if self.editor is None:
            raise ValueError("no model is open")
        rows = self.editor.index[self.editor.selected] if selection_only else self.editor.index
        if selection_only and len(rows) == 0:
            raise ValueError("nothing is selected")
        if self.source_gaussians is None:
            raise ValueError("the edited model belongs to the run: export it from the running trainer")
        return self.source_gaussians.subset(torch.as_tensor(rows, dtype=torch.long))

    def edit_live(self) -> None:
        """Select and delete in the model a running trainer trains; deletions reach it at its next step."""
        from app.viewer.selection import Editor

        trainer = self.session.trainer
        if trainer is None or not hasattr(trainer, "keep") or not self.session.running:
            raise ValueError("no running trainer to edit")
        self.editor = Editor(trainer.snapshot(), on_keep=self._keep_live)
        self.source_gaussians = None
        self.scene_models = SceneModels()
        self.edit.live = True
        self.say("editing the running trainer's model: deletions and crops apply to it and cannot be undone")

    def _keep_live(self, keep: np.ndarray, structure_version: int) -> None:
        """A deletion or crop of the running trainer's model, applied between two of its steps, and only to the
        Gaussians the selection was made on (densification in between would shift the rows)."""
        keep = np.array(keep, dtype=bool)

        def apply(trainer):
            if trainer.structure_version != structure_version:
                raise ValueError("the trainer changed its Gaussians since the selection was made: select again")
            trainer.keep(keep)

        self.submit_to_trainer("delete", apply)

    def submit_to_trainer(self, what: str, fn, done=None) -> None:
        """``fn(trainer)`` on the training thread between steps (session.submit); its error, or ``done(result)``,
        comes back at a later frame."""
        self.training.pending.append((what, self.session.submit(fn), done))

    def _finish_pending(self) -> None:
        still = []
        for what, future, done in self.training.pending:
            if not future.done():
                still.append((what, future, done))
            elif future.exception() is not None:
                exc = future.exception()
                self.fail(f"{what}: {exc}")
            elif done is not None:
                self.guarded(what, done, future.result())
        self.training.pending = still

    def edited(self) -> bool:
        return self.editor is not None and (len(self.editor.index) != len(self.source_gaussians)
                                            or bool(self.editor.hidden.any()))

    def photo(self, index: int) -> np.ndarray | None:
        """The dataset photo of camera ``index`` at the loader's size (loaded once, on first use)."""
        if index in self.scene.photos:
            return self.scene.photos[index]
        if not self.scene.path:
            return None
        from training.scene.loader import load_scene

        if self.scene.images_scene is None:
            self.scene.images_scene = load_scene(self.scene.path, downscale=self._photo_downscale())
        img = self.scene.images_scene.images[index]
        self.scene.photos[index] = img
        return img

    def _photo_downscale(self) -> int:
        long_side = max(max(c.width, c.height) for c in self.scene.cameras)
        return max(1, long_side // 1024)

    def _describe(self, snap: ModelSnapshot) -> None:
        if len(snap) == 0:
            self.model_info = {"count": 0}
            return
        lo, hi = snap.means.min(axis=0), snap.means.max(axis=0)
        self.model_info = {"count": len(snap), "sh_degree": snap.sh_degree, "min": lo, "max": hi}

    # ------------------------------------------------------------------ camera placement
    def _place_camera(self) -> None:
        from app.viewer.camera_control import ViewerCamera

        if self.scene.cameras:
            from app.viewer.world_edit import scene_up

            self.view.camera = ViewerCamera.from_dataset(self.scene.cameras, up=scene_up(self))  # levelled: -y
            self.view.moved()
            self.update_overlays()
        elif self.static_model is not None:
            self._frame_model(self.static_model)

    def _frame_model(self, snap: ModelSnapshot) -> None:
        from app.viewer.camera_control import ViewerCamera

        if len(snap) == 0:
            return
        # the sphere holding most of the splats (stray far ones left out) fills the view's height, seen from a little
        # above; -y is up, the convention of the COLMAP and OpenCV frames our files use
        center = np.median(snap.means, axis=0).astype(np.float64)
        radius = float(np.percentile(np.linalg.norm(snap.means - center, axis=1), 80)) or 1.0
        fov = 50.0
        distance = 1.15 * radius / np.sin(np.radians(fov) / 2)
        direction = np.array([0.0, -0.35, -1.0]) / np.linalg.norm([0.0, -0.35, -1.0])
        self.view.camera = ViewerCamera.looking_at(center + direction * distance, center, up=(0.0, -1.0, 0.0),
                                                   fov_y_degrees=fov)
        self.view.moved()

    def reset_camera(self) -> None:
        self._place_camera()

    def snap_to_camera(self, index: int) -> None:
        if 0 <= index < len(self.scene.cameras):
            self.view.snap_to(self.scene.cameras[index], self.scene.cameras)
            self.update_overlays()
            if self.view.settings.photo != "off":
                self.set_photo(index)

    def snap_to_nearest(self) -> int | None:
        if not self.scene.cameras or self.view.camera is None:
            return None
        index = self.view.nearest(self.scene.cameras)
        self.snap_to_camera(index)
        return index

    def set_photo(self, index: int) -> None:
        img = self.photo(index)
        self.view.renderer.set_photo(img)
        self.window.photo_index = index
        self.view.dirty = True

    # ------------------------------------------------------------------ per frame
    def sync(self) -> None:
        """Drain the session's news and take a new snapshot when one is due."""
        from app.viewer.gizmo import sync_crop_box
        from app.viewer.world_edit import sync_world

        sync_world(self)  # the dataset cameras follow the scene's world transform (and its undo)
        sync_crop_box(self)  # and the crop box the undo of its drags
        for item in self.session.poll():
            if isinstance(item, SessionMessage):
                if item.kind == "stage":
                    self._stage = item.text
                    if item.text == "stylize" and self.original is None and self.view is not None:
                        self.original = self._current_model()
                    self.update_overlays()
                elif item.kind == "error":
                    self.fail(item.text)
                elif item.kind == "saved":
                    self.record_saved(item.stage, item.text)
                elif item.kind == "state":
                    self.view.dirty |= item.text in ("paused", "finished", "stopped")
                    self._last_snapshot_at = 0.0  # a pause or the end: show the model as it is now
            elif isinstance(item, TrainerEvent):
                if item.kind == "view":
                    self.update_overlays()
                elif item.kind == "warning":
                    self.say(f"warning: {item.message}")
        self._finish_pending()
        if self.scene.cameras and self.view.settings.show_frustums and \
                self._cameras_at_view() != self._frustums_hidden:
            self.update_overlays()  # the view came near cameras, or left them
        now = time.perf_counter()
        editing_live = self.edit.live
        if editing_live and (not self.session.running or self.editor is None):
            self.edit.live = editing_live = False
        # a new snapshot only once the last one is on screen: each upload spends the view's drawing budget, and
        # taking one whenever the budget allows would spend it all on uploads and never draw (a frozen view)
        if (self.session.trainer is not None and now - self._last_snapshot_at >= self.training.refresh_s
                and not self.view.dirty and (not self.training_now() or self.view.may_draw_now())):
            snap = self.session.snapshot()
            self._last_snapshot_at = now
            if snap is not None:
                self.training.shown_step = snap.step
            t0 = time.perf_counter()
            shown = snap is not None and self.view.show(displayed(self, snap), 0)
            if self.training_now():
                self.view.charge(time.perf_counter() - t0)
            if shown:
                self._describe(snap)
                if editing_live and self.training.pending:
                    pass  # the editor is ahead of the trainer until its changes have been applied
                elif editing_live and (len(snap) != self.editor.count
                                       or snap.structure_version != self.editor.structure_version):
                    # densification changed the Gaussians under the selection: start again from the new model
                    from app.viewer.selection import Editor

                    self.editor = Editor(snap, on_keep=self._keep_live)
                    self.say("the trainer changed its Gaussians: the selection was cleared")
                elif editing_live:
                    self.editor.model = snap  # positions move while reconstructing: select where they are now
                if editing_live and len(snap) == self.editor.count:  # not while a deletion is on its way
                    self.view.renderer.set_flags(self.editor.flags(), 0)
                if self.view.camera is None:
                    self._place_camera()
        if self.original is not None and self.view.settings.split:
            self.view.show(self.original, 1)
        if editing_live and self.edit.shown_version != self.editor.version:
            snap = self.session.snapshot()
            if snap is not None and len(snap) == self.editor.count:
                self.view.show(displayed(self, snap), 0)
                self.view.renderer.set_flags(self.editor.flags(), 0)
                self.edit.shown_version = self.editor.version
                self.view.dirty = True
        elif (self.editor is not None and self.session.trainer is None
              and self.edit.shown_version != self.editor.version):
            self.view.show(displayed(self, self.editor.model), 0)
            self.view.renderer.set_flags(self.editor.flags(), 0)
            self._describe(self.editor.model)
            self.edit.shown_version = self.editor.version
            self.view.dirty = True
        elif self.editor is not None and self.edit.shown_version != self.editor.version:
            show_run_colours(self)  # a stylization's model with the Colour panel's edits (colour_view.py)

    def training_now(self) -> bool:
        """A trainer is stepping (not paused, not loading): the view shares the CPU with it."""
        return self.session.running and self.session.status().state == "running"

    def _current_model(self) -> ModelSnapshot | None:
        trainer = self.session.trainer
        return trainer.snapshot() if trainer is not None else self.static_model

    def _cameras_at_view(self) -> frozenset[int]:
        """The dataset cameras within two frustum sizes of the view's eye: their frustums would be lines from
        around the eye across the whole picture, so they are not drawn while the view stands there."""
        cams = self.scene.cameras
        if not cams or self.view is None or self.view.camera is None:
            return frozenset()
        centres = np.array([c.center for c in cams])
        d = np.linalg.norm(centres - self.view.camera.position, axis=1)
        return frozenset(np.nonzero(d <= 2 * FRUSTUM_SIZE * _span(centres))[0].tolist())

    def update_overlays(self) -> None:
        """Frustums of the dataset cameras and the stylization's path through them, in the 3D view."""
        if self.view is None:
            return
        from renderer_gl import Lines, frustums, polyline

        parts = []
        cams = self.scene.cameras
        if cams:
            size = FRUSTUM_SIZE * _span([c.center for c in cams])
            if self.view.settings.show_frustums:
                current = self.current_view_index()
                self._frustums_hidden = self._cameras_at_view()
                shown = [i for i in range(len(cams)) if i not in self._frustums_hidden]
                colors = [(1.0, 0.25, 0.2, 1.0) if i == current else (0.95, 0.8, 0.2, 0.8) for i in shown]
                if shown:
                    parts.append(frustums([cams[i] for i in shown], size, colors))
            if self.view.settings.show_path:
                order = [item[0] for item in self.trajectory() if not item[2]]
                if len(order) > 1:
                    parts.append(polyline(np.array([cams[i].center for i in order]), (0.2, 0.9, 1.0, 0.9)))
        from app.viewer.path_panel import path_line

        line = path_line(self)
        if line is not None:
            parts.append(polyline(line, (1.0, 0.3, 0.9, 0.9)))  # the video's camera path, magenta
        self.view.overlays = Lines.join(parts) if parts else None
        self.view.dirty = True

    # ------------------------------------------------------------------ runner callbacks
    def post_init(self) -> None:
        import moderngl

        from app.viewer.view3d import View3D

        self.ctx = moderngl.create_context(require=330)
        if self._platform != "null":
            import glfw
            from imgui_bundle import glfw_utils

            glfw.set_drop_callback(glfw_utils.glfw_window_hello_imgui(), self.on_drop)
        self.view = View3D(self.ctx)
        renderer = str(self.ctx.info.get("GL_RENDERER", "")).lower()
        self.software_gl = any(name in renderer for name in ("llvmpipe", "softpipe", "swrast"))
        if self.software_gl:
            # drawing on the CPU competes with the trainer for the same cores: a coarser live view by default
            self.view.settings.training_scale = 0.5
            self.view.settings.motion_lod = 0.35  # software GL pays per splat: a lighter preview while moving
        for what, path, fn in (("model", self.paths.model, self.open_model), ("data", self.paths.data, self.open_data),
                               ("painting", self.paths.style, self.open_style)):
            if path:
                self.guarded(f"open {what}", fn, path)
        if self.view.camera is None:
            self._place_camera()
        if self.project.path:
            self.guarded("open project", self.open_project, self.project.path)
        if self._start == "demo":
            self.guarded("start", self.start_reconstruction, then_stylize=True)
        elif self._start == "reconstruct":
            self.guarded("start", self.start_reconstruction)
        elif self._start == "stylize":
            self.guarded("start", self.start_stylization)

    def before_exit(self) -> None:
        """Window closed: the trainer stops and saves (checkpoint, model) before the GL objects go."""
        self.session.close()
        for item in self.session.poll():
            if isinstance(item, SessionMessage) and item.kind == "saved":
                self.say(f"saved {item.text}")
        self._release_style_textures()
        if self.view is not None:
            self.view.release()
        self.closed = True

    def _release_style_textures(self) -> None:
        for tex in (self.capacity_texture, self.style_texture):
            if tex is not None:
                tex.release()
        self.capacity_texture = self.style_texture = None

    def gui(self) -> None:
        """Everything of a frame but the docked panels and the view (Hello ImGui draws those after this)."""
        from imgui_bundle import imgui

        from app.viewer import panels
        from app.viewer.path_panel import step_video

        self.frames += 1
        now = time.perf_counter()
        self.window.frame_dt, self._last_frame_time = now - self._last_frame_time, now
        if self.window.frame_dt > 0:
            self.window.fps = 0.9 * self.window.fps + 0.1 / self.window.frame_dt
        while self._dropped:
            path = self._dropped.pop(0)
            self.guarded(f"open {path}", self.open_dropped, path)
        self.guarded("update", self.sync)
        self.guarded("keys", self.shortcuts)
        step_video(self)
        if self.window.show_help:
            panels.help_overlay(self)
        io = imgui.get_io()
        training = self.training_now()
        drawable = self.view.needs_draw(training) and (not training or self.view.may_draw_now())
        if (io.mouse_delta.x or io.mouse_delta.y or io.mouse_wheel or imgui.is_any_item_active()
                or any(imgui.is_mouse_down(b) for b in range(3)) or drawable
                or self.view.flying or (self.path.job is not None and not self.path.job.finished)):
            self.note_input()

    def shortcuts(self) -> None:
        """Keys act on the key's press event, with the modifiers held at that event (imgui's key chords, from its
        ordered input queue), so a quick Ctrl+Z undoes once and a held one does not repeat; plain keys never fire
        while text is typed."""
        from imgui_bundle import imgui

        io = imgui.get_io()
        k, ctrl, shift = imgui.Key, imgui.Key.mod_ctrl.value, imgui.Key.mod_shift.value
        chord = imgui.is_key_chord_pressed
        if self.editor is not None and not io.want_text_input:
            if chord(ctrl | k.s.value):
                self.guarded("save project", self.save_project)
            elif chord(ctrl | k.z.value):
                self.editor.undo()
            elif chord(ctrl | k.y.value) or chord(ctrl | shift | k.z.value):
                self.editor.redo()
        if imgui.is_key_pressed(k.f1, False):
            self.window.show_help = not self.window.show_help
        if io.want_text_input or self.editor_shortcut_held():
            return
        if imgui.is_key_pressed(k.h, False):
            self.window.show_help = not self.window.show_help
        if imgui.is_key_pressed(k.r, False):
            self.reset_camera()
        if imgui.is_key_pressed(k.n, False):
            self.snap_to_nearest()
        if imgui.is_key_pressed(k.space, False) and self.session.running:
            (self.session.resume if self.session.status().state == "paused" else self.session.pause)()
        if imgui.is_key_pressed(k.delete, False) and self.editor is not None:
            self.guarded("delete", self.editor.delete)
        from app.viewer.gizmo import gizmo_keys

        gizmo_keys(self)

    @staticmethod
    def editor_shortcut_held() -> bool:
        """Ctrl or Super is down: the keys under them are shortcuts, not camera moves."""
        from imgui_bundle import imgui

        io = imgui.get_io()
        return bool(io.key_ctrl or io.key_super)

    def fly_span(self) -> float:
        return _span([c.center for c in self.scene.cameras]) if self.scene.cameras else 1.0

    def open_from_dialog(self, what: str) -> None:
        """File menu: a file dialog (where a dialog program exists) for the model, dataset or painting."""
        from app.viewer.scene_panel import choose_file
        from training.model.model_io import FILE_DIALOG_PATTERN

        actions = {"model": (self.open_model, ["Gaussians", FILE_DIALOG_PATTERN]),
                   "data": (self.open_data, ["Scenes", "transforms.json cameras.bin images.bin"]),
                   "style": (self.open_style, ["Images", "*.jpg *.jpeg *.png *.exr *.tif"]),
                   "project": (self.open_project, ["Projects", "*.splatproj"])}
        action, filters = actions[what]
        path = choose_file(f"Open {what}", filters)
        if path:
            action(path)

    def note_input(self) -> None:
        """Something happened that the next frames should answer promptly (input, a picture to draw)."""
        self._active_at = time.perf_counter()

    def pace(self) -> None:
        """Sleep out the rest of the frame: 30 frames/s while the user acts or something is being drawn, 4 when
        nothing happens. Sleeping frees the CPU and the GIL for the trainer. (Hello ImGui's own idling either
        never idled or spun a whole core on GLFW's null platform, measured; ours is the same on every platform.)"""
        now = time.perf_counter()
        active = now - self._active_at < ACTIVE_AFTER_INPUT_S
        top = MAX_FPS_TRAINING if self.training_now() else MAX_FPS
        wait = 1.0 / (top if active else IDLE_FPS) - (now - self._frame_start)
        if wait > 0:
            if self._platform == "null":
                time.sleep(wait)  # no input to wait for (and the null platform's event wait returns at once)
            else:
                # wait for input or the frame time, whichever comes first, without the GIL (pyGLFW is ctypes)
                import glfw

                glfw.wait_events_timeout(wait)
        self._frame_start = time.perf_counter()

    def runner_params(self, title: str = "splatstyler", size: tuple[int, int] | None = None):
        """Hello ImGui's parameters: the docked layout, our frame pacing, and the window at the monitor's work area
        (or ``size``)."""
        from imgui_bundle import hello_imgui

        from app.viewer.layout import configure
        from app.viewer.platform import choose_platform

        rp = hello_imgui.RunnerParams()
        rp.app_window_params.window_title = title
        if size is None:
            rp.app_window_params.window_geometry.full_screen_mode = hello_imgui.FullScreenMode.full_monitor_work_area
        else:
            rp.app_window_params.window_geometry.size = size
        rp.app_window_params.restore_previous_geometry = False
        self._platform = choose_platform()
        rp.fps_idling.enable_idling = False  # paced by ``pace`` instead
        rp.fps_idling.vsync_to_monitor = False
        rp.callbacks.after_swap = self.pace
        rp.callbacks.post_init = self.post_init
        rp.callbacks.before_exit = self.before_exit
        # right after imgui's new frame, before the docked panels and the view: the frame's news, shortcuts and
        # moves reach the view in the frame that draws it
        rp.callbacks.post_new_frame = self.gui
        rp.callbacks.pre_new_frame = self.load_pending_layout
        configure(rp, self)
        return rp


def _span(points) -> float:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 2:
        return 1.0
    return max(float(np.ptp(pts, axis=0).max()), 1e-6)


def run(app: ViewerApp) -> int | None:
    """Open the window and run until it is closed. SIGTERM (what timeout, systemd, Docker, SLURM send) and SIGINT
    (Ctrl-C) close it as the close button does: the trainer stops at its next step and saves, the layout is saved,
    and this returns the signal's number (None for a close by the user). A second signal while closing is ignored,
    so the save finishes."""
    import signal

    from imgui_bundle import hello_imgui, immapp

    from app.viewer.platform import choose_platform, prepare_glfw

    prepare_glfw(choose_platform())
    # pycolmap's glog installs its own SIGTERM handler (a stack dump, no save) when it is first imported, which
    # opening a COLMAP dataset would do mid-session: import it now, and put Python's handlers in after it
    import pycolmap  # noqa: F401

    stopped_by: list[int] = []

    def close(signum, _frame) -> None:
        if stopped_by:
            return
        stopped_by.append(signum)
        print(f"splatstyler: {signal.Signals(signum).name} received: closing the window and saving", flush=True)
        hello_imgui.get_runner_params().app_shall_exit = True

    previous = {sig: signal.signal(sig, close) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        immapp.run(app.runner_params(), immapp.AddOnsParams(with_implot=True))
    except KeyboardInterrupt:
        app.session.close()
    finally:
        if not app.closed:
            app.session.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return stopped_by[0] if stopped_by else None
