"""The modifiers a shortcut reads are the ones held at its key's press (app/viewer/key_presses.py): GLFW's bits
become imgui's, a press's modifiers are taken once, and a press the window system did not report (imgui's test
engine, the null platform) reads imgui's modifiers of the frame. The whole path, through the X server with Ctrl let
go before Q: tests/test_viewer_x11_full_hd.py."""

from imgui_bundle import imgui

from app.viewer.key_presses import KeyPresses, imgui_mods

CTRL, SHIFT, ALT, SUPER = (imgui.Key.mod_ctrl.value, imgui.Key.mod_shift.value, imgui.Key.mod_alt.value,
                           imgui.Key.mod_super.value)


def test_glfw_modifier_bits_become_imgui_ones():
    import glfw

    assert imgui_mods(0) == 0
    assert imgui_mods(glfw.MOD_CONTROL) == CTRL
    assert imgui_mods(glfw.MOD_CONTROL | glfw.MOD_SHIFT) == CTRL | SHIFT
    assert imgui_mods(glfw.MOD_ALT | glfw.MOD_SUPER) == ALT | SUPER
    assert imgui_mods(glfw.MOD_CAPS_LOCK | glfw.MOD_NUM_LOCK) == 0  # locks are no modifiers of a chord


def test_a_press_keeps_the_modifiers_it_came_with_until_imgui_reports_it():
    presses = KeyPresses()
    presses.record("q", CTRL)  # Ctrl held at Q's press, let go before imgui's frame read Q
    assert presses.take("q", 0) == CTRL
    assert presses.take("q", 0) == 0  # taken once: a later press that no window reported reads imgui's
    presses.record("s", 0)
    presses.record("s", CTRL | SHIFT)  # the latest press is the one imgui has not reported yet
    assert presses.take("s", CTRL) == CTRL | SHIFT
    assert presses.take("z", CTRL) == CTRL  # never reported by the window (test engine): imgui's modifiers
