"""--mask, --box, --sphere and --invert are one set of flags (app/region_flags.py): export, crop and stylize check
them alike, in one line naming the flag, before the model is read."""

from __future__ import annotations

import pytest

from app.cli import main

COMMANDS = {
    "export": ["export", "missing.ply", "-o", "out.ply"],
    "crop": ["crop", "missing.ply", "-o", "out.ply"],
    "stylize": ["stylize", "missing.ply", "--data", "nowhere", "--style", "none.png", "-o", "out"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("flags, message", [
    (["--sphere", "0,0,0,-1"], "--sphere radius must be >= 0, got -1.0"),
    (["--box", "1,2,3"], "--box takes 6 comma-separated numbers, got '1,2,3'")])
def test_the_same_flags_are_checked_alike_before_the_model_is_read(command, flags, message, capsys, tmp_path,
                                                                   monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing named here exists: the flags are refused before any file is read
    assert main(COMMANDS[command] + flags) == 2
    assert capsys.readouterr().err.strip() == f"splatstyler: error: {message}"


@pytest.mark.parametrize("command", ["export", "stylize"])
def test_invert_alone_is_refused(command, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(COMMANDS[command] + ["--invert"]) == 2
    assert "--invert needs --mask, --box or --sphere" in capsys.readouterr().err
