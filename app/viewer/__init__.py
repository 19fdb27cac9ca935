"""The live viewer: a glfw window with imgui-bundle panels in which renderer_gl draws the Gaussians while a trainer
runs beside it (``session``). The session and the camera are window-free, so tests drive them directly too.
"""
