"""The 3D view: the models on the GPU and when to draw (``view3d.py``), which way it draws (``choice.py``: the GL
renderer or the CUDA path, ``cuda.py`` and its CUDA-GL ``interop.py``), what the
mouse (``gestures.py``) and the transform gizmo (``gizmo.py``) do over it, and the camera path's video
(``path_video.py``).
"""
