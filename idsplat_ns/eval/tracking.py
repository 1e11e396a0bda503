"""CLEAR-MOT tracking metrics (Bernardin & Stiefelhagen 2008) on object centres, at several distance
thresholds, over one or many sequences (the paper's supplementary "Tracking results" table).

The per-frame accumulation is py-motmetrics' ``MOTAccumulator``: (1) a ground-truth object keeps the
prediction it was last matched to if that prediction is present and within the threshold; (2) the
remaining pairs within the threshold are assigned by the Hungarian algorithm; a pair whose object was
last matched to another prediction is an ID switch; (3) unmatched objects are misses (FN), unmatched
predictions false positives (FP). ``MOTA = 1 - (FN + FP + switches) / objects``; ``MOTP`` is the mean
distance [m] of matched pairs (switches included). Over several sequences the counts and matched
distances are summed (a sequence without matches adds nothing to MOTP, unlike motmetrics' OVERALL row).

Beside CLEAR-MOT, from the same accumulator: fragmentations (a ground-truth trajectory tracked,
then lost, then tracked again, once per interruption) and the identity scores of Ristani et al.
2016 (motmetrics' global one-to-one matching of whole trajectories: IDTP, IDFP, IDFN and
``IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN)``); predictions in regions that do not count are left
out of the identity matching.
"""

from __future__ import annotations

from collections.abc import Collection, Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Optional

import motmetrics
import numpy as np

from idsplat_ns.errors import IDSplatError

PAPER_THRESHOLDS: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 5.0, 10.0)
"""Distance thresholds [m] of the paper's tracking table."""

FrameObjects = Mapping[Hashable, Sequence[float]]  # object id -> xyz [3]
Track = Mapping[Hashable, FrameObjects]  # frame -> objects in it


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
    num_fragmentations: int = 0  # interruptions of ground-truth trajectories that are tracked again
    id_true_positives: int = 0  # IDTP: object appearances matched to their trajectory's one prediction
    id_false_positives: int = 0  # IDFP
    id_false_negatives: int = 0  # IDFN

    @property
    def idf1(self) -> float:
        """``2 IDTP / (2 IDTP + IDFP + IDFN)`` (NaN with neither objects nor predictions)."""
        denominator = 2 * self.id_true_positives + self.id_false_positives + self.id_false_negatives
        return 2 * self.id_true_positives / denominator if denominator else float("nan")

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


def _distances(oids: list, o_xyz: np.ndarray, hids: list, h_xyz: np.ndarray, frame: Hashable) -> np.ndarray:
    """[N, M] centre distances [m] of a frame's objects and predictions."""
    if not oids or not hids:
        return np.zeros((len(oids), len(hids)))
    if o_xyz.shape[1] != h_xyz.shape[1]:
        raise IDSplatError(f"clear_mot: frame {frame!r} mixes 2-D and 3-D positions")
    return np.linalg.norm(o_xyz[:, None, :] - h_xyz[None, :, :], axis=2)


def _counts(acc: motmetrics.MOTAccumulator, dont_care: list[set[int]]) -> dict[str, float]:
    """Event counts of an accumulator; a prediction left unmatched in a frame where it is in
    ``dont_care[frame]`` is neither a false positive nor a prediction."""
    ev = acc.mot_events  # one row per MATCH / SWITCH / MISS / FP (+ sub-events), indexed (frame, event)
    kind = ev["Type"].to_numpy()
    fp_frames = ev.index.get_level_values(0).to_numpy()[kind == "FP"]
    fp_ids = ev["HId"].to_numpy()[kind == "FP"]
    ignored = sum(1 for f, h in zip(fp_frames, fp_ids) if int(h) in dont_care[int(f)])
    paired = np.isin(kind, ("MATCH", "SWITCH"))
    return {"matches": int((kind == "MATCH").sum()), "switches": int((kind == "SWITCH").sum()),
            "misses": int((kind == "MISS").sum()), "fp": int((kind == "FP").sum()) - ignored,
            "ignored": ignored, "distance": float(ev["D"].to_numpy()[paired].sum())}


_MOT_METRICS = motmetrics.metrics.create()


def _identity_counts(per_frame: list, ignore: list[set[int]], threshold: float) -> dict[str, int]:
    """IDTP, IDFP, IDFN (motmetrics) with the ``ignore``d predictions of each frame left out."""
    kept = []
    for (oids, hids, dist), skip in zip(per_frame, ignore):
        cols = [k for k, h in enumerate(hids) if h not in skip]
        kept.append((oids, [hids[k] for k in cols], dist[:, cols] if dist.size else dist.reshape(len(oids), 0)))
    row = _MOT_METRICS.compute(_accumulate(kept, threshold), metrics=["idtp", "idfp", "idfn"], name="s").loc["s"]
    return {k: int(row[k]) for k in ("idtp", "idfp", "idfn")}


def _numbered(gt: Track, pred: Track):
    """Frames in order and, per frame, (object numbers, prediction numbers, distances [N, M]), with
    the id -> number maps: motmetrics wants numeric ids and frame numbers (it subtracts them)."""
    frames = sorted(set(gt.keys()) | set(pred.keys()), key=frame_sort_key)
    o_num: dict[Hashable, int] = {}
    h_num: dict[Hashable, int] = {}
    per_frame = []
    for frame in frames:
        oids, o_xyz = _positions(gt.get(frame, {}), f"ground truth of frame {frame!r}")
        hids, h_xyz = _positions(pred.get(frame, {}), f"predictions of frame {frame!r}")
        dist = _distances(oids, o_xyz, hids, h_xyz, frame)
        per_frame.append(([o_num.setdefault(o, len(o_num)) for o in oids],
                          [h_num.setdefault(h, len(h_num)) for h in hids], dist))
    return frames, per_frame, o_num, h_num


def _accumulate(per_frame: list, threshold: float) -> motmetrics.MOTAccumulator:
    """motmetrics' accumulator over the numbered frames (:func:`_numbered`), pairs beyond
    ``threshold`` metres not allowed."""
    acc = motmetrics.MOTAccumulator(auto_id=False)
    for k, (oids, hids, dist) in enumerate(per_frame):
        acc.update(oids, hids, np.where(dist <= threshold, dist, np.nan), frameid=k)
    return acc


def object_matches(gt: Track, pred: Track, threshold: float) -> dict[tuple[Hashable, Hashable], Optional[tuple[Hashable, float]]]:
    """Who each ground-truth object was matched to, frame by frame, under :func:`clear_mot`'s rules
    at one ``threshold``: ``{(frame, object id): (prediction id, distance [m]) or None (a miss)}``."""
    frames, per_frame, o_num, h_num = _numbered(gt, pred)
    objects = {v: k for k, v in o_num.items()}
    predictions = {v: k for k, v in h_num.items()}
    ev = _accumulate(per_frame, threshold).mot_events
    out: dict = {}
    for (k, _), kind, oid, hid, d in zip(ev.index, ev["Type"], ev["OId"], ev["HId"], ev["D"]):
        if kind in ("MATCH", "SWITCH"):
            out[(frames[int(k)], objects[int(oid)])] = (predictions[int(hid)], float(d))
        elif kind == "MISS":
            out[(frames[int(k)], objects[int(oid)])] = None
    return out


def clear_mot(
    gt: Track,
    pred: Track,
    thresholds: Sequence[float] = PAPER_THRESHOLDS,
    dont_care: Optional[Mapping[Hashable, Collection[Hashable]]] = None,
) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT metrics of one sequence at each distance threshold [m].

    ``gt`` and ``pred`` map each frame (any sortable key, e.g. a frame index or timestamp) to
    ``{object_id: xyz}``; a frame may be missing from either. Object and prediction ids are
    independent namespaces of any hashable keys. ``dont_care`` maps a frame to prediction ids that
    take part in the matching but, left unmatched there, are neither false positives nor counted
    predictions (predictions inside regions that do not count, as KITTI's "don't care" boxes).
    Returns ``{threshold: TrackingMetrics}``.
    """
    frames, per_frame, _, h_num = _numbered(gt, pred)
    ignore = [{h_num[h] for h in (dont_care or {}).get(frame, ()) if h in h_num} for frame in frames]
    n_obj = sum(len(o) for o, _, _ in per_frame)
    n_pred = sum(len(h) for _, h, _ in per_frame)
    out: dict[float, TrackingMetrics] = {}
    for t in thresholds:
        acc = _accumulate(per_frame, t)
        c = _counts(acc, ignore)
        frags = int(_MOT_METRICS.compute(acc, metrics=["num_fragmentations"], name="s").loc["s", "num_fragmentations"])
        ids = _identity_counts(per_frame, ignore, t)
        out[float(t)] = TrackingMetrics(
            threshold=float(t), num_frames=len(frames), num_objects=n_obj, num_predictions=n_pred - c["ignored"],
            num_matches=c["matches"], num_switches=c["switches"], num_false_positives=c["fp"],
            num_misses=c["misses"], total_distance=c["distance"], num_fragmentations=frags,
            id_true_positives=ids["idtp"], id_false_positives=ids["idfp"], id_false_negatives=ids["idfn"],
        )
    return out


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
            num_fragmentations=sum(r.num_fragmentations for r in rows),
            id_true_positives=sum(r.id_true_positives for r in rows),
            id_false_positives=sum(r.id_false_positives for r in rows),
            id_false_negatives=sum(r.id_false_negatives for r in rows),
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
        "| Dist. threshold [m] | Frames | Objects | Predictions | Matches | Switches | FP | FN | MOTA | MOTP | Recall | Precision "
        "| Frag. | IDF1 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t, r in sorted(results.items()):
        lines.append(
            f"| {t:g} | {r.num_frames} | {r.num_objects} | {r.num_predictions} | {r.num_matches} | {r.num_switches} "
            f"| {r.num_false_positives} | {r.num_misses} | {r.mota:.2f} | {r.motp:.2f} | {r.recall:.2f} | {r.precision:.2f} "
            f"| {r.num_fragmentations} | {r.idf1:.2f} |"
        )
    return "\n".join(lines)
