"""The camera path panel: keyframes from the current view (reordered, deleted, visited), the dataset's trajectory
or an orbit as ready-made paths, save and load as JSON, and a video of the path (MP4 or PNG frames, path_video.py)
with a progress bar and Cancel. The path is the document's (a project keeps it); a before/after video shows the
model before stylization left of a divider and the stylized one right of it.
"""

from __future__ import annotations

from imgui_bundle import imgui

from app.camera_path import CameraPath, dataset_path, keyframe_from, orbit_around
from app.viewer.display.path_video import start_video


def path_panel(doc, session, ui) -> None:
    st, path = ui.video, doc.camera_path
    keys = path.keyframes
    view = ui.view
    if imgui.button("Add keyframe") and view.camera is not None:
        io = imgui.get_io()
        keys.append(keyframe_from(view.camera.camera(int(io.display_size.x), int(io.display_size.y))))
        ui.requests.overlays = True
    imgui.same_line()
    if imgui.button("Dataset trajectory") and doc.cameras:
        keys[:] = dataset_path(doc.cameras).keyframes
        ui.requests.overlays = True
    imgui.same_line()
    if imgui.button("Orbit"):
        snap = session.snapshot() if session.has_trainer else doc.model
        if snap is not None:
            orbit = ui.messages.guarded("orbit", orbit_around, snap.means, snap.opacities, doc.cameras or None)
            if orbit is not None:
                keys[:] = orbit.keyframes
                path.loop = True
                ui.requests.overlays = True
    for i in range(len(keys)):
        imgui.push_id(i)
        imgui.text(f"{i:2d}")
        imgui.same_line()
        if imgui.small_button("go"):
            ui.requests.camera_to = (keys[i], None, None)
        imgui.same_line()
        if imgui.small_button("up") and i > 0:
            keys[i - 1], keys[i] = keys[i], keys[i - 1]
            ui.requests.overlays = True
        imgui.same_line()
        if imgui.small_button("down") and i + 1 < len(keys):
            keys[i + 1], keys[i] = keys[i], keys[i + 1]
            ui.requests.overlays = True
        imgui.same_line()
        if imgui.small_button("delete"):
            del keys[i]
            ui.requests.overlays = True
            imgui.pop_id()
            break
        imgui.pop_id()
    # a value typed into a slider (Ctrl+click) is held to its range, as dragging is
    clamp = imgui.SliderFlags_.always_clamp
    changed, seconds = imgui.slider_float("seconds", float(path.duration), 1.0, 60.0, "%.3f", clamp)
    if changed:
        path.duration = seconds
        ui.requests.overlays = True
    changed, fps = imgui.slider_int("fps", int(round(path.fps)), 10, 60, "%d", clamp)
    if changed:
        path.fps = float(fps)
    changed, path.loop = imgui.checkbox("loop", path.loop)
    ui.requests.overlays |= changed
    _, st.file = imgui.input_text("path file", st.file)
    if imgui.button("Save path") and len(keys) >= 2:
        ui.messages.guarded("save path", lambda: (path.save(st.file), ui.messages.say(f"wrote {st.file}")))
    imgui.same_line()
    if imgui.button("Load path"):
        loaded = ui.messages.guarded("load path", CameraPath.load, st.file)
        if loaded is not None:
            doc.camera_path = loaded
            ui.requests.overlays = True
    imgui.separator_text("Video")
    before = ui.training.before
    _, st.size = imgui.input_int2("size", st.size)
    _, st.video = imgui.input_text("video file", st.video)
    imgui.set_item_tooltip("a .mp4 file, or a folder for PNG frames")
    imgui.begin_disabled(before is None)
    _, st.split = imgui.checkbox("before | after", st.split and before is not None)
    imgui.end_disabled()
    job = st.job
    if job is None or job.finished:
        imgui.begin_disabled(len(keys) < 2)
        if imgui.button("Render video"):
            ui.messages.guarded("video", start_video, doc, ui)
        imgui.end_disabled()
    else:
        imgui.progress_bar(job.done / max(job.total, 1), imgui.ImVec2(-80, 0), f"{job.done}/{job.total}")
        imgui.same_line()
        if imgui.button("Cancel"):
            job.cancel()
            st.job = None
