"""The test-set options, worded once for every command that evaluates (train, evaluate)."""

from __future__ import annotations

TEST_SET_HELP = (
    "grid, uniform, a set the environment names (Parkour: walking, climbing, swimming) or a "
    ".json/.csv file of tasks"
)
NB_TEST_EPISODES_HELP = (
    "size of a generated test set; a grid keeps floor(n^(1/d)) points per varying dimension "
    "(Stump Tracks' default grid: 25 -> 5 x 5, 8 -> 2 x 2), and the command says so"
)


def add_test_set_arguments(
    group, test_set_default: str, nb_default: int, unset_is_none: bool = False,
    nb_default_text: str | None = None,
) -> None:  # fmt: skip
    """--test-set and --nb-test-episodes, each help ending with this command's default
    (`unset_is_none`: an absent option reads None, for commands that merge config files or
    tell an absent option from one given; `nb_default_text`: the default in words)."""
    group.add_argument("--test-set", help=f"{TEST_SET_HELP} (default: {test_set_default})")
    group.add_argument(
        "--nb-test-episodes",
        type=int,
        default=None if unset_is_none else nb_default,
        help=f"{NB_TEST_EPISODES_HELP} (default {nb_default_text or nb_default})",
    )
