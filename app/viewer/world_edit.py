"""The measure and up tools' actions on the viewer (no imgui: measure_panel.py calls these): pick points on the
model by the depth the renderer draws under the cursor, measure between two, rescale the scene to a known length,
and level it from a picked floor, a plane fitted to the Gaussians around a picked point, or the dataset cameras.

The scene's world transform (app/world_transform.py) lives in the editor's undo history (``Editor.extras["world"]``)
beside the model it was applied to, so undo and redo restore both exactly. The dataset cameras follow it:
``sync_world`` (every frame, and when a dataset opens) gives ``app.scene.cameras`` the cameras as loaded, moved
by the world; the view's camera moves with the scene, so a rescale leaves the picture as it was.

While a trainer is running (or has run) the view shows the trainer's model, which lives in the dataset's own
frame: the cameras are then shown as loaded, and the tools that change the world are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.world_transform import (VIEWER_UP, cameras_up, compose, level, plane_normal, scale_about,
                                 transform_camera, transform_snapshot, unproject)

PICK_TOOLS = ("measure", "floor", "fit")  # two points to measure; three floor points; one point to fit around
PICKS = {"measure": 2, "floor": 3, "fit": 1}
MIN_ALPHA = 0.5  # a pick needs this much coverage under the cursor (less: the depth is a mix of background)


@dataclass
class WorldState:
    tool: str = ""  # "" | one of PICK_TOOLS: what a click (not a drag) in the 3D view picks
    points: list = field(default_factory=list)  # picked world points, (3,) arrays, in the scene's current frame
    length: float = 1.0  # the known length the user types
    fit_radius: float = 0.0  # world units around the picked point whose Gaussians the fitted plane goes through
    base_cameras: list = field(default_factory=list)  # the dataset's cameras as loaded
    shown_cameras: list | None = None  # what sync_world put in app.scene.cameras
    applied: np.ndarray | None = None  # the world those cameras were moved by
    editor: object = None  # the editor whose world was applied
    pressed: bool = False  # the left button went down on the view with a pick tool on


def world_of(app) -> np.ndarray:
    """The scene's world transform (4x4 similarity; the identity until a tool changes it)."""
    ed = app.editor
    return np.eye(4) if ed is None else ed.extras.get("world", np.eye(4))


def _shown_world(app) -> np.ndarray:
    """The world the view shows: the editor's, or the identity while the view shows a trainer's model."""
    return np.eye(4) if app.session.trainer is not None or app.edit.live else world_of(app)


def can_change(app) -> str:
    """'' when the world can be changed now, else why not (one line)."""
    if app.editor is None:
        return "open a model first"
    if app.session.trainer is not None or app.edit.live:
        return "the view shows a trainer's model: scale and up apply to a model opened in the viewer"
    return ""


def sync_world(app) -> None:
    """Give the dataset cameras (and the view's camera and the picked points, when the world of the same editor
    changed: a tool, undo, redo) the world the view shows."""
    st = app.world
    if app.scene.cameras is not st.shown_cameras:  # a dataset was opened: these are its cameras as loaded
        st.base_cameras, st.applied = list(app.scene.cameras), None
    world = _shown_world(app)
    same_editor = app.editor is st.editor
    if st.applied is not None and same_editor and np.array_equal(world, st.applied):
        return
    identity = np.array_equal(world, np.eye(4))
    cameras = list(st.base_cameras) if identity else [transform_camera(c, world) for c in st.base_cameras]
    app.scene.cameras = st.shown_cameras = cameras
    if st.applied is not None and same_editor:
        delta = world @ np.linalg.inv(st.applied)
        st.points = [delta[:3, :3] @ p + delta[:3, 3] for p in st.points]
        if app.view is not None and app.view.camera is not None:
            move_camera(app.view.camera, delta)
            app.view.moved()
    elif not same_editor:
        st.points = []  # they were picked on another model
    st.applied, st.editor = world.copy(), app.editor
    app.order_preview = None
    if app.view is not None:
        app.update_overlays()


def move_camera(camera, matrix) -> None:
    """Move a ViewerCamera with the scene (similarity ``matrix``): it sees the same picture."""
    from training.model.transform import split_similarity

    s, r, t = split_similarity(matrix)
    camera.rotation = r @ camera.rotation
    camera.position = s * (r @ camera.position) + t
    camera.target_distance *= s
    camera.up = r @ camera.up


def pick(app, camera, x: float, y: float) -> np.ndarray | None:
    """The world point under pixel (x, y) of ``camera`` (the view's, in framebuffer pixels from its top-left):
    the depth the renderer draws there, unprojected. None (and a line) where nothing solid is under it. GL thread
    only."""
    if app.view is None or not app.view.has_model(0):
        raise ValueError("no model in the view to pick on")
    ix, iy = int(np.floor(x)), int(np.floor(y))
    if not (0 <= ix < camera.width and 0 <= iy < camera.height):
        return None
    out = app.view.render_arrays(camera, ("alpha", "depth"))
    if out["alpha"][iy, ix] < MIN_ALPHA or out["depth"][iy, ix] <= 0:
        app.say("nothing solid under the cursor: pick on the model")
        return None
    return unproject(camera, ix + 0.5, iy + 0.5, float(out["depth"][iy, ix]))


def add_point(app, point: np.ndarray) -> None:
    """A picked point for the current tool; a tool's points start over once it has all it needs."""
    st = app.world
    if len(st.points) >= PICKS.get(st.tool, 0):
        st.points = []
    st.points.append(np.asarray(point, np.float64))


def distance(app) -> float | None:
    """The measured distance (world units), once two points are picked with the measure tool."""
    st = app.world
    if st.tool != "measure" or len(st.points) != 2:
        return None
    return float(np.linalg.norm(st.points[1] - st.points[0]))


def set_world(app, world: np.ndarray) -> None:
    """Give the scene the world transform ``world`` (one undoable step): the model, then the cameras and the
    view's camera follow."""
    why = can_change(app)
    if why:
        raise ValueError(why)
    ed = app.editor
    old = world_of(app)
    delta = compose(world, np.linalg.inv(old))
    model = transform_snapshot(ed.model, delta, version=ed.model.version + 1_000_000)
    ed.change(model, world=np.asarray(world, np.float64).copy())
    sync_world(app)


def rescale_to(app, length: float) -> float:
    """Scale the scene (about the origin) so that the measured distance becomes ``length``; returns the factor."""
    if not np.isfinite(length) or length <= 0:
        raise ValueError(f"the known length must be a positive number, got {length}")
    d = distance(app)
    if d is None:
        raise ValueError("pick two points with Measure first")
    if d <= 0:
        raise ValueError("the two points are the same: pick two different points")
    factor = float(length) / d
    set_world(app, compose(scale_about(factor, np.zeros(3)), world_of(app)))
    app.say(f"scaled the scene by {factor:.6g}: the measured distance is now {length:g}")
    return factor


def level_to(app, up: np.ndarray, what: str) -> None:
    """Turn the scene (about the origin) so that ``up`` (a direction in the current frame) is the viewer's up,
    then stand the view upright about its orbit centre."""
    set_world(app, compose(level(up, np.zeros(3)), world_of(app)))
    cam = app.view.camera if app.view is not None else None
    if cam is not None:
        from app.viewer.camera_control import ViewerCamera

        upright = ViewerCamera.looking_at(cam.position, cam.target, up=VIEWER_UP, fov_y_degrees=cam.fov_y_degrees)
        app.view.camera = upright
        app.view.moved()
    app.say(f"levelled the scene: {what} is up now")


def level_from_cameras(app) -> None:
    if not app.scene.cameras:
        raise ValueError("open the dataset: its cameras give the up direction")
    level_to(app, cameras_up(app.scene.cameras), "the cameras' mean up")


def _upward(app) -> np.ndarray:
    """Which side of a picked plane is up: the view's current up."""
    return app.view.camera.up if app.view is not None and app.view.camera is not None else VIEWER_UP


def level_from_floor(app) -> None:
    st = app.world
    if st.tool != "floor" or len(st.points) != 3:
        raise ValueError("pick three points on the floor first")
    level_to(app, plane_normal(st.points, toward=_upward(app)), "the picked floor's normal")


def level_from_fit(app) -> None:
    """The plane fitted to the centres of the Gaussians within ``fit_radius`` of the picked point."""
    st = app.world
    if st.tool != "fit" or len(st.points) != 1:
        raise ValueError("pick a point on the floor first")
    if not np.isfinite(st.fit_radius) or st.fit_radius <= 0:
        raise ValueError(f"the fit radius must be a positive number, got {st.fit_radius}")
    ed = app.editor
    means = ed.model.means.astype(np.float64)
    near = (np.sum((means - st.points[0]) ** 2, axis=1) <= st.fit_radius ** 2) & ~ed.hidden
    if near.sum() < 3:
        raise ValueError(f"only {int(near.sum())} Gaussians within {st.fit_radius:g} of the point: a larger radius")
    level_to(app, plane_normal(means[near], toward=_upward(app)),
             f"the plane through {int(near.sum())} Gaussians around the point")


def open_with_world(app, world) -> None:
    """A project's world given to the model it just opened (not a step to undo: the history starts here)."""
    world = np.asarray(world, np.float64)
    ed = app.editor
    if ed is None or np.array_equal(world, np.eye(4)):
        return
    ed.model = transform_snapshot(ed.model, world, version=ed.model.version + 1_000_000)
    ed.extras = {**ed.extras, "world": world.copy()}
    ed.version += 1


def in_file_frame(app, snap):
    """The editor's model snapshot moved back to the file's frame (where a trainer works), or as it is."""
    world = world_of(app)
    if snap is None or np.array_equal(world, np.eye(4)):
        return snap
    return transform_snapshot(snap, np.linalg.inv(world), version=snap.version + 1_000_000)


def scene_up(app) -> np.ndarray | None:
    """The viewer's up once the up tools turned the scene (None: the dataset cameras' mean up, as before)."""
    world = _shown_world(app)
    s = float(np.cbrt(np.linalg.det(world[:3, :3])))
    return None if np.allclose(world[:3, :3] / s, np.eye(3), atol=1e-12) else VIEWER_UP.copy()


def with_world(app, gaussians):
    """An export of the opened model as the view shows it: with the scene's world transform."""
    from training.model.transform import transform_gaussians

    return transform_gaussians(gaussians, world_of(app))
