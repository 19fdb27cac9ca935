"""The bottom layer of the engine: the one-line input error, atomic file writes, the user cache folder, the version, and
the messages a trainer exchanges with whoever drives it (events out, snapshots of the model, config updates in).

Imports nothing from the rest of ``training`` and nothing from ``app`` or ``renderer_gl``.
"""
