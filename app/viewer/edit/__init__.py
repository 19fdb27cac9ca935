"""The edited scene, with no UI (no imgui, glfw or GL here): the document File > Open and Save project read and
write (``document.py``), the editor's selections and edits with undo (``editor.py``), the scene's models and their
ledger (``scene_models.py``), the selection tools by attribute (``select_tools.py``), colour edits and style strength
(``colour_view.py``), measure and level (``world_edit.py``) and the three-point alignment (``align_points.py``).
"""
