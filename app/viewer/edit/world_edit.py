"""The measure and up tools' actions (no imgui: measure_panel.py and the view's picks call these): pick points on
the model by the depth the renderer draws under the cursor, measure between two, rescale the scene to a known
length, and level it from a picked floor, a plane fitted to the Gaussians around a picked point, or the dataset
cameras.

The scene's world transform (app/world_transform.py) is the document's, in the editor's undo history beside the
model it was applied to, so undo and redo restore both exactly. The dataset cameras follow it: ``follow_world``
(every frame, and right after a tool changed the world) puts the document's cameras in the world the view shows;
the view's camera and the picked points move with the scene, so a rescale leaves the picture as it was.

While a trainer is running (or has run) the view shows the trainer's model, which lives in the dataset's own
frame: the cameras are then shown as loaded, and the tools that change the world are refused.
"""

from __future__ import annotations

import numpy as np

from app.viewer.camera import ViewerCamera
from app.world_transform import VIEWER_UP, cameras_up, compose, level, plane_normal, scale_about

PICK_TOOLS = ("measure", "floor", "fit")  # two points to measure; three floor points; one point to fit around
PICKS = {"measure": 2, "floor": 3, "fit": 1}
MIN_ALPHA = 0.5  # a pick needs this much coverage under the cursor (less: the depth is a mix of background)


def trainer_shown(session) -> bool:
    """The view shows a trainer's model (running or ended), not the document's."""
    return session.has_trainer


def follow_world(doc, session, ui) -> None:
    """The dataset cameras, and the view's camera and the picked points when the world of the same editor changed
    (a tool, undo, redo), in the world the view shows."""
    moved = doc.show_world(trainer_shown(session))
    if moved is None:
        return
    st = ui.world
    if moved.delta is not None:
        delta = moved.delta
        st.points = [delta[:3, :3] @ p + delta[:3, 3] for p in st.points]
        view = ui.view
        if view is not None and view.camera is not None and not np.allclose(delta, np.eye(4)):
            move_camera(view.camera, delta)
            view.moved()
    else:
        st.points = []  # they were picked on another model
    ui.training.order_preview = None
    ui.requests.overlays = True


def move_camera(camera, matrix) -> None:
    """Move a ViewerCamera with the scene (similarity ``matrix``): it sees the same picture."""
    from training.model.transform import split_similarity

    s, r, t = split_similarity(matrix)
    camera.rotation = r @ camera.rotation
    camera.position = s * (r @ camera.position) + t
    camera.target_distance *= s
    camera.up = r @ camera.up


def pick(ui, camera, x: float, y: float) -> np.ndarray | None:
    """The world point under pixel (x, y) of ``camera`` (the view's, in framebuffer pixels from its top-left):
    the depth the renderer draws there, unprojected. None (and a line) where nothing solid is under it. GL thread
    only."""
    view = ui.view
    if view is None or not view.has_model(0):
        raise ValueError("no model in the view to pick on")
    ix, iy = int(np.floor(x)), int(np.floor(y))
    if not (0 <= ix < camera.width and 0 <= iy < camera.height):
        return None
    out = view.render_arrays(camera, ("alpha", "depth"))
    if out["alpha"][iy, ix] < MIN_ALPHA or out["depth"][iy, ix] <= 0:
        ui.messages.say("nothing solid under the cursor: pick on the model")
        return None
    return camera.unproject(ix + 0.5, iy + 0.5, float(out["depth"][iy, ix]))


def add_point(tools, point: np.ndarray) -> None:
    """A picked point for the current tool; a tool's points start over once it has all it needs."""
    if len(tools.points) >= PICKS.get(tools.tool, 0):
        tools.points = []
    tools.points.append(np.asarray(point, np.float64))


def distance(tools) -> float | None:
    """The measured distance (world units), once two points are picked with the measure tool."""
    if tools.tool != "measure" or len(tools.points) != 2:
        return None
    return float(np.linalg.norm(tools.points[1] - tools.points[0]))


def set_world(doc, session, ui, world: np.ndarray) -> None:
    """Give the scene the world transform ``world`` (one undoable step): the model, then the cameras and the
    view's camera follow."""
    doc.set_world(world, trainer_shown(session))
    follow_world(doc, session, ui)


def rescale_to(doc, session, ui, length: float) -> float:
    """Scale the scene (about the origin) so that the measured distance becomes ``length``; returns the factor."""
    if not np.isfinite(length) or length <= 0:
        raise ValueError(f"the known length must be a positive number, got {length}")
    d = distance(ui.world)
    if d is None:
        raise ValueError("pick two points with Measure first")
    if d <= 0:
        raise ValueError("the two points are the same: pick two different points")
    factor = float(length) / d
    set_world(doc, session, ui, compose(scale_about(factor, np.zeros(3)), doc.world))
    ui.messages.say(f"scaled the scene by {factor:.6g}: the measured distance is now {length:g}")
    return factor


def level_to(doc, session, ui, up: np.ndarray, what: str) -> None:
    """Turn the scene (about the origin) so that ``up`` (a direction in the current frame) is the viewer's up,
    then stand the view upright about its orbit centre."""
    set_world(doc, session, ui, compose(level(up, np.zeros(3)), doc.world))
    view = ui.view
    cam = view.camera if view is not None else None
    if cam is not None:
        view.camera = ViewerCamera.looking_at(cam.position, cam.target, up=VIEWER_UP, fov_y_degrees=cam.fov_y_degrees)
        view.moved()
    ui.messages.say(f"levelled the scene: {what} is up now")


def level_from_cameras(doc, session, ui) -> None:
    if not doc.cameras:
        raise ValueError("open the dataset: its cameras give the up direction")
    level_to(doc, session, ui, cameras_up(doc.cameras), "the cameras' mean up")


def _upward(ui) -> np.ndarray:
    """Which side of a picked plane is up: the view's current up."""
    return ui.view.camera.up if ui.view is not None and ui.view.camera is not None else VIEWER_UP


def level_from_floor(doc, session, ui) -> None:
    st = ui.world
    if st.tool != "floor" or len(st.points) != 3:
        raise ValueError("pick three points on the floor first")
    level_to(doc, session, ui, plane_normal(st.points, toward=_upward(ui)), "the picked floor's normal")


def level_from_fit(doc, session, ui) -> None:
    """The plane fitted to the centres of the Gaussians within ``fit_radius`` of the picked point."""
    st = ui.world
    if st.tool != "fit" or len(st.points) != 1:
        raise ValueError("pick a point on the floor first")
    if not np.isfinite(st.fit_radius) or st.fit_radius <= 0:
        raise ValueError(f"the fit radius must be a positive number, got {st.fit_radius}")
    ed = doc.editor
    means = ed.model.means.astype(np.float64)
    near = (np.sum((means - st.points[0]) ** 2, axis=1) <= st.fit_radius ** 2) & ~ed.hidden
    if near.sum() < 3:
        raise ValueError(f"only {int(near.sum())} Gaussians within {st.fit_radius:g} of the point: a larger radius")
    level_to(doc, session, ui, plane_normal(means[near], toward=_upward(ui)),
             f"the plane through {int(near.sum())} Gaussians around the point")


def scene_up(doc, session) -> np.ndarray | None:
    """The viewer's up once the up tools turned the scene (None: the dataset cameras' mean up, as before)."""
    world = doc.shown_world(trainer_shown(session))
    s = float(np.cbrt(np.linalg.det(world[:3, :3])))
    return None if np.allclose(world[:3, :3] / s, np.eye(3), atol=1e-12) else VIEWER_UP.copy()
