"""The colours the viewer writes its text in, defined once for every panel (panels may not import each other): grey
for hints and the reasons a control is off, red for an error."""

from imgui_bundle import imgui

GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)
RED = imgui.ImVec4(1.0, 0.4, 0.35, 1.0)
