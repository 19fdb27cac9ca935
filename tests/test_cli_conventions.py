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
    says_resume = "and --resume" in text
    try:
        takes_resume = build_parser().parse_args(bad[command] + ["--resume"]).resume is True
    except SystemExit:  # argparse: unrecognized arguments
        takes_resume = False
    assert says_resume == takes_resume
    if not takes_resume:
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


@pytest.mark.slow
def test_reconstruct_no_progress_leaves_no_bar_and_reports_the_version_and_estimate(tmp_path, capsys):
    from assets.demo.scene import make_demo_scene, write_demo_scene

    folder = write_demo_scene(tmp_path / "scene", make_demo_scene(num_views=8, width=48, height=36, num_points=200))
    for flags, out in (([], "a"), (["--no-progress"], "b")):
        assert main(["reconstruct", str(folder), "-o", str(tmp_path / out), "--iters", "40", "--downscale", "1",
                     *flags]) == 0
        err = capsys.readouterr().err
        assert ("reconstruct:" in err) == (not flags), err  # tqdm's bar, named by its desc
        assert "estimated training time: about" in err
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert report["splatstyler_version"] == version("splatstyler")
    est = report["time_estimate"]
    assert est["first_estimate_s"] > 0 and est["actual_s"] > 0
    assert est["actual_over_first_estimate"] == pytest.approx(est["actual_s"] / est["first_estimate_s"])
    assert len(est["load_average_1_5_15"]["at_start"]) == 3


@pytest.mark.slow
def test_stylize_no_progress_still_says_its_estimate_and_reports_it(tmp_path, capsys):
    import numpy as np

    from assets.demo.scene import make_demo_scene, write_demo_scene
    from training.model.gaussian_init import gaussians_from_points
    from training.model.ply_io import write_ply
    from training.scene.image_io import write_image

    demo = make_demo_scene(num_views=4, width=64, height=48, num_points=800, supersample=1)
    data = write_demo_scene(tmp_path / "scene", demo)
    write_ply(tmp_path / "model.ply", gaussians_from_points(demo.points, demo.point_colors, sh_degree=1))
    yy, xx = np.mgrid[0:96, 0:96] / 96.0
    write_image(tmp_path / "style.png", np.stack([np.sin(9 * xx) * 0.5 + 0.5, yy, 0.5 + 0 * xx], -1))
    # 4 views x 4 iterations: 2 warm-up and 8 timed steps leave 6 for the estimate to be said before the end
    assert main(["stylize", str(tmp_path / "model.ply"), "--data", str(data), "--style", str(tmp_path / "style.png"),
                 "-o", str(tmp_path / "out"), "--preset", "quick", "--max-side", "64", "--iters-per-view", "4",
                 "--no-metrics", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "estimated stylization time: about" in err and "for 16 iterations" in err, err
    assert "stylizing:" not in err  # no bar
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["splatstyler_version"] == version("splatstyler")
    est = report["time_estimate"]
    assert est["first_estimate_at_iteration"] == 10 and est["first_estimate_s"] > 0 and est["actual_s"] > 0


@pytest.mark.slow
def test_stylize_offline_without_the_lpips_weights_keeps_its_outputs(tmp_path):
    """A machine without network or cache for LPIPS (the GPU lease's; it ended a 1,340-step run with an error after
    the loop): the stylization's model, renders and report are written, the measures that need the weights are
    None and one warning says why."""
    import os
    import subprocess
    import sys

    import numpy as np

    import training.stylize.vgg_weights as vw
    from assets.demo.scene import make_demo_scene, write_demo_scene
    from training.core.cache_dir import cache_dir
    from training.model.gaussian_init import gaussians_from_points
    from training.model.ply_io import write_ply
    from training.scene.image_io import write_image

    vw.resolve_vgg_weights(log=lambda s: None)  # the stylizer's own weights come from a file, as --vgg-weights
    weights = cache_dir("weights") / vw.CONVERTED_NAME
    demo = make_demo_scene(num_views=4, width=64, height=48, num_points=800, supersample=1)
    data = write_demo_scene(tmp_path / "scene", demo)
    write_ply(tmp_path / "model.ply", gaussians_from_points(demo.points, demo.point_colors, sh_degree=1))
    yy, xx = np.mgrid[0:96, 0:96] / 96.0
    write_image(tmp_path / "style.png", np.stack([np.sin(9 * xx) * 0.5 + 0.5, yy, 0.5 + 0 * xx], -1))
    env = dict(os.environ, SPLATSTYLER_CACHE=str(tmp_path / "empty_cache"), SPLATSTYLER_VGG_WEIGHTS=str(weights),
               PIP_INDEX_URL="http://127.0.0.1:9/simple", PIP_RETRIES="0", PIP_NO_CACHE_DIR="1")
    proc = subprocess.run([sys.executable, "-m", "app", "stylize", str(tmp_path / "model.ply"), "--data", str(data),
                           "--style", str(tmp_path / "style.png"), "-o", str(tmp_path / "out"), "--preset", "quick",
                           "--max-side", "64", "--iters-per-view", "2", "--no-progress"],
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "LPIPS and the VGG measures (style distances, structure distance) skipped" in proc.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    metrics = report["metrics"]
    assert metrics["structure_distance"] is None and metrics["consistency_short_lpips"] is None
    assert metrics["consistency_short_rmse"] is not None and metrics["luminance_psnr"] > 0
    assert (tmp_path / "out" / "point_cloud.ply").is_file() and any((tmp_path / "out" / "renders").iterdir())
