"""The modifiers held at each letter key's press, as the window system reports them with the press.

Why imgui's own chords are not enough: its input queue trickles one change per key per frame, and a modifier is a
key of its own. When Ctrl's release reaches the window in the same frame as Q's press (a slow frame on a busy
machine, with Ctrl let go before Q, as quick hands and ``xdotool key ctrl+q`` do), imgui applies both in that frame
and its chord check sees a plain Q. ``xdotool key ctrl+q`` did not close the window in 4 of 37 tries on a loaded
machine; a frame log of the window showed Ctrl alone in one frame, then Q with no modifier in the next. GLFW gives
every key event the modifiers held at it; this keeps them for each letter until imgui reports that letter's press.
"""

from __future__ import annotations

# GLFW's modifier bits (glfw3.h) and imgui's ImGuiMod_ values: shift, ctrl, alt, super
_GLFW_TO_IMGUI = ((0x0001, 1 << 13), (0x0002, 1 << 12), (0x0004, 1 << 14), (0x0008, 1 << 15))


def imgui_mods(glfw_mods: int) -> int:
    """GLFW's modifier bits as imgui's (``imgui.Key.mod_ctrl`` and the others)."""
    return sum(im for gl, im in _GLFW_TO_IMGUI if glfw_mods & gl)


class KeyPresses:
    """The modifiers at the latest press of each letter that imgui has not reported yet (``take``)."""

    def __init__(self) -> None:
        self._mods: dict[str, int] = {}
        self._callback = None  # the ctypes callback GLFW calls: kept alive here
        self._previous = None  # imgui's own key callback, called on after ours

    def install(self, window) -> None:
        """Put a key callback on the GLFW ``window`` (Hello ImGui's) ahead of imgui's, which it calls on."""
        import glfw

        def on_key(win, key, scancode, action, mods):
            try:
                if action == glfw.PRESS:
                    name = glfw.get_key_name(key, scancode)  # the layout's letter, as imgui's GLFW backend reads it
                    if name and len(name) == 1 and name.isalpha():
                        self.record(name.lower(), imgui_mods(mods))
            finally:
                if self._previous:
                    self._previous(win, key, scancode, action, mods)

        # pyGLFW's set_key_callback drops the callback it replaces; the C call returns it, so imgui's keeps working.
        # Both names are pyGLFW's own (since its 1.x); without them, imgui's modifiers alone, as before.
        setter = getattr(getattr(glfw, "_glfw", None), "glfwSetKeyCallback", None)
        make = getattr(glfw, "_GLFWkeyfun", None)
        if setter is None or make is None:
            return
        self._callback = make(on_key)
        self._previous = setter(window, self._callback)

    def record(self, letter: str, mods: int) -> None:
        """A press of ``letter`` with imgui modifier flags ``mods``, as the window system reported it."""
        self._mods[letter] = mods

    def take(self, letter: str, held: int) -> int:
        """The modifiers at the press of ``letter`` that imgui reports in this frame: the ones the window system
        gave with it, or ``held`` (imgui's, now) where it gave none (no GLFW window: the null platform, keys
        injected by imgui's test engine)."""
        return self._mods.pop(letter, held)
