"""The live session, with no UI (no imgui, glfw or GL here): a trainer running beside the window and its messages
(``session.py``), the stages it runs (``stages.py``, ``sfm_run.py``), starting and following runs (``runs.py``) and
the photos pipeline (``photos.py``).
"""
