"""The viewer application: one window (imgui-bundle's runner, GLFW 3.5.1, GL 3.3 core) with the 3D view as the
central node of a docked layout (layout.py), a live session beside it, the document being edited (document.py) and
the panels' state (state.py). ViewerApp keeps the window, the frame loop, the display and the session; the panels
are functions of (document, session, UI state) and ask the display for what they need through ``ui.requests``.

Per frame: drain the session's messages, take a new model snapshot when one is due (at most every
``refresh_s`` while training, so drawing does not starve the trainer of the GIL, and only once the last one has
been drawn), show the document's model when it changed, carry out the panels' requests, act on the shortcuts,
draw the panels and the view. The 3D view redraws only when something it shows changed (see view3d.py), and the
runner idles at a low frame rate when nothing happens.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from app.viewer import dialogs, files
from app.viewer.camera import ViewerCamera, camera_span
from app.viewer.display.gizmo import gizmo_keys, sync_crop_box
from app.viewer.display.path_video import step_video
from app.viewer.display.view3d import View3D
from app.viewer.edit.colour_view import displayed
from app.viewer.edit.document import Document
from app.viewer.edit.world_edit import follow_world, scene_up
from app.viewer.key_presses import KeyPresses
from app.viewer.layout import (configure, floating_windows, help_overlay, quit_app, style_back, style_forward,
                               watch_style_tab, window_title)
from app.viewer.live import photos, runs
from app.viewer.live.session import Failed, LiveSession, Said, Saved, StageBegan, StateChanged
from app.viewer.platform import choose_platform, prepare_glfw
from app.viewer.state import Paths, Question, TrainingState, Ui
from training.core.messages import ModelSnapshot, Noted, ViewMoved, Warned
from training.core import stop

IDLE_FPS = 4.0  # frames per second while nothing happens: each frame costs a running trainer CPU time
# ... and while a trainer runs on software GL: a frame of the whole window there is about 65 ms of llvmpipe's CPU at
# 1920x1080 (16 ms at 960x540: it goes by the pixels), measured idle with no model: 0.27 of the 2 cores at 4 frames/s
IDLE_FPS_SOFTWARE_TRAINING = 2.0
MAX_FPS = 30.0  # while the user acts
MAX_FPS_TRAINING = 12.0  # while the user acts beside a running trainer (each frame is CPU the trainer loses)
ACTIVE_AFTER_INPUT_S = 0.5
FRUSTUM_SIZE = 0.05  # the dataset cameras' frustums in the view, as a fraction of the cameras' span
PATH_LINE_POINTS = 512  # the camera path drawn in the view: this many points at most, however long the video


# the letters a shortcut or a plain key uses (gizmo_keys: g, t, y); the modifiers at their press are looked up
SHORTCUT_LETTERS = "qszyhrngt"


class ViewerApp:
    def __init__(self, paths: Paths | None = None, start: str | None = None, preset: str = "quick",
                 recon_iters: int | None = None, stylize_overrides: dict | None = None,
                 downscale: int | None = None, project: str | None = None, outputs=None, photos=None):
        from training.stylize.config import StylizeConfig

        self.session = LiveSession()
        self.document = Document()
        self.ui = Ui(paths=paths or Paths())
        ui = self.ui
        out = Path(ui.paths.out)
        ui.export.path = str(out / "export.ply")
        ui.video.file, ui.video.video = str(out / "camera_path.json"), str(out / "path.mp4")
        ui.training = TrainingState(preset=preset, recon_iters=recon_iters, downscale=downscale,
                                    stylize=StylizeConfig(preset="quick", **(stylize_overrides or {})),
                                    outputs=outputs)
        ui.project.path = project or ""
        if photos is not None:  # PhotosState: the photos pipeline to start with the window (`view PHOTOS`)
            ui.photos = photos
        self.ctx = None
        self.frames = 0
        self.closed = False
        # a signal's close, taken by the next frame: set from the handler before the first frame was drawn, Hello
        # ImGui's exit would read that frame's draw data (for its last screenshot), which does not exist yet
        self.close_requested = False
        self._start = start
        self._platform = "null"
        self._dropped: list[str] = []
        self.key_presses = KeyPresses()  # the modifiers at each letter's press, from the window (key_presses.py)
        self._last_snapshot_at = 0.0
        self._last_frame_time = time.perf_counter()
        self._active_at = 0.0
        self._frame_start = 0.0
        self._frustums_hidden: frozenset[int] = frozenset()
        self._overlays_stale = False  # the stylizer changed view since the overlays were built
        self._sfm_framed = None  # (position, rotation) of the view as the SfM preview last framed it
        self.sfm_shown: tuple = ((), None)  # (cameras, points snapshot) of SfM the view was last given (tests look)
        self.recovery = None  # recovery.Recovery, made with the window (post_init)

    @property
    def view(self) -> View3D | None:
        """The display (made in post_init: it needs the GL context)."""
        return self.ui.view

    def training_now(self) -> bool:
        """A trainer is stepping (not paused, not loading): the view shares the CPU with it."""
        return self.session.running and self.session.status().state == "running"

    def on_drop(self, _window, paths) -> None:
        """GLFW's drop callback (during its event polling): queued, opened at the next frame."""
        self._dropped.extend(str(p) for p in paths)
        self.note_input()

    def save_project(self, path: str | None = None) -> Path:
        """File > Save project and Ctrl+S (files.save_project, with imgui's layout as it is now)."""
        return files.save_project(self.document, self.session, self.ui, path)

    def load_pending_layout(self) -> None:
        """Before a frame begins (imgui's rule for loading settings): the layout a project brought."""
        if self.ui.project.layout_to_load:
            from imgui_bundle import imgui

            imgui.load_ini_settings_from_memory(self.ui.project.layout_to_load)
            self.ui.project.layout_to_load = ""

    # ------------------------------------------------------------------ what the view shows
    def _describe(self, snap: ModelSnapshot) -> None:
        if len(snap) == 0:
            self.ui.window.model_info = {"count": 0}
            return
        lo, hi = snap.means.min(axis=0), snap.means.max(axis=0)
        self.ui.window.model_info = {"count": len(snap), "sh_degree": snap.sh_degree, "min": lo, "max": hi}

    def _place_camera(self) -> None:
        doc = self.document
        if not doc.cameras and self.session.cameras():
            self._frame_sfm()
        elif doc.cameras:
            self.view.camera = ViewerCamera.from_dataset(doc.cameras, up=scene_up(doc, self.session))  # levelled
            self.view.moved()
            self.update_overlays()
        elif doc.model is not None:
            self._frame_model(doc.model)

    def _frame_model(self, snap: ModelSnapshot) -> None:
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

    def _frame_sfm(self) -> None:
        """The SfM preview from behind and above the cameras registered so far, their points ahead: the whole rig
        and what it sees. Framed again as it grows, until the user moves the view."""
        cams, snap = self.sfm_shown
        if not cams:
            return
        centres = np.array([c.center for c in cams])
        forward = np.mean([c.forward for c in cams], axis=0)
        forward /= max(np.linalg.norm(forward), 1e-9)
        up = -np.mean([c.camera_to_world[:3, 1] for c in cams], axis=0)
        up /= max(np.linalg.norm(up), 1e-9)
        seen = np.concatenate([centres, snap.means]) if snap is not None and len(snap) else centres
        target = np.median(seen, axis=0).astype(np.float64)
        radius = float(np.percentile(np.linalg.norm(seen - target, axis=1), 90)) or camera_span(cams) or 1.0
        fov = 50.0
        direction = -forward + 0.5 * up
        eye = target + direction / np.linalg.norm(direction) * 1.2 * radius / np.sin(np.radians(fov) / 2)
        self.view.camera = ViewerCamera.looking_at(eye, target, up=up, fov_y_degrees=fov)
        self.view.moved()
        self._sfm_framed = (self.view.camera.position.copy(), self.view.camera.rotation.copy())

    def _sfm_view_untouched(self) -> bool:
        """The view is where the SfM preview last framed it (the user has not moved it since)."""
        camera = self.view.camera
        if camera is None:
            return True
        if self._sfm_framed is None:
            return False
        position, rotation = self._sfm_framed
        return bool(np.array_equal(position, camera.position) and np.array_equal(rotation, camera.rotation))

    def _snap_to_camera(self, index: int) -> None:
        cams = self.document.cameras
        if 0 <= index < len(cams):
            self.view.snap_to(cams[index], cams)
            self.update_overlays()
            if self.view.settings.photo != "off":
                self._set_photo(index)

    def _set_photo(self, index: int) -> None:
        dataset = self.document.dataset
        if dataset is None:
            return
        self.view.renderer.set_photo(dataset.photo(index))
        self.ui.window.photo_index = index
        self.view.dirty = True

    def _carry_out_requests(self) -> None:
        """What the panels asked of the view since the last frame."""
        r, view, guarded = self.ui.requests, self.view, self.ui.messages.guarded
        if r.reset:
            r.reset = False
            self._place_camera()
        if r.camera is not None:
            index, r.camera = r.camera, None
            guarded("snap", self._snap_to_camera, index)
        if r.nearest:
            r.nearest = False
            if self.document.cameras and view.camera is not None:
                guarded("snap", self._snap_to_camera, view.nearest(self.document.cameras))
        if r.photo is not None:
            index, r.photo = r.photo, None
            guarded("photo", self._set_photo, index)
        if r.camera_to is not None:
            (camera, up, distance), r.camera_to = r.camera_to, None
            up = up if up is not None else (view.camera.up if view.camera is not None else None)
            view.camera = ViewerCamera.from_camera(camera, up=up, target_distance=distance or 1.0)
            view.moved()
        if r.overlays:
            r.overlays = False
            self.update_overlays()

    def _cameras_at_view(self) -> frozenset[int]:
        """The dataset cameras within two frustum sizes of the view's eye: their frustums would be lines from
        around the eye across the whole picture, so they are not drawn while the view stands there."""
        cams = self.document.cameras or list(self.sfm_shown[0])
        if not cams or self.view is None or self.view.camera is None:
            return frozenset()
        centres = np.array([c.center for c in cams])
        d = np.linalg.norm(centres - self.view.camera.position, axis=1)
        return frozenset(np.nonzero(d <= 2 * FRUSTUM_SIZE * camera_span(cams))[0].tolist())

    def update_overlays(self) -> None:
        """Frustums of the dataset cameras (the one being stylized red), the stylization's path through them, and
        the video's camera path."""
        self._overlays_stale = False
        if self.view is None:
            return
        from renderer_gl import Lines, frustums, polyline

        doc, parts = self.document, []
        cams = doc.cameras
        sfm = not cams and bool(self.sfm_shown[0]) and self.session.status().stage == "sfm"
        if sfm:  # the cameras registered so far, the newest red
            cams = list(self.sfm_shown[0])
        if cams:
            size = FRUSTUM_SIZE * camera_span(cams)
            if self.view.settings.show_frustums:
                current = len(cams) - 1 if sfm else runs.current_camera_index(self.session)
                self._frustums_hidden = self._cameras_at_view()
                shown = [i for i in range(len(cams)) if i not in self._frustums_hidden]
                colors = [(1.0, 0.25, 0.2, 1.0) if i == current else (0.95, 0.8, 0.2, 0.8) for i in shown]
                if shown:
                    parts.append(frustums([cams[i] for i in shown], size, colors))
            if self.view.settings.show_path and not sfm:
                order = [item[0] for item in runs.trajectory(doc, self.session, self.ui) if not item[2]]
                if len(order) > 1:
                    parts.append(polyline(np.array([cams[i].center for i in order]), (0.2, 0.9, 1.0, 0.9)))
        path = doc.camera_path
        if len(path.keyframes) >= 2:  # the video's camera path, magenta
            times = np.linspace(0.0, path.duration, min(path.frame_count, PATH_LINE_POINTS))
            parts.append(polyline(np.array([path.camera_at(float(t), 64, 36).center for t in times]),
                                  (1.0, 0.3, 0.9, 0.9)))
        self.view.overlays = Lines.join(parts) if parts else None
        self.view.dirty = True

    # ------------------------------------------------------------------ per frame
    def sync(self) -> None:
        """Drain the session's news, take a new snapshot when one is due, show the document when it changed."""
        doc, session, ui, view = self.document, self.session, self.ui, self.view
        follow_world(doc, session, ui)  # the dataset cameras follow the scene's world transform (and its undo)
        sync_crop_box(doc, ui)  # and the crop box the undo of its drags
        for item in session.poll():
            if isinstance(item, StageBegan):
                if item.stage == "sfm":  # a new SfM: nothing registered yet, and the view is for it to frame
                    self.sfm_shown, self._sfm_framed = ((), None), None
                if item.stage == "stylize" and ui.training.before is None:
                    ui.training.before = session.snapshot() if session.has_trainer else doc.model
                if item.stage == "stylize":
                    style_forward(ui)  # the painting and its capacity map are what a stylization changes
                self.update_overlays()
            elif isinstance(item, Failed):
                ui.messages.fail(item.text)
            elif isinstance(item, Said):
                ui.messages.say(item.text)
            elif isinstance(item, Saved):
                runs.record_saved(doc, ui, item.stage, item.path)
            elif isinstance(item, StateChanged):
                view.dirty |= item.state in ("paused", "finished", "stopped")
                self._last_snapshot_at = 0.0  # a pause or the end: show the model as it is now
                if item.stage == "stylize" and item.state in ("finished", "stopped", "error"):
                    style_back(ui)
                photos.note_state(ui, item.state)
            elif isinstance(item, ViewMoved):
                self._overlays_stale = True
            elif isinstance(item, Warned):
                ui.messages.say(f"warning: {item.message}")
            elif isinstance(item, Noted):
                ui.messages.say(item.message)
        runs.finish_pending(ui)
        ui.messages.guarded("photos", photos.end_when_done, doc, session, ui)
        runs.give_back_unused(session, ui)
        watch_style_tab(ui)
        if doc.cameras and view.settings.show_frustums and self._cameras_at_view() != self._frustums_hidden:
            self.update_overlays()  # the view came near cameras, or left them
        self._take_snapshot()
        if self._overlays_stale and (view.dirty or not self.training_now()):
            # the stylizer moved to another view (under the interleaved schedule at every step): its red frustum
            # moves when the view draws anyway (the next model refresh), not in a splat draw of its own per step
            self.update_overlays()
        self._carry_out_requests()
        editing_live = doc.live
        if ui.training.before is not None and view.settings.split:
            view.show(ui.training.before, 1)
        if editing_live and ui.edit.shown_version != doc.editor.version:
            snap = session.snapshot()
            if snap is not None and len(snap) == doc.editor.count:
                view.show(displayed(doc, session, snap), 0)
                view.renderer.set_flags(doc.editor.flags(), 0)
                ui.edit.shown_version = doc.editor.version
                view.dirty = True
        elif doc.editor is not None and not session.has_trainer and ui.edit.shown_version != doc.editor.version:
            view.show(displayed(doc, session, doc.model), 0)
            view.renderer.set_flags(doc.editor.flags(), 0)
            self._describe(doc.model)
            ui.edit.shown_version = doc.editor.version
            view.dirty = True
            if view.camera is None:
                self._place_camera()
        elif doc.editor is not None and ui.edit.shown_version != doc.editor.version:
            # a run's model is shown and the colour edits changed: show it again with them (nothing is uploaded when
            # its colours did not change)
            snap = session.snapshot()
            if snap is not None and view.show(displayed(doc, session, snap), 0):
                view.dirty = True
            ui.edit.shown_version = doc.editor.version

    def _take_snapshot(self) -> None:
        """The trainer's model, when one is due: a new snapshot only once the last one is on screen (each upload
        spends the view's drawing budget, and taking one whenever the budget allows would spend it all on uploads
        and never draw: a frozen view)."""
        doc, session, ui, view = self.document, self.session, self.ui, self.view
        now = time.perf_counter()
        if doc.live and (not session.running or doc.editor is None):
            doc.live = False
        if (not session.has_trainer or now - self._last_snapshot_at < ui.training.refresh_s or view.dirty
                or (self.training_now() and not view.may_draw_now())):
            return
        snap = session.snapshot()
        self._last_snapshot_at = now
        if snap is not None:
            ui.training.shown_step = snap.step
        t0 = time.perf_counter()
        shown = snap is not None and view.show(displayed(doc, session, snap), 0)
        if self.training_now():
            view.charge(time.perf_counter() - t0)
        if not shown:
            return
        self._describe(snap)
        if session.status().stage == "sfm":
            self._show_sfm(snap)
        editing_live = doc.live
        if editing_live and ui.training.pending:
            pass  # the editor is ahead of the trainer until its changes have been applied
        elif editing_live and (len(snap) != doc.editor.count
                               or snap.structure_version != doc.editor.structure_version):
            # densification changed the Gaussians under the selection: start again from the new model
            doc.edit_live(snap, runs.keep_live(session, ui))
            ui.messages.say("the trainer changed its Gaussians: the selection was cleared")
        elif editing_live:
            doc.editor.model = snap  # positions move while reconstructing: select where they are now
        if editing_live and len(snap) == doc.editor.count:  # not while a deletion is on its way
            view.renderer.set_flags(doc.editor.flags(), 0)
        if view.camera is None:
            self._place_camera()

    def _show_sfm(self, snap: ModelSnapshot) -> None:
        """A new SfM preview is on its way to the screen: its cameras' frustums with it, and the view framed on
        them while the user has not taken it."""
        untouched = self._sfm_view_untouched()
        self.sfm_shown = (tuple(self.session.cameras() or ()), snap)
        if untouched:
            self._frame_sfm()
        self.update_overlays()

    # ------------------------------------------------------------------ runner callbacks
    def post_init(self) -> None:
        import moderngl

        self.ctx = moderngl.create_context(require=330)
        if self._platform != "null":
            import glfw
            from imgui_bundle import glfw_utils

            glfw.set_drop_callback(glfw_utils.glfw_window_hello_imgui(), self.on_drop)
            self.key_presses.install(glfw_utils.glfw_window_hello_imgui())
        doc, session, ui = self.document, self.session, self.ui
        from imgui_bundle import imgui

        ui.window.layout_now = imgui.save_ini_settings_to_memory  # what a saved project keeps of the window
        ui.view = View3D(self.ctx)
        renderer = str(self.ctx.info.get("GL_RENDERER", "")).lower()
        ui.window.software_gl = any(name in renderer for name in ("llvmpipe", "softpipe", "swrast"))
        if ui.window.software_gl:
            # drawing on the CPU competes with the trainer for the same cores: a coarser live view by default
            self.view.settings.training_scale = 0.5
            self.view.settings.motion_lod = 0.35  # software GL pays per splat: a lighter preview while moving
        paths = ui.paths
        for what, path, fn in (("model", paths.model, files.open_model), ("data", paths.data, files.open_data),
                               ("painting", paths.style, files.open_style)):
            if path:
                ui.messages.guarded(f"open {what}", fn, doc, session, ui, path)
        follow_world(doc, session, ui)
        self._place_camera()
        if ui.project.path:
            ui.messages.guarded("open project", files.open_project, doc, session, ui, ui.project.path)
        self._start_recovery()
        start = {"demo": lambda: runs.start_reconstruction(doc, session, ui, then_stylize=True),
                 "reconstruct": lambda: runs.start_reconstruction(doc, session, ui),
                 "stylize": lambda: runs.start_stylization(doc, session, ui)}.get(self._start)
        if start is not None:
            ui.messages.guarded("start", start)
        elif ui.photos.folder and not ui.photos.dialog:
            ui.messages.guarded("from photos", photos.start_photos, doc, session, ui)

    # ------------------------------------------------------------------ unsaved edits
    def _start_recovery(self) -> None:
        """This window's recovery project, and the question for each one a closed window left (newest first)."""
        from app.viewer.recovery import Recovery, forget, left_behind

        ui = self.ui
        try:
            left = left_behind()
            self.recovery = Recovery()
        except OSError as exc:
            ui.messages.fail(f"no recovery project for unsaved edits: {exc}")
            return
        for path, note in left:
            written = note.get("written")
            if not isinstance(written, (int, float)):
                written = path.stat().st_mtime
            written = time.strftime("%Y-%m-%d %H:%M", time.localtime(written))
            scene = str(note.get("scene") or "")
            ui.questions.append(Question(
                "Recover unsaved edits", f"splatstyler closed on {written} with edits that were not saved"
                + (f" (of {scene})" if scene else "") + ". Open them?",
                [("Open", lambda p=path, s=scene: files.open_recovered(self.document, self.session, ui, str(p), s,
                                                                       self.recovery.adopted.append)),
                 ("Discard", lambda p=path: forget(p)), ("Later", None)]))

    def _scene_name(self) -> str:
        return self.ui.project.path or self.ui.paths.model

    def keep_recovery(self) -> None:
        """Each frame: the recovery project written or removed (recovery.py), the title's "*"."""
        doc, ui = self.document, self.ui
        if self.recovery is not None:
            self.recovery.keep(doc, lambda: files.project_now(doc, ui), self._scene_name())
        title = window_title(doc, ui)
        if title != ui.window.title:
            ui.window.title = title
            if self._platform != "null":
                import glfw
                from imgui_bundle import glfw_utils

                glfw.set_window_title(glfw_utils.glfw_window_hello_imgui(), title)

    def before_exit(self) -> None:
        """Window closed: the trainer stops and saves (checkpoint, model) before the GL objects go; unsaved edits
        (a signal closes without asking) are kept in the recovery project."""
        if self.recovery is not None:
            doc, ui = self.document, self.ui
            ui.messages.guarded("recovery project", self.recovery.close, doc, lambda: files.project_now(doc, ui),
                                self._scene_name())
        self.session.close()
        runs.give_back_unused(self.session, self.ui)  # no frame comes after this one to do it
        for item in self.session.poll():
            if isinstance(item, Saved):
                self.ui.messages.say(f"saved {item.path}")
        self.ui.textures.release()
        if self.view is not None:
            self.view.release()
        self.closed = True

    def gui(self) -> None:
        """Everything of a frame but the docked panels and the view (Hello ImGui draws those after this)."""
        from imgui_bundle import imgui

        ui = self.ui
        if self.close_requested:
            from imgui_bundle import hello_imgui

            hello_imgui.get_runner_params().app_shall_exit = True
        self.frames += 1
        now = time.perf_counter()
        ui.window.frame_dt, self._last_frame_time = now - self._last_frame_time, now
        if ui.window.frame_dt > 0:
            ui.window.fps = 0.9 * ui.window.fps + 0.1 / ui.window.frame_dt
        while self._dropped:
            path = self._dropped.pop(0)
            ui.messages.guarded(f"open {path}", photos.open_dropped, self.document, self.session, ui, path)
        ui.messages.guarded("update", self.sync)
        ui.messages.guarded("keys", self.shortcuts)
        ui.messages.guarded("recovery project", self.keep_recovery)
        step_video(ui)
        if ui.window.show_help:
            help_overlay(ui)
        else:
            ui.window.help_rect = None
        floating_windows(self.document, self.session, ui)
        io = imgui.get_io()
        training = self.training_now()
        view = self.view
        # a picture to draw is drawn in this frame: while a trainer runs, the model's refresh is no reason for the
        # frames after it to come fast (the moves that need the settled picture are input themselves)
        drawable = not training and view.needs_draw(training)
        if (io.mouse_delta.x or io.mouse_delta.y or io.mouse_wheel or imgui.is_any_item_active()
                or any(imgui.is_mouse_down(b) for b in range(3)) or drawable
                or view.flying or (ui.video.job is not None and not ui.video.job.finished)):
            self.note_input()

    def shortcuts(self) -> None:
        """Keys act on the key's press event, with the modifiers held at that event (for letters, as the window
        system gave them with the press: key_presses.py says why imgui's state in the frame is not enough), so a
        quick Ctrl+Z undoes once and a held one does not repeat; plain keys never fire while text is typed, or when
        their press came with Ctrl or Super."""
        from imgui_bundle import imgui

        doc, ui = self.document, self.ui
        io = imgui.get_io()
        k = imgui.Key
        ctrl, shift, alt, super_ = k.mod_ctrl.value, k.mod_shift.value, k.mod_alt.value, k.mod_super.value
        held = int(io.key_mods) & (ctrl | shift | alt | super_)
        pressed = {letter: self.key_presses.take(letter, held) for letter in SHORTCUT_LETTERS
                   if imgui.is_key_pressed(getattr(k, letter), False)}

        def chord(mods: int, letter: str) -> bool:
            return pressed.get(letter) == mods

        if chord(ctrl, "q"):
            quit_app(doc, self.session, ui)  # as the close button: before_exit stops the trainer, which saves
        if doc.editor is not None and not io.want_text_input:
            if chord(ctrl, "s"):
                ui.messages.guarded("save project", self.save_project)
            elif chord(ctrl | shift, "s"):
                ui.messages.guarded("save project as", dialogs.save_project_as, doc, self.session, ui)
            elif chord(ctrl, "z"):
                doc.undo()
            elif chord(ctrl, "y") or chord(ctrl | shift, "z"):
                doc.redo()
        if imgui.is_key_pressed(k.f1, False):
            ui.window.show_help = not ui.window.show_help
        # Ctrl and Super make shortcuts, not camera moves
        if io.want_text_input or io.key_ctrl or io.key_super or any(m & (ctrl | super_) for m in pressed.values()):
            return
        if "h" in pressed:
            ui.window.show_help = not ui.window.show_help
        if "r" in pressed:
            ui.requests.reset = True
        if "n" in pressed:
            ui.requests.nearest = True
        if imgui.is_key_pressed(k.space, False) and self.session.running and self.session.status().stage != "sfm":
            (self.session.resume if self.session.status().state == "paused" else self.session.pause)()
        if imgui.is_key_pressed(k.delete, False) and doc.editor is not None:
            ui.messages.guarded("delete", doc.delete)
        gizmo_keys(ui)

    def note_input(self) -> None:
        """Something happened that the next frames should answer promptly (input, a picture to draw)."""
        self._active_at = time.perf_counter()

    def pace(self) -> None:
        """Sleep out the rest of the frame: 30 frames/s while the user acts or something is being drawn (12 beside
        a running trainer), 4 when nothing happens (2 beside a trainer on software GL). Sleeping frees the CPU and the GIL for the trainer. (Hello ImGui's own idling either
        never idled or spun a whole core on GLFW's null platform, measured; ours is the same on every platform.)"""
        now = time.perf_counter()
        active = now - self._active_at < ACTIVE_AFTER_INPUT_S
        training = self.training_now()
        top = MAX_FPS_TRAINING if training else MAX_FPS
        idle = IDLE_FPS_SOFTWARE_TRAINING if training and self.ui.window.software_gl else IDLE_FPS
        wait = 1.0 / (top if active else idle) - (now - self._frame_start)
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
        configure(rp, self.document, self.session, self.ui)
        return rp


def run(app: ViewerApp) -> int | None:
    """Open the window and run until it is closed. SIGTERM (what timeout, systemd, Docker, SLURM send) and SIGINT
    (Ctrl-C) close it as the close button does: the trainer stops at its next step and saves, the layout is saved,
    and this returns the signal's number (None for a close by the user). A second signal while closing is ignored,
    so the save finishes."""
    import signal

    from imgui_bundle import immapp

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
        app.close_requested = True

    previous = {sig: signal.signal(sig, close) for sig in (signal.SIGTERM, signal.SIGINT)}
    if stop.requested():  # recorded by the command's handler while the viewer was starting: nothing runs yet
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        signum = stop.signal_number() or signal.SIGINT
        print(f"splatstyler: {signal.Signals(signum).name} received while the viewer was starting: nothing to save",
              flush=True)
        return signum
    try:
        immapp.run(app.runner_params(), immapp.AddOnsParams(with_implot=True))
    except KeyboardInterrupt:
        app.session.close()
    finally:
        if not app.closed:
            app.session.close()
            runs.give_back_unused(app.session, app.ui)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return stopped_by[0] if stopped_by else None
