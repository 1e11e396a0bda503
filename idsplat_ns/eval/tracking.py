"""CLEAR-MOT tracking metrics (Bernardin & Stiefelhagen 2008) on object centres, at several distance
thresholds, over one or many sequences (the paper's supplementary "Tracking results" table).

Per frame and threshold: (1) a ground-truth object keeps the prediction it was last matched to if
that prediction is present and within the threshold (identity continuity); (2) the remaining pairs
within the threshold are assigned by the Hungarian algorithm, maximising the number of pairs and
then minimising the summed distance; a pair whose object was last matched to another prediction is
an ID switch; (3) unmatched objects are misses (FN), unmatched predictions false positives (FP).
``MOTA = 1 - (FN + FP + switches) / objects``; ``MOTP`` is the mean distance [m] of matched pairs
(switches included). Follows py-motmetrics' accumulator rules, so counts agree with it exactly.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from idsplat_ns.errors import IDSplatError

PAPER_THRESHOLDS: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 5.0, 10.0)
"""Distance thresholds [m] of the paper's tracking table."""

FrameObjects = Mapping[Hashable, Sequence[float]]  # object id -> xyz [3]
Track = Mapping[Hashable, FrameObjects]  # frame -> objects in it

_MISSING = object()  # sentinel: an object without a previous match


@dataclass(frozen=True)
class TrackingMetrics:
    """CLEAR-MOT counts and scores at one distance threshold."""

    threshold: float  # matching distance threshold [m]
    num_frames: int  # frames evaluated (union of ground-truth and prediction frames)
    num_objects: int  # ground-truth object appearances
    num_predictions: int  # predicted object appearances
    num_matches: int  # matched pairs that are not ID switches
    num_switches: int  # matched pairs whose object was last matched to another prediction
    num_false_positives: int  # predictions left unmatched
    num_misses: int  # ground-truth objects left unmatched (FN)
    total_distance: float  # summed distance of all matched pairs (switches included) [m]

    @property
    def num_detections(self) -> int:
        """All matched pairs (matches + switches)."""
        return self.num_matches + self.num_switches

    @property
    def mota(self) -> float:
        """``1 - (FN + FP + switches) / objects`` (NaN without objects)."""
        if self.num_objects == 0:
            return float("nan")
        return 1.0 - (self.num_misses + self.num_false_positives + self.num_switches) / self.num_objects

    @property
    def motp(self) -> float:
        """Mean distance of matched pairs [m] (NaN without matches)."""
        return self.total_distance / self.num_detections if self.num_detections else float("nan")

    @property
    def recall(self) -> float:
        """Matched pairs / ground-truth objects."""
        return self.num_detections / self.num_objects if self.num_objects else float("nan")

    @property
    def precision(self) -> float:
        """Matched pairs / predictions."""
        return self.num_detections / self.num_predictions if self.num_predictions else float("nan")


def _assign(cost: np.ndarray) -> list[tuple[int, int]]:  # cost: [N, M], NaN = not allowed
    """Pairs of a maximum-cardinality, then minimum-cost assignment over the finite entries.

    Forbidden entries get a constant so large that using one is always worse than any assignment
    of allowed pairs (``2 r c + 1``, with ``r`` the smaller side and ``c`` above every allowed cost).
    """
    allowed = np.isfinite(cost)
    if not allowed.any():
        return []
    c = float(np.abs(cost[allowed]).max()) + 1.0
    big = 2.0 * min(cost.shape) * c + 1.0
    rows, cols = linear_sum_assignment(np.where(allowed, cost, big))
    return [(int(i), int(j)) for i, j in zip(rows, cols) if allowed[i, j]]


def _positions(objects: FrameObjects, where: str) -> tuple[list[Hashable], np.ndarray]:
    ids = list(objects.keys())
    if not ids:
        return ids, np.zeros((0, 3))
    xyz = np.array([np.asarray(objects[i], dtype=np.float64).reshape(-1) for i in ids], dtype=np.float64)
    if (xyz.shape[1] not in (2, 3) or not np.all(np.isfinite(xyz))):
        raise IDSplatError(f"clear_mot: {where} positions must be finite 2-D or 3-D points")
    return ids, xyz


def frame_sort_key(frame: Hashable) -> tuple[int, object]:
    """Order frames: numbers numerically first, then anything else by its string."""
    return (0, frame) if isinstance(frame, (int, float, np.integer, np.floating)) else (1, str(frame))


def _clear_mot_one(gt: Track, pred: Track, threshold: float) -> TrackingMetrics:
    frames = sorted(set(gt.keys()) | set(pred.keys()), key=frame_sort_key)
    last_match: dict[Hashable, Hashable] = {}  # object id -> prediction id it was last matched to
    n_obj = n_pred = n_match = n_switch = n_fp = n_miss = 0
    total = 0.0
    for frame in frames:
        oids, o_xyz = _positions(gt.get(frame, {}), f"ground truth of frame {frame!r}")
        hids, h_xyz = _positions(pred.get(frame, {}), f"predictions of frame {frame!r}")
        n_obj += len(oids)
        n_pred += len(hids)
        if oids and hids:
            if o_xyz.shape[1] != h_xyz.shape[1]:
                raise IDSplatError(f"clear_mot: frame {frame!r} mixes 2-D and 3-D positions")
            dist = np.linalg.norm(o_xyz[:, None, :] - h_xyz[None, :, :], axis=2)
            dist[dist > threshold] = np.nan
        else:
            dist = np.full((len(oids), len(hids)), np.nan)
        o_used = np.zeros(len(oids), dtype=bool)
        h_used = np.zeros(len(hids), dtype=bool)
        h_index = {h: j for j, h in enumerate(hids)}
        # 1. Identity continuity: keep last frame's pairs that are still within the threshold.
        for i, o in enumerate(oids):
            j = h_index.get(last_match.get(o, _MISSING))
            if j is not None and not h_used[j] and np.isfinite(dist[i, j]):
                o_used[i] = h_used[j] = True
                n_match += 1
                total += float(dist[i, j])
        # 2. Hungarian assignment of the rest.
        rest = dist.copy()
        rest[o_used, :] = np.nan
        rest[:, h_used] = np.nan
        for i, j in _assign(rest):
            o, h = oids[i], hids[j]
            if o in last_match and last_match[o] != h:
                n_switch += 1
            else:
                n_match += 1
            total += float(dist[i, j])
            last_match[o] = h
            o_used[i] = h_used[j] = True
        # 3./4. Leftovers.
        n_miss += int((~o_used).sum())
        n_fp += int((~h_used).sum())
    return TrackingMetrics(
        threshold=float(threshold), num_frames=len(frames), num_objects=n_obj, num_predictions=n_pred,
        num_matches=n_match, num_switches=n_switch, num_false_positives=n_fp, num_misses=n_miss,
        total_distance=total,
    )


def clear_mot(gt: Track, pred: Track, thresholds: Sequence[float] = PAPER_THRESHOLDS) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT metrics of one sequence at each distance threshold [m].

    ``gt`` and ``pred`` map each frame (any sortable key, e.g. a frame index or timestamp) to
    ``{object_id: xyz}``; a frame may be missing from either. Object and prediction ids are
    independent namespaces. Returns ``{threshold: TrackingMetrics}``.
    """
    return {float(t): _clear_mot_one(gt, pred, float(t)) for t in thresholds}


def aggregate(per_sequence: Sequence[Mapping[float, TrackingMetrics]]) -> dict[float, TrackingMetrics]:
    """Sum the counts (and matched distances) of several sequences, threshold by threshold."""
    if not per_sequence:
        raise IDSplatError("tracking aggregate: no sequence given")
    out: dict[float, TrackingMetrics] = {}
    for t in per_sequence[0]:
        rows = [seq[t] for seq in per_sequence]
        out[t] = TrackingMetrics(
            threshold=t,
            num_frames=sum(r.num_frames for r in rows),
            num_objects=sum(r.num_objects for r in rows),
            num_predictions=sum(r.num_predictions for r in rows),
            num_matches=sum(r.num_matches for r in rows),
            num_switches=sum(r.num_switches for r in rows),
            num_false_positives=sum(r.num_false_positives for r in rows),
            num_misses=sum(r.num_misses for r in rows),
            total_distance=sum(r.total_distance for r in rows),
        )
    return out


def clear_mot_sequences(
    sequences: Sequence[tuple[Track, Track]], thresholds: Sequence[float] = PAPER_THRESHOLDS
) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT over many ``(gt, pred)`` sequences (identities never carry across sequences)."""
    return aggregate([clear_mot(gt, pred, thresholds) for gt, pred in sequences])


def format_table(results: Mapping[float, TrackingMetrics]) -> str:
    """A markdown table with the paper's columns, one row per threshold."""
    lines = [
        "| Dist. threshold [m] | Frames | Objects | Predictions | Matches | Switches | FP | FN | MOTA | MOTP | Recall | Precision |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t, r in sorted(results.items()):
        lines.append(
            f"| {t:g} | {r.num_frames} | {r.num_objects} | {r.num_predictions} | {r.num_matches} | {r.num_switches} "
            f"| {r.num_false_positives} | {r.num_misses} | {r.mota:.2f} | {r.motp:.2f} | {r.recall:.2f} | {r.precision:.2f} |"
        )
    return "\n".join(lines)
