"""The scene's world transform (app/world_transform.py, app/viewer/edit/world_edit.py) without a window: the viewer's
model snapshot moves as the exported file does, the dataset cameras see the moved scene in the same pixels,
levelling turns a direction onto the viewer's up, rescale and undo in the editor, and the project carries the
world to ``splatstyler export --project``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from training.scene.pose import quat_to_matrix
from app.viewer.app import ViewerApp
from app.viewer.edit.editor import Editor
from app.viewer.edit.scene_models import snapshot_of
from app.viewer.files import open_model, open_project, save_project
from app.viewer.state import Paths
from app.world_transform import (VIEWER_UP, cameras_up, level, plane_normal, rotation_between, scale_about,
                                 transform_camera, transform_snapshot)
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply
from training.model.transform import transform_gaussians
from training.scene.scene import Camera


def model(n=80, degree=3, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g) - 3, torch.randn(n, 4, generator=g),
                     torch.randn(n, generator=g), torch.randn(n, 1, 3, generator=g),
                     torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g), degree)


def similarity(scale=2.5, q=(0.3, 0.5, -0.2, 0.7), t=(1.0, 2.0, -3.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * quat_to_matrix(np.array(q) / np.linalg.norm(q))
    m[:3, 3] = t
    return m


def camera(position, target, up=(0.0, -1.0, 0.0)) -> Camera:
    from app.viewer.camera import ViewerCamera

    return ViewerCamera.looking_at(position, target, up=up).camera(64, 48)


def test_the_viewers_snapshot_moves_as_the_exported_file_does():
    g = model()
    m = similarity()
    shown = transform_snapshot(snapshot_of(g), m, version=7)
    baked = snapshot_of(transform_gaussians(g, m))
    for name in ("means", "scales", "opacities", "sh"):
        assert np.allclose(getattr(shown, name), getattr(baked, name), atol=1e-5, rtol=1e-5), name
    same_sign = np.sign(np.sum(shown.quats * baked.quats, axis=1, keepdims=True))  # q and -q: one rotation
    assert np.allclose(shown.quats, baked.quats * same_sign, atol=1e-5)
    assert shown.version == shown.geometry_version == 7 and not shown.means.flags.writeable


def test_a_moved_camera_sees_the_moved_scene_in_the_same_pixels():
    points = np.random.default_rng(0).normal(size=(50, 3))
    cam = camera([0.5, -1.0, -6.0], [0.0, 0.0, 0.0])
    m = similarity()
    moved = transform_camera(cam, m)
    uv, front = cam.project(points)
    uv2, front2 = moved.project(points @ m[:3, :3].T + m[:3, 3])
    assert front.all() and front2.all() and np.allclose(uv, uv2, atol=1e-9)
    assert np.allclose(moved.center, m[:3, :3] @ cam.center + m[:3, 3])


def test_unproject_inverts_projection():
    cam = camera([1.0, -2.0, -5.0], [0.0, 0.3, 0.0])
    p = np.array([0.2, -0.1, 0.4])
    (u, v), = cam.project(p[None])[0]
    z = (cam.world_to_camera[:3, :3] @ p + cam.world_to_camera[:3, 3])[2]
    assert np.allclose(cam.unproject(u, v, z), p, atol=1e-12)


def test_level_turns_the_up_direction_onto_the_viewers_up_and_planes_have_normals():
    for up in ([0.0, 0.0, 1.0], [0.3, -0.2, 0.9], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]):
        r = rotation_between(up, VIEWER_UP)
        assert np.allclose(r @ (np.array(up) / np.linalg.norm(up)), VIEWER_UP, atol=1e-12)
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)
    m = level([0.0, 0.0, 1.0], [1.0, 2.0, 3.0])
    assert np.allclose(m[:3, :3] @ [1.0, 2.0, 3.0] + m[:3, 3], [1.0, 2.0, 3.0])  # the pivot stays
    floor = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.2], [0.0, 1.0, -0.1]])
    n = plane_normal(floor, toward=[0.0, 0.0, 1.0])
    assert np.allclose(floor[1:] @ n - floor[0] @ n, 0.0, atol=1e-12) and n[2] > 0
    with pytest.raises(ValueError, match="one line"):
        plane_normal([[0, 0, 0], [1, 1, 1], [2, 2, 2]])
    with pytest.raises(ValueError, match="positive"):
        scale_about(0.0, [0, 0, 0])


def test_the_cameras_mean_up_is_their_minus_y():
    # a ring of cameras above the origin, looking down at it with +z up: their tilts cancel, +z is left
    cams = [camera([np.cos(a) * 5, np.sin(a) * 5, 1.0], [0.0, 0.0, 0.0], up=(0.0, 0.0, 1.0))
            for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    assert np.allclose(cameras_up(cams), [0.0, 0.0, 1.0], atol=1e-9)


def test_rescale_moves_model_and_cameras_by_the_ratio_and_undo_restores_them_bit_for_bit(tmp_path):
    write_ply(tmp_path / "m.ply", model(n=60, degree=1))
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    doc, session, ui = app.document, app.session, app.ui
    open_model(doc, session, ui, str(tmp_path / "m.ply"))
    cams = [camera([4.0, -1.0, -4.0], [0.0, 0.0, 0.0]), camera([-4.0, -1.0, -3.0], [0.0, 0.0, 0.0])]
    from app.viewer.edit.document import Dataset

    doc.dataset = Dataset("", cams)  # a dataset's cameras, as loaded
    from app.viewer.edit.world_edit import add_point, follow_world, level_from_cameras, rescale_to

    follow_world(doc, session, ui)
    before = doc.editor.model
    ui.world.tool = "measure"
    add_point(ui.world, before.means[0].astype(np.float64))
    add_point(ui.world, before.means[1].astype(np.float64))
    d = float(np.linalg.norm(before.means[1].astype(np.float64) - before.means[0]))
    factor = rescale_to(doc, session, ui, 3.0)
    assert factor == pytest.approx(3.0 / d, rel=1e-12)
    assert np.allclose(doc.editor.model.means, before.means * factor, rtol=1e-6, atol=1e-6)
    assert np.allclose(doc.editor.model.scales, before.scales * factor, rtol=1e-6)
    for a, b in zip(doc.cameras, cams):
        assert np.allclose(a.center, b.center * factor, rtol=1e-12)
    assert np.isclose(np.linalg.norm(ui.world.points[1] - ui.world.points[0]), 3.0)
    from app.viewer.edit.world_edit import scene_up

    assert scene_up(doc, session) is None  # scaled, not turned: the cameras still say where up is
    assert np.allclose(doc.in_file_frame(doc.editor.model).means, before.means, atol=1e-6)  # what a run starts from
    level_from_cameras(doc, session, ui)
    assert np.allclose(cameras_up(doc.cameras), VIEWER_UP, atol=1e-9)
    assert np.array_equal(scene_up(doc, session), VIEWER_UP)
    assert len(doc.editor.undo_stack) == 2
    doc.undo()
    doc.undo()
    follow_world(doc, session, ui)
    assert doc.editor.model is before and np.array_equal(doc.world, np.eye(4))
    assert all(a is b for a, b in zip(doc.cameras, cams))
    doc.redo()
    follow_world(doc, session, ui)
    assert np.allclose(doc.cameras[0].center, cams[0].center * factor, rtol=1e-12)


def test_a_change_keeps_its_gaussians_and_refuses_others():
    g = snapshot_of(model(n=10, degree=0))
    ed = Editor(g)
    with pytest.raises(ValueError, match="keep the 10"):
        ed.change(snapshot_of(model(n=9, degree=0)), world=np.eye(4))
    assert not ed.undo_stack


def test_export_of_a_rescaled_levelled_project_is_the_file_moved_by_the_world(tmp_path):
    from app.commands.export import baked_project
    from app.viewer.edit.world_edit import set_world

    g = model(n=40, degree=2)
    write_ply(tmp_path / "m.ply", g)
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    open_model(app.document, app.session, app.ui, str(tmp_path / "m.ply"))
    world = level([0.2, 0.1, 1.0], [0.0, 0.0, 0.0]) @ scale_about(0.25, [0.0, 0.0, 0.0])
    set_world(app.document, app.session, app.ui, world)
    path = save_project(app.document, app.session, app.ui, str(tmp_path / "s.splatproj"), layout="")
    expected = transform_gaussians(read_ply(tmp_path / "m.ply"), world)
    baked = baked_project(path, drop_hidden=False)
    for name, value in expected.parameters().items():
        assert torch.allclose(baked.parameters()[name], value, atol=1e-6), name
    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    open_project(again.document, again.session, again.ui, str(path))
    assert np.array_equal(again.document.world, world)
    assert np.allclose(again.document.editor.model.means, app.document.editor.model.means, atol=1e-6)


def floor_scene(tmp_path):
    """A tilted floor of Gaussians with a box standing on it (on the floor's upper side): a viewer session."""
    rng = np.random.default_rng(3)
    normal = np.array([0.3, -0.9, 0.3]) / np.linalg.norm([0.3, -0.9, 0.3])  # up-ish, tilted
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    uv = rng.uniform(-2, 2, size=(300, 2))
    floor = uv[:, :1] * a + uv[:, 1:] * b
    box = rng.uniform(-0.3, 0.3, size=(60, 3)) + normal * 1.0
    g = model(n=360, degree=1)
    g.means = torch.from_numpy(np.concatenate([floor, box])).float()
    write_ply(tmp_path / "floor.ply", g)
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    open_model(app.document, app.session, app.ui, str(tmp_path / "floor.ply"))
    from app.viewer.edit.world_edit import follow_world

    follow_world(app.document, app.session, app.ui)  # what each frame does first
    return app, floor


def test_fit_the_floor_levels_the_plane_of_the_gaussians_around_the_point(tmp_path):
    from app.viewer.edit.world_edit import add_point, level_from_fit

    app, floor = floor_scene(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    ui.world.tool, ui.world.fit_radius = "fit", 1.0
    add_point(ui.world, floor[0])
    level_from_fit(doc, session, ui)
    means = doc.editor.model.means.astype(np.float64)
    assert np.ptp(means[:300, 1]) < 1e-5  # the floor is level: one height
    assert means[300:, 1].max() < means[:300, 1].min()  # the box stands above it (up is -y)
    ui.world.fit_radius = 1e-6
    with pytest.raises(ValueError, match="Gaussians within"):
        level_from_fit(doc, session, ui)


def test_pick_the_floor_levels_the_plane_through_three_points(tmp_path):
    from app.viewer.edit.world_edit import add_point, level_from_floor

    app, floor = floor_scene(tmp_path)
    ui = app.ui
    ui.world.tool = "floor"
    for i in (0, 1, 2):
        add_point(ui.world, floor[i])
    level_from_floor(app.document, app.session, ui)
    means = app.document.editor.model.means.astype(np.float64)
    assert np.ptp(means[:300, 1]) < 1e-5 and means[300:, 1].max() < means[:300, 1].min()
    add_point(ui.world, floor[3])  # a fourth click starts the next floor
    assert len(ui.world.points) == 1
