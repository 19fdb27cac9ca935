"""The panels and Edit panel sections of the viewer's window, one a module (``*_panel.py``), and the text colours
they share. A panel is a leaf: it imports no other panel, and only app/viewer/layout.py puts panels in the window.
"""
