"""The live viewer: a glfw window with imgui-bundle panels in which renderer_gl draws the Gaussians while a trainer
runs beside it (``live.session``). The session and the camera are window-free, so tests drive them directly too.

Its rooms: the window at the top (``app.py``: the loop; ``layout.py``: the docked panels and menus; ``state.py``:
the UI state the panels read and write; ``files.py``: File > Open, Save and a dropped file; ``platform.py``: X11
or the null platform); ``panels/`` (one panel or section each, leaves that never import each other); ``display/``
(the 3D view: how it is drawn and timed, its camera, what the mouse and the gizmo do over it, the camera path's
video); ``edit/`` (the edited scene without UI: the document, the editor and its undo, the scene's models, the
selection tools, colours, measure and level); ``live/`` (the live session: the trainer beside the UI, its stages,
the runs and the photos pipeline).
"""
