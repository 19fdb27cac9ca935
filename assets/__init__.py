"""The demo's assets: the code that generates its scene and painting (``assets/demo``). The shaders live with the
renderer (``renderer_gl/shaders``); the viewer's fonts are imgui-bundle's own."""
