"""What a user types on every command: `splatstyler --version`, and the flags every long command shares
(--no-progress, --debug, --resume where a run can be continued) with --help saying which it takes."""

from __future__ import annotations

import json
from importlib.metadata import version

import pytest

from app.cli import build_parser, main
from app.commands import LONG_COMMANDS
from training.core.errors import InputError


@pytest.fixture(scope="module")
def bad(tmp_path_factory):
    """Each long command's arguments naming an input that is not there (its first check fails at once)."""
    d = tmp_path_factory.mktemp("bad")
    missing = d / "missing"
    return {
        "reconstruct": ["reconstruct", str(missing / "transforms.json"), "-o", str(d / "r")],
        "stylize": ["stylize", str(missing / "a.ply"), "--data", str(missing), "--style", str(missing / "p.png"),
                    "-o", str(d / "s")],
        "sfm": ["sfm", str(missing), "-o", str(d / "f")],
        "video": ["video", str(missing / "a.ply"), "--orbit", "-o", str(d / "v.mp4")],
        "eval": ["eval", str(missing / "grid.toml"), "-o", str(d / "e")],
        "demo": ["demo", "--headless", "--data", str(missing), "--style", str(missing / "p.png"), "-o", str(d / "d")],
    }


def test_version_prints_the_installed_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"splatstyler {version('splatstyler')}"


def test_the_list_of_long_commands_is_the_issue_s(bad):
    assert set(LONG_COMMANDS) == {"reconstruct", "stylize", "sfm", "video", "eval", "demo"} == set(bad)


@pytest.mark.parametrize("command", LONG_COMMANDS)
def test_every_long_command_takes_no_progress_and_debug(command, bad):
    argv = bad[command]
    args = build_parser().parse_args(argv + ["--no-progress", "--debug"])
    assert args.no_progress is True and args.debug is True
    args = build_parser().parse_args(argv)
    assert args.no_progress is False and args.debug is False
    # `splatstyler --debug COMMAND ...`: the command's own parser must not reset it
    assert build_parser().parse_args(["--debug"] + argv).debug is True


@pytest.mark.parametrize("command", LONG_COMMANDS)
def test_help_says_which_run_flags_apply(command, bad, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "run options:" in text and "--no-progress" in text and "--debug" in text
    takes_resume = "and --resume" in text
    assert takes_resume == ("--resume " in text.split("run options:")[1].split("takes", 1)[1])
    if takes_resume:
        assert build_parser().parse_args(bad[command] + ["--resume"]).resume is True
    else:
        assert "(no --resume:" in text  # and why


@pytest.mark.parametrize("command", LONG_COMMANDS)
def test_debug_after_the_command_shows_the_traceback(command, bad, capsys):
    argv = bad[command]
    assert main(argv + ["--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("splatstyler: error:"), err
    with pytest.raises(InputError):
        main(argv + ["--no-progress", "--debug"])


def test_eval_resume_refuses_an_output_with_nothing_to_continue(tmp_path, capsys):
    grid = tmp_path / "grid.toml"
    grid.write_text('title = "t"\nseeds = [0]\n[scenes.a]\ndata = "{}"\n[paintings]\np = "{}"\n[settings.s]\n'
                    .format(tmp_path, tmp_path / "grid.toml"))
    assert main(["eval", str(grid), "-o", str(tmp_path / "new"), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "holds no recorded job of this grid for --resume to continue" in err, err

