"""The two recipes and the structure budget (issue 48): `--recipe paper` is the paper's stated objective and settings,
one switch away; the default is the balanced recipe; a flag on top of either changes that one setting and the run
says so; and the budget steers the content weight the way its name promises."""

from __future__ import annotations

import argparse
import math

import pytest

from app.settings.stylize import add_arguments, config_from_args
from training.stylize import defaults as D
from training.stylize.config import StylizeConfig, recipe_departures, recipe_line, recipe_settings
from training.stylize.structure_budget import RATE, SPAN, StructureBudget


def config_of(*flags: str) -> StylizeConfig:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return config_from_args(parser.parse_args(["--device", "cpu", *flags]))


def test_recipe_paper_is_the_papers_stated_objective_and_settings():
    """paper.tex 221-232: content the MSE of features at 0.005, K 16 (with epsilon 0.05, tau 0.5, lambda_guide 1,
    lambda_CCFT 30), the objective CCFT plus content alone (no TV, no other term, no budget), the colour attributes
    optimised (every SH band)."""
    cfg = config_of("--recipe", "paper")
    assert (cfg.content_norm, cfg.lambda_content, cfg.k) == ("mse", 0.005, 16)
    assert (cfg.epsilon, cfg.tau, cfg.lambda_guide, cfg.style_weight) == (0.05, 0.5, 1.0, 30.0)
    assert (cfg.lambda_tv, cfg.lambda_moments, cfg.structure_budget) == (0.0, 0.0, 0.0)
    assert cfg.dc_only is False and cfg.params == "colour"
    assert recipe_departures(cfg) == {} and recipe_line(cfg) == "the paper recipe"


def test_the_default_is_the_balanced_recipe_and_a_flag_changes_one_setting():
    cfg = config_of()
    assert cfg.recipe == "balanced" and recipe_departures(cfg) == {}
    for name, value in D.RECIPE_SETTINGS["balanced"].items():
        assert getattr(cfg, name) == value, name
    assert cfg.structure_budget > 0 and cfg.lambda_moments > 0  # the balanced recipe steers and matches statistics
    changed = config_of("--recipe", "paper", "--k", "8")
    assert recipe_departures(changed) == {"k": (16, 8)}
    assert recipe_line(changed) == "the paper recipe, changed: k 8"
    # what the report and the Style tab list: every setting the recipes set, with the run's and each recipe's value
    settings = recipe_settings(changed)
    assert set(settings) == set(D.RECIPE_SETTINGS["paper"]) == set(D.RECIPE_SETTINGS["balanced"])
    assert settings["k"] == {"value": 8, "balanced": 32, "paper": 16}


def test_the_help_names_where_each_of_the_papers_values_comes_from():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    text = " ".join(parser.format_help().split())
    for name, source in D.RECIPE_SOURCES.items():
        assert " ".join(source.split()) in text, name


def test_the_budget_raises_the_content_weight_over_it_lowers_it_under_and_stays_in_its_span():
    over, under, off = StructureBudget(), StructureBudget(), StructureBudget()
    for _ in range(20):
        over.update(0.10, 0.05)
        under.update(0.01, 0.05)
        off.update(0.10, 0.0)
    assert over.scale > 1 > under.scale and off.scale == 1.0
    assert math.isclose(math.log(over.scale), 20 * RATE, rel_tol=1e-9)  # an excess of 1 or more: RATE a step
    for _ in range(10_000):
        over.update(1.0, 0.05)
        under.update(0.0, 0.05)
    assert over.scale == pytest.approx(SPAN) and under.scale == pytest.approx(1 / SPAN)
    resumed = StructureBudget.from_state(over.state())
    assert (resumed.scale, resumed.drift) == (over.scale, over.drift)
