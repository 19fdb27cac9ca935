"""Measure a finished stylization again from its saved model, without stylizing again: what `splatstyler eval` does
with a cell whose metrics came from another METRICS_VERSION (training/evaluate/measure.py)."""

from __future__ import annotations

from pathlib import Path


def prepared_stylizer(model: Path, data: Path, painting: Path, flags: list[str]):
    """(Stylizer, parsed stylize args): the stylizer a `splatstyler stylize MODEL --data DATA --style PAINTING
    FLAGS` run starts from (cameras at the stylization size, trajectory order, pre colour transfer), not stepped."""
    from app.settings import parse_flags
    from app.settings import stylize as settings
    from training.model.model_io import read_model
    from training.scene.loader import load_scene
    from training.stylize.pipeline import choose_downscale
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import Stylizer

    args = parse_flags(settings.add_arguments, flags, "stylize flags")
    config = settings.config_from_args(args)
    scene = load_scene(data, downscale=choose_downscale(data, config.render_max_side))
    stylizer = Stylizer(read_model(model), scene, load_style_image(painting), config, vgg_weights=args.vgg_weights,
                        model_name=model)
    return stylizer, args


def remeasure(stylized_ply: Path, input_ply: Path, data: Path, painting: Path, flags: list[str]) -> dict:
    """The metrics of ``stylized_ply`` (a stylization of ``input_ply`` run with the stylize ``flags``): the
    stylizer is prepared as the run was, its model replaced by the saved one, and measured as the stylize command
    measures."""
    from training.evaluate.measure import measure_stylizer
    from training.model.model_io import read_model

    stylizer, args = prepared_stylizer(input_ply, data, painting, flags)
    original = read_model(input_ply)
    stylized = read_model(stylized_ply)
    if len(stylized) != len(original):
        raise ValueError(f"{stylized_ply} has {len(stylized)} Gaussians, its input {input_ply} {len(original)}")
    stylizer.gaussians = stylized.to(stylizer.device)
    return measure_stylizer(stylizer, original=original, max_pairs=args.metric_pairs)
