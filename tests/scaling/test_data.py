"""Training data: the dataset spec, static-hold episodes, and the two interchangeable back ends."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scaling.data.holds import draw_hold, make_hold_policy, pose_in_workspace
from scaling.data.recordings import (
    STANDARD,
    DatasetSpec,
    StaleRecordingsWarning,
    dataset_hash,
    generate_frame,
    generate_recordings,
    load_or_generate,
    load_recordings,
    prepare,
)
from scaling.evaluation import metrics as ev

ONE = DatasetSpec(machines=(("er12", "er12"),), soils=("gravel",), pile_heights=(0.7,), dig_seeds=1,
                  hold_episodes=1, hold_poses=2)


def test_every_episode_has_its_own_seed() -> None:
    tasks = STANDARD.tasks()
    seeds = [t.seed for _, _, t in tasks]
    assert len(set(seeds)) == len(seeds) == 2 * (4 * 3 * 4 + 16)
    assert {k for _, k, _ in tasks} == {"dig", "hold"}
    assert DatasetSpec.from_dict(STANDARD.to_dict()) == STANDARD


def test_hold_draws_are_seeded_and_inside_the_workspace() -> None:
    assert draw_hold(3) == draw_hold(3) != draw_hold(4)
    for boom, pitch in draw_hold(5, n_poses=6)["poses"]:
        assert pose_in_workspace(boom, pitch)
    assert not pose_in_workspace(0.8, 0.2)  # tilt cylinder against its stop there
    assert make_hold_policy(seed=2).poses == draw_hold(2)["poses"]


def test_back_ends_agree_and_holds_reach_rest(tmp_path: Path) -> None:
    frame = generate_frame(ONE)
    generate_recordings(ONE, tmp_path, executor="serial", progress=False)
    recorded = load_recordings(tmp_path)
    assert dataset_hash(frame) == dataset_hash(recorded)
    pd.testing.assert_frame_equal(frame.drop(columns="episode_key"), recorded.drop(columns="episode_key"))
    assert list(frame.columns[:6]) == ["machine", "episode", "episode_key", "kind", "soil", "t"]
    hold = frame[frame["kind"] == "hold"]
    at_rest = ev.at_rest(hold)
    assert at_rest.sum() >= 10  # the static-hold episode provides near-static rows from the simulator
    assert np.all(hold.loc[at_rest, "m_b"] > hold["m_b"].min() - 1e-9)
    # a rerun skips recorded episodes and returns the same table
    generate_recordings(ONE, tmp_path, executor="serial", progress=False)
    assert dataset_hash(load_recordings(tmp_path)) == dataset_hash(frame)


def test_episodes_are_numbered_in_task_order_not_key_order(tmp_path: Path) -> None:
    """Episode ids (and so every positional draw downstream: reference rows, training pairs) follow the data
    set's task order in both back ends; renaming every episode's key, as a schema or preset change does, changes
    nothing else."""
    frame = generate_frame(ONE)
    tasks = [task.key() for _, _, task in ONE.tasks()]
    first = frame.drop_duplicates("episode")
    assert first["episode_key"].tolist() == tasks
    renamed = frame.assign(episode_key=frame["episode_key"].map({k: f"{9 - i}-{k}" for i, k in enumerate(tasks)}))
    again = prepare(renamed)
    pd.testing.assert_frame_equal(again.drop(columns="episode_key"), frame.drop(columns="episode_key"))


def test_a_reused_folder_returns_only_the_episodes_of_the_spec(tmp_path: Path) -> None:
    """A recordings folder reused after the spec changed (here: the same label on a 0.9-scale machine) keeps the
    old episodes on disk; ``load_or_generate`` records the new ones, returns only those, and warns."""
    first = load_or_generate(tmp_path, ONE, executor="serial", progress=False)
    other = DatasetSpec(machines=(("er12", 0.9),), soils=("gravel",), pile_heights=(0.7,), dig_seeds=1,
                        hold_episodes=1, hold_poses=2)
    with pytest.warns(StaleRecordingsWarning, match="2 recorded episodes are not in this data set's spec"):
        second = load_or_generate(tmp_path, other, executor="serial", progress=False)
    assert set(second["episode_key"]) == {task.key() for _, _, task in other.tasks()}
    assert not set(second["episode_key"]) & set(first["episode_key"])
    assert dataset_hash(second) == dataset_hash(generate_frame(other))
