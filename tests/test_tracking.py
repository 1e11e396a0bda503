"""CLEAR-MOT (py-motmetrics' accumulator behind eval/tracking.py): hand-checked cases, counts frozen
from the hand-written accumulator it replaced (which agreed with it exactly on 82 random and
adversarial sequences: ties, objects appearing and vanishing, identity swaps, string ids), and the
summing of many sequences."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from idsplat_ns.errors import IDSplatError
from idsplat_ns.eval.tracking import PAPER_THRESHOLDS, clear_mot, clear_mot_sequences, format_table

import motmetrics as mm

MM_METRICS = ["num_frames", "num_objects", "num_predictions", "num_matches", "num_switches",
              "num_false_positives", "num_misses", "mota", "motp", "recall", "precision"]


def _accumulate(gt, pred, threshold: float) -> "mm.MOTAccumulator":
    acc = mm.MOTAccumulator(auto_id=False)
    frames = sorted(set(gt) | set(pred))
    for f in frames:
        g, p = gt.get(f, {}), pred.get(f, {})
        oids, hids = list(g), list(p)
        d = np.full((len(oids), len(hids)), np.nan)
        for i, o in enumerate(oids):
            for j, h in enumerate(hids):
                dist = float(np.linalg.norm(np.asarray(g[o], float) - np.asarray(p[h], float)))
                d[i, j] = dist if dist <= threshold else np.nan
        acc.update(oids, hids, d, frameid=f)
    return acc


def _assert_same(ours, theirs) -> None:
    mine = {"num_frames": ours.num_frames, "num_objects": ours.num_objects, "num_predictions": ours.num_predictions,
            "num_matches": ours.num_matches, "num_switches": ours.num_switches,
            "num_false_positives": ours.num_false_positives, "num_misses": ours.num_misses,
            "mota": ours.mota, "motp": ours.motp, "recall": ours.recall, "precision": ours.precision}
    for name in MM_METRICS:
        a, b = float(mine[name]), float(theirs[name])
        if math.isnan(b):
            assert math.isnan(a), name
        else:
            assert a == pytest.approx(b, abs=1e-9, rel=0), (name, a, b)


def _random_sequence(rng: np.random.Generator, frames: int = 30, objects: int = 8, grid: bool = False):
    """Objects moving, appearing and vanishing; predictions with noise, drops, extra tracks and
    swapped ids. ``grid`` snaps positions to a 1 m grid so that distance ties are common."""
    start = rng.uniform(-20, 20, (objects, 3))
    vel = rng.normal(0, 1, (objects, 3))
    alive_from = rng.integers(0, frames // 2, objects)
    alive_to = rng.integers(frames // 2, frames + 1, objects)
    id_map = {o: 100 + o for o in range(objects)}
    gt, pred = {}, {}
    for f in range(frames):
        if rng.random() < 0.1:  # the tracker swaps two identities from here on
            a, b = rng.choice(objects, 2, replace=False)
            id_map[a], id_map[b] = id_map[b], id_map[a]
        g, p = {}, {}
        for o in rng.permutation(objects):
            if not alive_from[o] <= f < alive_to[o]:
                continue
            pos = start[o] + vel[o] * f
            if grid:
                pos = np.round(pos / 2.0)  # coarse positions: many objects share distances
            g[int(o)] = pos
            if rng.random() < 0.85:
                noise = rng.integers(-2, 3, 3) * 0.5 if grid else rng.normal(0, 1.5, 3)
                p[id_map[int(o)]] = pos + noise
        for k in range(rng.integers(0, 3)):  # false tracks
            p[500 + int(rng.integers(0, 5))] = rng.uniform(-20, 20, 3) if not grid else np.round(rng.uniform(-10, 10, 3))
        if g or rng.random() < 0.5:
            gt[f] = g
        if p or rng.random() < 0.5:
            pred[f] = p
    return gt, pred


def test_hand_checked_sequence() -> None:
    gt = {0: {1: [0, 0, 0], 2: [10, 0, 0]}, 1: {1: [1, 0, 0], 2: [11, 0, 0]}, 2: {1: [2, 0, 0]}, 3: {1: [3, 0, 0]}}
    pred = {0: {"a": [0.2, 0, 0], "b": [10, 0.5, 0]}, 1: {"a": [1, 0.3, 0], "b": [30, 0, 0]},
            2: {"c": [2, 0, 0.1]}, 3: {"c": [3, 0, 0]}}
    r = clear_mot(gt, pred, [1.0])[1.0]
    # Frame 0: 1-a, 2-b; frame 1: 1-a, 2 missed, b FP; frame 2: 1-c is a switch; frame 3: 1-c continues.
    assert (r.num_frames, r.num_objects, r.num_predictions) == (4, 6, 6)
    assert (r.num_matches, r.num_switches, r.num_false_positives, r.num_misses) == (4, 1, 1, 1)
    assert r.mota == pytest.approx(1 - 3 / 6)
    assert r.motp == pytest.approx((0.2 + 0.5 + 0.3 + 0.1 + 0.0) / 5)
    assert r.recall == pytest.approx(5 / 6) and r.precision == pytest.approx(5 / 6)
    assert "| 1 | 4 | 6 | 6 | 4 | 1 | 1 | 1 | 0.50 |" in format_table({1.0: r})
    # Identities, by hand: whole trajectories matched one to one, 1-a (or 1-c: 2 frames each) and
    # 2-b (frame 0): IDTP 3 of 6 objects and 6 predictions, IDF1 = 6 / (6 + 3 + 3).
    assert (r.id_true_positives, r.id_false_positives, r.id_false_negatives) == (3, 3, 3)
    assert r.idf1 == pytest.approx(0.5)
    assert r.num_fragmentations == 0  # 1 is tracked in every frame (by a switch), 2 only at its start


def test_fragmentations_count_each_interruption_tracked_again() -> None:
    gt = {f: {1: [float(f), 0, 0]} for f in range(7)}
    tracked = (0, 1, 3, 5, 6)  # lost in frames 2 and 4, found again each time: 2 fragmentations
    pred = {f: {"a": [float(f), 0.1, 0]} for f in tracked}
    r = clear_mot(gt, pred, [1.0])[1.0]
    assert r.num_fragmentations == 2 and r.num_misses == 2 and r.num_switches == 0
    assert (r.id_true_positives, r.id_false_positives, r.id_false_negatives) == (5, 0, 2)
    assert r.idf1 == pytest.approx(10 / 12)
    # A prediction in a region that does not count takes no part in the identity matching either.
    pred[6]["z"] = [40.0, 0, 0]
    assert clear_mot(gt, pred, [1.0], dont_care={6: {"z"}})[1.0].idf1 == pytest.approx(10 / 12)
    assert clear_mot(gt, pred, [1.0])[1.0].id_false_positives == 1


def test_continuity_beats_a_closer_newcomer() -> None:
    # Object 1 is tracked by "a"; in frame 1 "b" is closer, but "a" is still within the threshold.
    gt = {0: {1: [0, 0, 0]}, 1: {1: [0, 0, 0]}}
    pred = {0: {"a": [0.5, 0, 0]}, 1: {"a": [0.9, 0, 0], "b": [0.1, 0, 0]}}
    r = clear_mot(gt, pred, [1.0])[1.0]
    assert (r.num_matches, r.num_switches, r.num_false_positives) == (2, 0, 1)
    assert r.motp == pytest.approx(0.7)


# (objects, predictions, matches, switches, FP, FN, summed matched distance) at 1, 2 and 5 m, as the
# hand-written accumulator counted them before it was replaced by motmetrics.
FROZEN = {
    (0, False): {1.0: (131, 133, 8, 1, 124, 122, 7.244864), 2.0: (131, 133, 35, 2, 96, 94, 51.89833),
                 5.0: (131, 133, 103, 2, 28, 26, 249.871492)},
    (1, True): {1.0: (104, 118, 14, 0, 104, 90, 11.047824), 2.0: (104, 118, 82, 4, 32, 18, 105.969356),
                5.0: (104, 118, 81, 6, 31, 17, 108.205424)},
    (3, True): {1.0: (127, 143, 31, 4, 108, 92, 25.522515), 2.0: (127, 143, 105, 3, 35, 19, 123.9129),
                5.0: (127, 143, 105, 3, 35, 19, 123.9129)},
}


@pytest.mark.parametrize("seed,grid", sorted(FROZEN))
def test_counts_match_the_replaced_accumulator(seed: int, grid: bool) -> None:
    gt, pred = _random_sequence(np.random.default_rng(seed), grid=grid)
    if seed == 3:  # string object ids and predictions work as well as numbers
        gt = {f: {f"o{k}": v for k, v in objs.items()} for f, objs in gt.items()}
        pred = {f: {f"h{k}": v for k, v in objs.items()} for f, objs in pred.items()}
    ours = clear_mot(gt, pred, (1.0, 2.0, 5.0))
    for t, expected in FROZEN[(seed, grid)].items():
        r = ours[t]
        got = (r.num_objects, r.num_predictions, r.num_matches, r.num_switches, r.num_false_positives, r.num_misses)
        assert got == expected[:6], t
        assert r.total_distance == pytest.approx(expected[6], abs=1e-5)


def test_adversarial_ties_and_empty_frames() -> None:
    # Two objects equidistant from two predictions, objects vanishing and reappearing, empty frames.
    gt = {0: {1: [0, 0, 0], 2: [2, 0, 0]}, 1: {1: [0, 0, 0], 2: [2, 0, 0]}, 2: {}, 3: {2: [2, 0, 0]},
          4: {1: [1, 0, 0], 2: [1, 0, 0]}, 5: {1: [0, 0, 0]}, 7: {3: [5, 5, 5]}}
    pred = {0: {11: [1, 0, 0], 12: [1, 0, 0]}, 1: {12: [1, 0, 0], 11: [1, 0, 0]}, 2: {11: [1, 0, 0]},
            3: {11: [1, 0, 0]}, 4: {12: [1, 0, 0], 13: [1, 0, 0]}, 6: {12: [0, 0, 0]}, 7: {}}
    ours = clear_mot(gt, pred, PAPER_THRESHOLDS)
    r = ours[0.5]  # only frame 4's exact overlaps are within 0.5 m
    assert (r.num_frames, r.num_objects, r.num_predictions, r.num_matches, r.num_switches) == (8, 9, 9, 2, 0)
    assert (r.num_false_positives, r.num_misses, r.total_distance) == (7, 7, 0.0)
    r = ours[1.0]
    assert (r.num_matches, r.num_switches, r.num_false_positives, r.num_misses, r.total_distance) == (4, 3, 2, 2, 5.0)
    assert all(ours[t] == replace(r, threshold=t) for t in (2.0, 3.0, 5.0, 10.0))


def test_many_sequences_agree_with_motmetrics_overall() -> None:
    rng = np.random.default_rng(42)
    seqs = [_random_sequence(rng, frames=15 + 5 * k) for k in range(4)]
    ours = clear_mot_sequences(seqs, PAPER_THRESHOLDS)
    mh = mm.metrics.create()
    for t in PAPER_THRESHOLDS:
        accs = [_accumulate(g, p, t) for g, p in seqs]
        names = [f"s{k}" for k in range(4)]
        summary = mh.compute_many(accs, metrics=MM_METRICS, names=names, generate_overall=True)
        overall = summary.loc["OVERALL"].copy()
        # motmetrics 1.4.0 sums motp * detections over sequences, so a sequence without any
        # detection (motp NaN) makes its overall MOTP NaN; the reference is that sum without them.
        det = summary.loc[names, "num_matches"] + summary.loc[names, "num_switches"]
        has = det > 0
        overall["motp"] = float((summary.loc[names, "motp"][has] * det[has]).sum() / det[has].sum())
        _assert_same(ours[t], overall)


def test_metrics_improve_with_threshold_like_the_paper() -> None:
    gt, pred = _random_sequence(np.random.default_rng(7))
    res = clear_mot(gt, pred)
    assert sorted(res) == list(PAPER_THRESHOLDS)
    mota = [res[t].mota for t in PAPER_THRESHOLDS]
    recall = [res[t].recall for t in PAPER_THRESHOLDS]
    assert recall == sorted(recall) and mota[-1] > mota[0]


def test_bad_positions_raise() -> None:
    with pytest.raises(IDSplatError, match="finite"):
        clear_mot({0: {1: [np.nan, 0, 0]}}, {0: {2: [0, 0, 0]}}, [1.0])


def test_trajectory_plot_png(tmp_path) -> None:
    from matplotlib.image import imread

    from idsplat_ns.eval.trajectory_plots import plot_trajectories, tracks_by_id

    gt, pred = _random_sequence(np.random.default_rng(3), frames=20, objects=3)
    grouped = tracks_by_id(gt)
    assert sum(len(v) for v in grouped.values()) == sum(len(f) for f in gt.values())
    out = plot_trajectories([("seq A", gt, pred), ("seq B", gt, {})], tmp_path / "plots" / "traj.png", panel_size=3.0)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = imread(out)
    assert img.shape[:2] == (300, 600)  # 2 panels of 3 inches at 100 dpi
    rgb = img[..., :3]
    coloured = (rgb.max(axis=2) - rgb.min(axis=2)) > 0.3  # predicted tracks are drawn in colour
    assert coloured.sum() > 100
    assert not any(p.name.endswith(".tmp") for p in out.parent.iterdir())
    with pytest.raises(IDSplatError, match="no sequence"):
        plot_trajectories([], tmp_path / "x.png")


def test_dont_care_predictions_match_but_are_no_false_positives() -> None:
    gt = {0: {1: [0, 0, 0]}, 1: {1: [1, 0, 0]}}
    pred = {0: {"a": [0.1, 0, 0], "b": [9, 0, 0]}, 1: {"b": [1.2, 0, 0], "c": [20, 0, 0]}}
    plain = clear_mot(gt, pred, [1.0])[1.0]
    assert (plain.num_predictions, plain.num_false_positives, plain.num_switches) == (4, 2, 1)
    # "b" is don't care in both frames: unmatched in frame 0 it is ignored, matched in frame 1 it
    # still counts (a switch from "a"); "c" stays a false positive.
    r = clear_mot(gt, pred, [1.0], dont_care={0: {"b"}, 1: {"b"}})[1.0]
    assert (r.num_predictions, r.num_false_positives, r.num_matches, r.num_switches) == (3, 1, 1, 1)
    assert r.mota == pytest.approx(1 - 2 / 2) and r.motp == pytest.approx(0.15)
