"""Recipe files: recipes/paper.yaml is the code's paper recipe (TrainConfig's defaults),
recipes/shipped.yaml the config the shipped model was trained with, recipes/pgud.yaml the one of
quadnav_onboard/models/pgud.pt (the imitation recipes' starting point); ``quadnav-sim train --recipe``
maps a file's keys onto TrainConfig by field name, and refuses bad ones naming file, key and value."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest

from quadnav_onboard.checkpoint import load_checkpoint
from quadnav_onboard.config import ConfigError
from quadnav_onboard.policy import DEFAULT_MODEL_PATH, PGUD_MODEL_PATH, PRIVILEGED_LAB_HINGE_MODEL_PATH
from sim_harness import cmd_train
from sim_harness.rl.config import TrainConfig, load_train_config

REPO = Path(__file__).resolve().parent.parent
PAPER = REPO / "recipes" / "paper.yaml"
SHIPPED = REPO / "recipes" / "shipped.yaml"
PGUD = REPO / "recipes" / "pgud.yaml"
FILTER_TEACHER = REPO / "recipes" / "filter-teacher.yaml"
FILTER_TEACHER_H6 = REPO / "recipes" / "filter-teacher-h6.yaml"
FILTER_TEACHER_H6P12 = REPO / "recipes" / "filter-teacher-h6p12.yaml"
PRIVILEGED = REPO / "recipes" / "privileged.yaml"
PRIVILEGED_H6 = REPO / "recipes" / "privileged-h6.yaml"
PRIVILEGED_H6P12 = REPO / "recipes" / "privileged-h6p12.yaml"
PRIVILEGED_LAB = REPO / "recipes" / "privileged-lab.yaml"
PRIVILEGED_LAB_HINGE = REPO / "recipes" / "privileged-lab-hinge.yaml"
PRIVILEGED_LAB_HINGE3 = REPO / "recipes" / "privileged-lab-hinge3.yaml"
PRIVILEGED_LAB_HINGE3_ROUND2 = REPO / "recipes" / "privileged-lab-hinge3-round2.yaml"
PRIVILEGED_LAB_HINGE3_ROUND2_F25 = REPO / "recipes" / "privileged-lab-hinge3-round2-f25.yaml"
PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES = (
    REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures.yaml"
)
SOFT = REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures-soft.yaml"
FREE_1M = REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures-free1m.yaml"
SOFT_FREE_1M = REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures-soft-free1m.yaml"
SOFT_RELEASE = REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures-soft-release.yaml"
SOFT_RELEASE_E2 = REPO / "recipes" / "privileged-lab-hinge3-round2-f25-failures-soft-release-e2.yaml"
SOFT_RELEASE_E2_NOISE = SOFT_RELEASE_E2.with_name(SOFT_RELEASE_E2.stem + "-noise.yaml")
SOFT_RELEASE_E2_NOISE_PAPER = SOFT_RELEASE_E2.with_name(SOFT_RELEASE_E2.stem + "-noise-paper.yaml")
NOISE_PAPER_MARGIN1 = SOFT_RELEASE_E2.with_name(SOFT_RELEASE_E2.stem + "-noise-paper-margin1.yaml")
NOISE_PAPER_MARGIN3 = SOFT_RELEASE_E2.with_name(SOFT_RELEASE_E2.stem + "-noise-paper-margin3.yaml")
NOISE_PAPER_MARGIN1_GAP02 = NOISE_PAPER_MARGIN1.with_name(NOISE_PAPER_MARGIN1.stem + "-gap02.yaml")
NOISE_PAPER_MARGIN3_GAP02 = NOISE_PAPER_MARGIN3.with_name(NOISE_PAPER_MARGIN3.stem + "-gap02.yaml")
NOISE_PAPER_MARGIN1_HOLDING = NOISE_PAPER_MARGIN1.with_name(NOISE_PAPER_MARGIN1.stem + "-holding.yaml")
NOISE_PAPER_MARGIN1_HOLDING_SCALE = NOISE_PAPER_MARGIN1_HOLDING.with_name(
    NOISE_PAPER_MARGIN1_HOLDING.stem + "-scale.yaml")
NOISE_PAPER_MARGIN1_HOLDING_SCALE_LOGRANGE = NOISE_PAPER_MARGIN1_HOLDING_SCALE.with_name(
    NOISE_PAPER_MARGIN1_HOLDING_SCALE.stem + "-logrange.yaml")
NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M = NOISE_PAPER_MARGIN1_HOLDING.with_name(
    NOISE_PAPER_MARGIN1_HOLDING.stem + "-double1m.yaml")
NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M_ROUND3 = NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M.with_name(
    NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M.stem + "-round3.yaml")
NOISE_PAPER_MARGIN1_HOLDING_DOUBLED = NOISE_PAPER_MARGIN1_HOLDING.with_name(
    NOISE_PAPER_MARGIN1_HOLDING.stem + "-doubled.yaml")
NOISE_PAPER_MARGIN03 = SOFT_RELEASE_E2.with_name(SOFT_RELEASE_E2.stem + "-noise-paper-margin03.yaml")
FAILURES_NOISE_PAPER = PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES.with_name(
    PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES.stem + "-noise-paper.yaml"
)


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    cmd_train.add_parser(parser.add_subparsers())
    return parser.parse_args(["train", *argv])


def test_paper_recipe_file_is_the_code_s_paper_recipe() -> None:
    """recipes/paper.yaml loads into exactly TrainConfig() (the defaults are the paper's recipe)."""
    assert load_train_config(cmd_train.load_recipe(PAPER), str(PAPER)) == TrainConfig()
    assert cmd_train.config_for(_parse(["--recipe", str(PAPER)])) == TrainConfig()


@pytest.mark.parametrize(("recipe", "model"), [(SHIPPED, DEFAULT_MODEL_PATH), (PGUD, PGUD_MODEL_PATH)])
def test_a_bundled_model_s_recipe_file_is_what_it_was_trained_with(recipe: Path, model: Path) -> None:
    """recipes/shipped.yaml (default.pt) and recipes/pgud.yaml (pgud.pt) each equal the TrainConfig
    in their model's meta (keys added to TrainConfig since then at their defaults), and differ from
    the paper's recipe."""
    meta = load_checkpoint(model).meta["train_config"]
    trained = load_train_config(meta, f"{model.name} meta.train_config")
    from_file = cmd_train.config_for(_parse(["--recipe", str(recipe)]))
    assert from_file == trained
    assert from_file != TrainConfig()


def test_six_frame_recipe_is_the_filter_teacher_recipe_with_its_two_flags() -> None:
    """recipes/filter-teacher-h6.yaml is recipes/filter-teacher.yaml with ``--imitation-veto-weight
    1 --depth-history 6`` (the commands its figures were measured with), under its own name."""
    h6 = cmd_train.config_for(_parse(["--recipe", str(FILTER_TEACHER_H6)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(FILTER_TEACHER), "--imitation-veto-weight", "1", "--depth-history", "6"])
    )
    assert h6.name == "filter-teacher-h6"
    assert dataclasses.replace(h6, name=flags.name) == flags
    assert (h6.depth_history, h6.imitation_veto_weight) == (6, 1.0)


def test_twelve_position_recipe_is_the_six_frame_recipe_with_its_flag() -> None:
    """recipes/filter-teacher-h6p12.yaml is recipes/filter-teacher-h6.yaml with
    ``--position-history 12`` (the command its figures were measured with), under its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(FILTER_TEACHER_H6P12)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(FILTER_TEACHER_H6), "--position-history", "12"]))
    assert recipe.name == "filter-teacher-h6p12"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert (recipe.depth_history, recipe.position_history) == (6, 12)


def test_privileged_recipe_is_the_filter_teacher_recipe_with_the_privileged_teacher() -> None:
    """recipes/privileged.yaml is recipes/filter-teacher.yaml with ``--imitation-teacher privileged
    --dagger-filtered-share 0.5 --dagger-iterations 15`` (the commands its figures were measured
    with), under its own name, starting from the shipped model."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED)]))
    flags = cmd_train.config_for(_parse([
        "--recipe", str(FILTER_TEACHER), "--imitation-teacher", "privileged",
        "--dagger-filtered-share", "0.5", "--dagger-iterations", "15",
    ]))
    assert recipe.name == "privileged"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert (recipe.imitation_teacher, recipe.dagger_filtered_share, recipe.dagger_iterations) == (
        "privileged", 0.5, 15)
    assert (REPO / recipe.init_model).resolve() == PGUD_MODEL_PATH.resolve()


def test_privileged_six_frame_recipe_is_the_privileged_recipe_with_its_two_flags() -> None:
    """recipes/privileged-h6.yaml is recipes/privileged.yaml with ``--depth-history 6
    --teacher-respect-filter`` (the commands its figures were measured with), under its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_H6)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(PRIVILEGED), "--depth-history", "6", "--teacher-respect-filter"])
    )
    assert recipe.name == "privileged-h6"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert (recipe.depth_history, recipe.teacher_respect_filter) == (6, True)


def test_privileged_twelve_position_recipe_is_the_privileged_six_frame_recipe_with_its_flag() -> None:
    """recipes/privileged-h6p12.yaml is recipes/privileged-h6.yaml with ``--position-history 12``
    (the command its figures were measured with), under its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_H6P12)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_H6), "--position-history", "12"]))
    assert recipe.name == "privileged-h6p12"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert (recipe.depth_history, recipe.position_history, recipe.teacher_respect_filter) == (6, 12, True)


def test_privileged_lab_recipe_is_the_twelve_position_recipe_with_the_lab_s_layouts() -> None:
    """recipes/privileged-lab.yaml is recipes/privileged-h6p12.yaml with recipes/lab.yaml's three
    lab keys (DAgger also flies the lab's box layouts under its flight config), under its own name,
    starting from the ``pgud`` weights that the other recipes start from."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB)]))
    lab = cmd_train.config_for(_parse(["--recipe", str(REPO / "recipes" / "lab.yaml")]))
    flags = cmd_train.config_for(_parse([
        "--recipe", str(PRIVILEGED_H6P12), "--lab-world", lab.lab_world,
        "--lab-flight-config", lab.lab_flight_config, "--lab-layouts", str(lab.lab_layouts),
    ]))
    assert recipe.name == "privileged-lab"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert (recipe.lab_world, recipe.lab_flight_config, recipe.lab_layouts) == (
        "lab01-free", "config/flight.yaml", 200)
    assert (REPO / recipe.init_model).resolve() == PGUD_MODEL_PATH.resolve()


def test_privileged_lab_hinge_recipe_is_the_lab_recipe_with_the_hinge() -> None:
    """recipes/privileged-lab-hinge.yaml is recipes/privileged-lab.yaml with ``--imitation-veto-weight
    1`` (the command its figures were measured with), under its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB), "--imitation-veto-weight", "1"]))
    assert recipe.name == "privileged-lab-hinge"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert recipe.imitation_veto_weight == 1.0 and recipe.imitation_teacher == "privileged"


def test_privileged_lab_hinge3_recipe_is_the_hinge_recipe_at_weight_3() -> None:
    """recipes/privileged-lab-hinge3.yaml is recipes/privileged-lab-hinge.yaml with
    ``--imitation-veto-weight 3`` (the command its seeds were first trained with), under its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE3)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(PRIVILEGED_LAB_HINGE), "--imitation-veto-weight", "3"])
    )
    assert recipe.name == "privileged-lab-hinge3"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert recipe.imitation_veto_weight == 3.0 and recipe.lab_layouts == 200


def test_second_round_recipe_is_the_weight_3_recipe_from_the_pinned_earlier_bundled_model() -> None:
    """recipes/privileged-lab-hinge3-round2.yaml is recipes/privileged-lab-hinge3.yaml with
    ``--init-model quadnav_onboard/models/privileged-lab-hinge.pt --dagger-iterations 8`` under its
    own name, and pins the start to that file's sha256: the model bundled from 0.5.1 to 0.5.6, kept
    beside default.pt (its seeds were first trained from default.pt when it was that model)."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2)]))
    flags = cmd_train.config_for(_parse([
        "--recipe", str(PRIVILEGED_LAB_HINGE3),
        "--init-model", "quadnav_onboard/models/privileged-lab-hinge.pt", "--dagger-iterations", "8",
    ]))
    assert recipe.name == "privileged-lab-hinge3-round2"
    assert dataclasses.replace(recipe, name=flags.name, init_model_sha256="") == flags
    assert (REPO / recipe.init_model).resolve() == PRIVILEGED_LAB_HINGE_MODEL_PATH.resolve()
    assert recipe.init_model_sha256 == load_checkpoint(REPO / recipe.init_model).sha256
    assert recipe.dagger_iterations == 8


def test_the_kept_earlier_bundled_model_is_the_privileged_lab_hinge_recipe_s_seed_0() -> None:
    """quadnav_onboard/models/privileged-lab-hinge.pt was trained with recipes/privileged-lab-hinge.yaml
    at seed 0, the recipe the docs name for it."""
    meta = load_checkpoint(PRIVILEGED_LAB_HINGE_MODEL_PATH).meta["train_config"]
    trained = load_train_config(meta, "privileged-lab-hinge.pt meta.train_config")
    assert trained == cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE), "--seed", "0"]))


def test_second_round_quarter_recipe_is_the_second_round_with_a_quarter_behind_the_filter() -> None:
    """recipes/privileged-lab-hinge3-round2-f25.yaml is the second round with
    ``--dagger-filtered-share 0.25`` (the command its seeds were first trained with), its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2_F25)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2), "--dagger-filtered-share", "0.25"])
    )
    assert recipe.name == "privileged-lab-hinge3-round2-f25"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert recipe.dagger_filtered_share == 0.25 and recipe.init_model_sha256 == flags.init_model_sha256


def test_failure_sampling_recipe_is_the_quarter_recipe_with_its_flag() -> None:
    """recipes/privileged-lab-hinge3-round2-f25-failures.yaml is the quarter second round with
    ``--dagger-world-sampling failures`` (the command its first seeds were trained with), its own name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2_F25), "--dagger-world-sampling", "failures"])
    )
    assert recipe.name == "privileged-lab-hinge3-round2-f25-failures"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert recipe.dagger_world_sampling == "failures" and recipe.dagger_filtered_share == 0.25


def test_soft_target_recipe_is_the_failure_sampling_recipe_at_temperature_0_3() -> None:
    """recipes/privileged-lab-hinge3-round2-f25-failures-soft.yaml is the failure-sampling recipe
    with ``--imitation-temperature-m 0.3`` (the command its first seeds were trained with), its own
    name."""
    recipe = cmd_train.config_for(_parse(["--recipe", str(SOFT)]))
    flags = cmd_train.config_for(
        _parse(["--recipe", str(PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES),
                "--imitation-temperature-m", "0.3"])
    )
    assert recipe.name == "privileged-lab-hinge3-round2-f25-failures-soft"
    assert dataclasses.replace(recipe, name=flags.name) == flags
    assert recipe.imitation_temperature_m == 0.3 and recipe.dagger_world_sampling == "failures"


@pytest.mark.parametrize(("recipe", "base"), [
    (FREE_1M, PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES), (SOFT_FREE_1M, SOFT),
])
def test_free_1m_recipes_are_their_bases_with_the_filters_lessons_at_0_5_m_only(recipe, base) -> None:
    """The two ``-free1m`` recipes are their bases with ``--imitation-filter-scales 0.5``, their own
    names."""
    got = cmd_train.config_for(_parse(["--recipe", str(recipe)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(base), "--imitation-filter-scales", "0.5"]))
    assert got.name == recipe.stem
    assert dataclasses.replace(got, name=flags.name) == flags
    assert got.imitation_filter_scales == (0.5,) and got.imitation_scales == (1.0, 0.5)


def test_release_recipe_is_the_soft_recipe_with_the_teacher_released_at_0_75_m() -> None:
    """recipes/privileged-lab-hinge3-round2-f25-failures-soft-release.yaml is the soft recipe with
    ``--teacher-release-m 0.75`` (the command its first seeds were trained with), its own name; the
    teacher still respects the filter, which the release needs."""
    got = cmd_train.config_for(_parse(["--recipe", str(SOFT_RELEASE)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(SOFT), "--teacher-release-m", "0.75"]))
    assert got.name == SOFT_RELEASE.stem
    assert dataclasses.replace(got, name=flags.name) == flags
    assert got.teacher_release_m == 0.75 and got.teacher_respect_filter
    assert got.imitation_temperature_m == 0.3


@pytest.mark.parametrize(("recipe", "base", "flag", "expect"), [
    (SOFT_RELEASE_E2, SOFT_RELEASE, ["--imitation-epochs", "2"],
     {"imitation_epochs": 2.0, "teacher_release_m": 0.75}),
    (SOFT_RELEASE_E2_NOISE, SOFT_RELEASE_E2, ["--dagger-noise", "0.1"],
     {"dagger_noise": 0.1, "imitation_epochs": 2.0}),
    (SOFT_RELEASE_E2_NOISE_PAPER, SOFT_RELEASE_E2_NOISE, ["--lab-dagger-noise", "0"],
     {"dagger_noise": 0.1, "lab_dagger_noise": 0.0}),
    (FAILURES_NOISE_PAPER, PRIVILEGED_LAB_HINGE3_ROUND2_F25_FAILURES,
     ["--dagger-noise", "0.1", "--lab-dagger-noise", "0"],
     {"dagger_noise": 0.1, "lab_dagger_noise": 0.0, "teacher_release_m": 0.0}),
    (NOISE_PAPER_MARGIN1, SOFT_RELEASE_E2_NOISE_PAPER, ["--imitation-margin-weight", "1"],
     {"imitation_margin_weight": 1.0, "imitation_margin": 1.0, "imitation_temperature_m": 0.3}),
    (NOISE_PAPER_MARGIN03, SOFT_RELEASE_E2_NOISE_PAPER, ["--imitation-margin-weight", "0.3"],
     {"imitation_margin_weight": 0.3, "imitation_margin": 1.0, "lab_dagger_noise": 0.0}),
    (NOISE_PAPER_MARGIN3, SOFT_RELEASE_E2_NOISE_PAPER, ["--imitation-margin-weight", "3"],
     {"imitation_margin_weight": 3.0, "imitation_margin": 1.0, "imitation_veto_weight": 3.0}),
    (NOISE_PAPER_MARGIN1_GAP02, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-min-gap-m", "0.2"],
     {"imitation_margin_weight": 1.0, "imitation_margin_min_gap_m": 0.2, "imitation_temperature_m": 0.3}),
    (NOISE_PAPER_MARGIN3_GAP02, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "3", "--imitation-margin-min-gap-m", "0.2"],
     {"imitation_margin_weight": 3.0, "imitation_margin_min_gap_m": 0.2, "dagger_noise": 0.1}),
    (NOISE_PAPER_MARGIN1_HOLDING, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding"],
     {"imitation_margin_weight": 1.0, "imitation_margin_against": "holding", "imitation_margin": 1.0}),
    (NOISE_PAPER_MARGIN1_HOLDING_SCALE, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding", "--network-scale-input"],
     {"imitation_margin_against": "holding", "network_scale_input": True}),
    (NOISE_PAPER_MARGIN1_HOLDING_SCALE_LOGRANGE, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding", "--network-scale-input",
      "--network-scale-encoding", "log-range"],
     {"network_scale_input": True, "network_scale_encoding": "log-range"}),
    (NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding",
      "--imitation-scales", "1.0", "1.0", "0.5"],
     {"imitation_scales": (1.0, 1.0, 0.5), "imitation_margin_against": "holding"}),
    (NOISE_PAPER_MARGIN1_HOLDING_DOUBLED, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding",
      "--imitation-scales", "1.0", "1.0", "0.5", "0.5"],
     {"imitation_scales": (1.0, 1.0, 0.5, 0.5), "imitation_margin_against": "holding"}),
    (NOISE_PAPER_MARGIN1_HOLDING_DOUBLE1M_ROUND3, SOFT_RELEASE_E2_NOISE_PAPER,
     ["--imitation-margin-weight", "1", "--imitation-margin-against", "holding",
      "--imitation-scales", "1.0", "1.0", "0.5", "--init-model", "quadnav_onboard/models/default.pt",
      "--init-model-sha256", "4fa02fa9dce4a108e7afa6194486274fbf9c3e7cddf451fd8db4df77c326ad70"],
     {"imitation_scales": (1.0, 1.0, 0.5), "init_model": "quadnav_onboard/models/default.pt"}),
], ids=["two-pass", "noise", "noise-paper", "failures-noise-paper", "margin1", "margin03", "margin3",
        "margin1-gap02", "margin3-gap02", "margin1-holding", "margin1-holding-scale",
        "margin1-holding-scale-logrange", "margin1-holding-double1m",
        "margin1-holding-doubled", "margin1-holding-double1m-round3"])
def test_a_recipe_file_is_its_base_with_the_flag_its_first_seeds_were_trained_with(
    recipe: Path, base: Path, flag: list[str], expect: dict[str, float]
) -> None:
    """recipes/...-soft-release-e2.yaml is the release recipe with ``--imitation-epochs 2`` (run
    rel-e2), ...-e2-noise.yaml that with ``--dagger-noise 0.1`` (run e2-n01), and
    ...-e2-noise-paper.yaml that with ``--lab-dagger-noise 0``, ...-failures-noise-paper.yaml the
    failure recipe with both, and ...-noise-paper-margin1.yaml / -margin03.yaml / -margin3.yaml the
    noise-paper recipe with ``--imitation-margin-weight 1`` / ``0.3`` / ``3``, and
    -margin1-gap02.yaml / -margin3-gap02.yaml those with ``--imitation-margin-min-gap-m 0.2``,
    and -margin1-holding.yaml weight 1 with ``--imitation-margin-against holding``, and
    -margin1-holding-scale.yaml that with ``--network-scale-input``, and -scale-logrange.yaml
    that with ``--network-scale-encoding log-range``, and -margin1-holding-double1m.yaml the holding
    keys with ``--imitation-scales 1.0 1.0 0.5``, and -margin1-holding-doubled.yaml with
    ``--imitation-scales 1.0 1.0 0.5 0.5``, and -double1m-round3.yaml the double-1m keys with
    ``--init-model`` the bundled model, pinned by its sha256, each its own name."""
    got = cmd_train.config_for(_parse(["--recipe", str(recipe)]))
    flags = cmd_train.config_for(_parse(["--recipe", str(base), *flag]))
    assert got.name == recipe.stem
    assert dataclasses.replace(got, name=flags.name) == flags
    assert {key: getattr(got, key) for key in expect} == expect


def test_shipped_recipe_file_is_the_holding_margin_recipe_s_seed_0() -> None:
    """recipes/shipped.yaml (the bundled model's keys) is
    recipes/...-noise-paper-margin1-holding.yaml at seed 0, so the recipe the docs call the bundled
    model's is the one it was trained with."""
    shipped = cmd_train.config_for(_parse(["--recipe", str(SHIPPED)]))
    holding = cmd_train.config_for(_parse(["--recipe", str(NOISE_PAPER_MARGIN1_HOLDING), "--seed", "0"]))
    assert shipped == holding


def test_flags_override_the_recipe_file_s_keys() -> None:
    """A flag beside --recipe wins over the file; the file's other keys stay."""
    cfg = cmd_train.config_for(_parse(["--recipe", str(SHIPPED), "--episodes", "3", "--seed", "7"]))
    base = cmd_train.config_for(_parse(["--recipe", str(SHIPPED)]))
    assert (cfg.episodes, cfg.seed) == (3, 7)
    assert dataclasses.replace(cfg, episodes=base.episodes, seed=base.seed) == base


def test_every_train_config_field_is_a_recipe_key(tmp_path: Path) -> None:
    """Keys map by field name: a file naming each field with its default loads to the defaults."""
    import yaml

    path = tmp_path / "all.yaml"
    path.write_text(yaml.safe_dump(TrainConfig().to_dict()), encoding="utf-8")
    assert load_train_config(cmd_train.load_recipe(path), str(path)) == TrainConfig()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("episodes: 100\nepisodez: 5\n", ["key 'episodez'", "unknown key"]),
        ("learning_rate: .nan\n", ["key 'learning_rate'", "nan"]),
        ("episodes: 0\n", ["key 'episodes'", "bad value 0"]),
        ("double_dqn: maybe\n", ["key 'double_dqn'", "maybe"]),
        ("procedural_families: [corridor, tunnels]\n", ["key 'procedural_families'", "tunnels"]),
        ("- episodes\n", ["expected a mapping"]),
        ("", ["empty"]),
    ],
)
def test_a_bad_recipe_is_refused_naming_file_key_and_value(
    tmp_path: Path, text: str, words: list[str]
) -> None:
    """Unknown keys, NaN, out-of-range values, wrong types, an unknown family, a list or an empty
    file: ConfigError naming the file (and the key and value where there is one)."""
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        cmd_train.config_for(_parse(["--recipe", str(path)]))
    message = str(err.value)
    assert str(path) in message
    for word in words:
        assert word.lower() in message.lower(), message


def test_train_command_exits_2_on_a_bad_recipe(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """quadnav-sim train --recipe with an unknown key trains nothing and exits 2 naming it."""
    path = tmp_path / "bad.yaml"
    path.write_text("episodez: 5\n", encoding="utf-8")
    args = _parse(["--recipe", str(path), "--out-dir", str(tmp_path / "runs")])
    assert cmd_train.run(args) == 2
    assert "episodez" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_a_base_recipe_s_keys_are_taken_and_the_file_s_own_keys_win(tmp_path: Path) -> None:
    """``base: FILE`` (relative to the naming file, not the working directory) takes every key of
    FILE; the naming file's keys override them; chains resolve in order."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "root.yaml").write_text("name: root\nepisodes: 50\nn_step: 3\n", encoding="utf-8")
    (tmp_path / "sub" / "mid.yaml").write_text("base: root.yaml\nname: mid\nn_step: 2\n", encoding="utf-8")
    (tmp_path / "leaf.yaml").write_text("base: sub/mid.yaml\nseed: 7\n", encoding="utf-8")
    cfg = cmd_train.config_for(_parse(["--recipe", str(tmp_path / "leaf.yaml"), "--episodes", "9"]))
    assert (cfg.name, cfg.episodes, cfg.n_step, cfg.seed) == ("mid", 9, 2, 7)
    keys = cmd_train.load_recipe(tmp_path / "leaf.yaml")
    assert keys == {"name": "mid", "episodes": 50, "n_step": 2, "seed": 7}


@pytest.mark.parametrize(
    ("files", "words"),
    [
        ({"a.yaml": "base: missing.yaml\n"}, ["a.yaml", "key 'base'", "missing.yaml", "no such recipe file"]),
        ({"a.yaml": "base: b.yaml\n", "b.yaml": "base: a.yaml\n"}, ["key 'base'", "loop", "b.yaml"]),
        ({"a.yaml": "base: a.yaml\n"}, ["key 'base'", "loop"]),
        ({"a.yaml": "base: 3\n"}, ["a.yaml", "key 'base'", "bad value 3"]),
        ({"a.yaml": "base: ''\n"}, ["a.yaml", "key 'base'", "bad value"]),
        ({"a.yaml": "base: b.yaml\nseed: 1\n", "b.yaml": "episodez: 5\n"}, ["b.yaml", "key 'episodez'"]),
        ({"a.yaml": "base: b.yaml\n", "b.yaml": "- episodes\n"}, ["b.yaml", "expected a mapping"]),
    ],
)
def test_a_bad_base_is_refused_naming_the_file_that_is_wrong(
    tmp_path: Path, files: dict[str, str], words: list[str]
) -> None:
    """A missing base, a loop of bases, a base that is not a path, or a bad key inside a base:
    ConfigError naming the file where the fault is, the key and the value."""
    for name, text in files.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        cmd_train.config_for(_parse(["--recipe", str(tmp_path / "a.yaml")]))
    message = str(err.value)
    for word in words:
        assert word.lower() in message.lower(), message


def test_a_chain_of_bases_longer_than_the_limit_is_refused(tmp_path: Path) -> None:
    """Bases chain at most ``MAX_BASE_DEPTH`` files deep; one more is refused, naming the limit."""
    n = cmd_train.MAX_BASE_DEPTH + 1
    for i in range(n):
        text = f"base: r{i + 1}.yaml\n" if i < n - 1 else "episodes: 5\n"
        (tmp_path / f"r{i}.yaml").write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=f"more than {cmd_train.MAX_BASE_DEPTH}"):
        cmd_train.load_recipe(tmp_path / "r0.yaml")
    assert cmd_train.load_recipe(tmp_path / "r1.yaml") == {"episodes": 5}


@pytest.mark.parametrize(
    ("name", "scale"), [("default.eval.json", 1.0), ("default.eval.flight-scale.json", 0.5)]
)
def test_the_committed_eval_files_are_the_bundled_model_s(name: str, scale: float) -> None:
    """quadnav_onboard/models/default.eval*.json (the docs' headline flights with the filter, eval
    seed 0) were flown by the default.pt that is bundled now, at their scale, and their summary
    counts their rows: a new model without new eval files fails here."""
    data = json.loads((DEFAULT_MODEL_PATH.parent / name).read_text())
    assert data["model_sha256"] == load_checkpoint(DEFAULT_MODEL_PATH).sha256
    assert (data["primitive_scale_m"], data["trials"], data["seed"], data["shield"]["enabled"]) == (
        scale, 10, 0, True)
    rows = data["rows"]
    assert len(rows) == data["summary"]["trials"] == 100
    assert sum(r["outcome"] == "goal" for r in rows) == data["summary"]["goal"]
    assert sum(r["crash"] == "N" for r in rows) == data["summary"]["collision_free"]
    # flown from the repository root: the files name the model and worlds as the checkout does
    assert data["model"] == "quadnav_onboard/models/default.pt"
    assert all(w.startswith("sim_harness/worlds/env") for w in data["worlds"])
