"""The bottom layer of the engine: the one-line input error, atomic file writes, .npy arrays read within their
file's size, JSON read with numbers a float holds, the lock that says a process is using a folder, the user cache
folder, the version, the messages a trainer exchanges with whoever drives it (events
out, snapshots of the model and the status it publishes, config updates in), the trainers' checkpoint file, and the time a run will take.

Imports nothing from the rest of ``training`` and nothing from ``app`` or ``renderer_gl``.
"""
