"""renderer_gl: the real-time OpenGL (moderngl) renderer of Gaussian splat models, for the live viewer and for
headless rendering (``splatstyler render``). It takes numpy arrays of activated Gaussian parameters (means,
scales, wxyz quaternions, opacities, SH coefficients) and a pinhole camera (any object with ``world_to_camera``
in OpenCV axes, ``fx, fy, cx, cy, width, height``, or plain matrices via ``renderer_gl.camera.view``), and draws
into whatever moderngl framebuffer it is given, in a window's context or a standalone EGL/OSMesa one from
``create_context``. Its projection, culling and compositing follow the training rasterizer so that both draw the
same picture. It imports no torch and no window code (glfw, imgui), so a viewer, a CLI command or a test can use
it anywhere. API and conventions: docs/renderer.md.
"""

from renderer_gl.camera import view
from training.scene.camera import Camera
from training.scene.pose import look_at, orbit
from renderer_gl.context import Offscreen, create_context
from renderer_gl.overlays import Lines, frustum, frustums, polyline
from renderer_gl.renderer import MODES, FrameInfo, SplatRenderer
from renderer_gl.splats import SplatArrays

__all__ = [
    "Camera", "FrameInfo", "Lines", "MODES", "Offscreen", "SplatArrays", "SplatRenderer", "create_context",
    "frustum", "frustums", "look_at", "orbit", "polyline", "view",
]
