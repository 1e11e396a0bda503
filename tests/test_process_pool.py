"""Instances in worker processes (instances/process_pool.py): the same results as in one process,
in item order; how many workers; a worker that dies ends in one line."""

from __future__ import annotations

import operator
import os

import numpy as np
import pytest

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lifting import LiftedInstances
from idsplat_ns.instances.process_pool import available_cores, map_instances, resolve_workers
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_estimation import estimate_trajectories

from test_instances_registration_chain import _front_then_rear


def _die(shared: int, item: int) -> int:  # module level: the spawned worker imports it
    os._exit(3)


def test_items_come_back_in_order_from_every_worker_count():
    items = [5, 1, 9, 2, 7]
    one = map_instances(operator.add, 100, items, 1, items, "test", progress=False)
    two = map_instances(operator.add, 100, items, 2, items, "test", progress=False)
    assert one == two == [105, 101, 109, 102, 107]


def test_how_many_workers():
    assert resolve_workers(1, 10, 10_000, 300) == 1
    assert resolve_workers(0, 10, 299, 300) == 1  # small: in this process
    assert resolve_workers(0, 10, 300, 300) == min(available_cores(), 10)
    assert resolve_workers(8, 3, 10, 300) == 3  # never more than the instances
    assert resolve_workers(0, 0, 0, 300) == 1
    with pytest.raises(IDSplatError, match="preprocess.workers"):
        resolve_workers(-1, 10, 10, 300)


def test_a_worker_that_dies_ends_in_one_line():
    with pytest.raises(IDSplatError, match="worker process stopped.*preprocess.workers 1") as err:
        map_instances(_die, 0, [1, 2], 2, [1, 2], "registration", progress=False)
    assert "\n" not in str(err.value)


def test_registration_in_two_processes_gives_the_same_tracks():
    scene, lifted, features = _front_then_rear()
    # The car twice (instances 5 and 7): each splits into its front and rear views, the second
    # parts numbered after the highest instance, in instance order.
    lifted = LiftedInstances({5: "car", 7: "car"}, {5: lifted.observations[5], 7: lifted.observations[5]})
    features = PointFeatures("test", {**features.features, **{(7, f): v for (_, f), v in features.features.items()}}, {})
    one = estimate_trajectories(scene, lifted, features, TrajectoryConfig(), progress=False, workers=1)
    two = estimate_trajectories(scene, lifted, features, TrajectoryConfig(), progress=False, workers=2)
    assert [t.instance_id for t in two.instances] == [t.instance_id for t in one.instances] == [5, 8, 7, 9]
    assert two.metadata == one.metadata
    for a, b in zip(one.instances, two.instances):
        assert np.array_equal(a.poses, b.poses) and np.array_equal(a.valid, b.valid)
        assert np.array_equal(a.canonical_points, b.canonical_points)


def test_negative_workers_end_in_one_line_before_any_work(capsys):
    from idsplat_ns.cli.preprocess import main
    from idsplat_ns.instances.runner import PreprocessConfig

    with pytest.raises(IDSplatError, match="preprocess.workers"):
        PreprocessConfig(workers=-1)
    with pytest.raises(SystemExit) as exit_:
        main(["--preprocess.workers", "-1", "--builtin-preset", "tiny"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2 and len(err) == 1 and "workers=-1" in err[0], err
