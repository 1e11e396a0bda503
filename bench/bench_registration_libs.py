"""Library against hand-written: normals, point-to-plane ICP and correspondence RANSAC (open3d 0.20)
and the BERT tokenizer (``tokenizers``), for agreement and speed, side by side on the same inputs.

    .venv/bin/python bench/bench_registration_libs.py --trials 20

Rows (medians over repeats; times in milliseconds):

* normals: the project's :func:`estimate_normals` (open3d ``estimate_normals``, k = 12) against
  a numpy PCA of the k nearest neighbours (scipy KD-tree, the implementation it replaced).
* ICP: the project's :func:`icp_point_to_plane` (numpy least squares) against open3d's
  ``registration_icp`` with ``TransformationEstimationPointToPlane``, given the same pairs (each
  target point with its nearest source point: open3d is run target-onto-source with the source's
  normals, about the target's mean) and the same iteration cap.
* RANSAC: the project's :func:`register` reduced to the paper's RANSAC (no tilt limit, no
  back-face test, no ICP, no re-scoring or refit) against open3d's
  ``registration_ransac_based_on_correspondence``, on the same correspondences with a known
  transform; "ok" is a mean point error under 5 cm.
* tokenizer: the project's :class:`WordPieceTokenizer` (``tokenizers``) against transformers'
  pure-Python BERT tokenizer (``BertTokenizerLegacy``'s basic and WordPiece steps).
"""

from __future__ import annotations

import argparse
import string
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from idsplat_ns._compat.libusb import ensure_loadable
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.instances.masks.base import PROMPT_CLASSES
from idsplat_ns.instances.masks.bert_tokenizer import WordPieceTokenizer, caption_for
from idsplat_ns.instances.registration import RegistrationConfig, estimate_normals, icp_point_to_plane, register

ensure_loadable()
import open3d as o3d  # noqa: E402  (after the libusb guard)

REG = o3d.pipelines.registration


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def car(rng: np.random.Generator, n: int, noise: float = 0.01) -> np.ndarray:  # -> [n, 3]
    """Points on a 4.5 x 1.8 x 1.5 m box 20 m from the origin."""
    half = np.array([2.25, 0.9, 0.75])
    pts = rng.uniform(-1, 1, (n, 3)) * half
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = np.sign(pts[np.arange(n), face]) * half[face]
    return pts + [20.0, -5.0, 0.8] + rng.normal(scale=noise, size=pts.shape)


def numpy_normals(points: np.ndarray, k: int = 12) -> np.ndarray:  # [N, 3] -> [N, 3]
    """The former hand-written estimate: smallest principal axis of the k nearest neighbours."""
    _, idx = cKDTree(points).query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    return np.linalg.svd(np.einsum("nki,nkj->nij", nb, nb))[2][:, 2]


def open3d_icp(T: np.ndarray, source: np.ndarray, target: np.ndarray, iterations: int, max_distance: float) -> np.ndarray:
    """open3d's point-to-plane ICP with the project's pairing, as a drop-in for icp_point_to_plane."""
    if len(source) < 6 or len(target) < 6:
        return T
    c = target.mean(0)
    moved = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source @ T[:3, :3].T + T[:3, 3] - c))
    moved.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    seen = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target - c))
    res = REG.registration_icp(seen, moved, max_distance, np.eye(4), REG.TransformationEstimationPointToPlane(),
                               REG.ICPConvergenceCriteria(max_iteration=iterations))
    shift = make_pose(np.eye(3), c)
    return shift @ np.linalg.inv(np.asarray(res.transformation)) @ np.linalg.inv(shift) @ T


def open3d_ransac(cs: np.ndarray, ct: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    o3d.utility.random.seed(cfg.seed)
    pairs = o3d.utility.Vector2iVector(np.repeat(np.arange(len(cs), dtype=np.int32)[:, None], 2, 1))
    res = REG.registration_ransac_based_on_correspondence(
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cs)), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ct)),
        pairs, cfg.inlier_distance, REG.TransformationEstimationPointToPoint(False), 3, [],
        REG.RANSACConvergenceCriteria(cfg.max_iterations, cfg.confidence))
    return np.asarray(res.transformation)


def pose_gap(A: np.ndarray, B: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """Mean distance [m] between the points moved by A and by B, and their rotation difference [deg]."""
    d = np.linalg.norm(points @ (A[:3, :3] - B[:3, :3]).T + (A[:3, 3] - B[:3, 3]), axis=1).mean()
    return float(d), float(np.degrees(Rotation.from_matrix(A[:3, :3] @ B[:3, :3].T).magnitude()))


def bench_normals(rng: np.random.Generator, repeats: int) -> None:
    print("\n| normals | points | min abs(dot) | numpy ms | open3d ms |\n|---|---|---|---|---|")
    plane = lambda n: np.c_[rng.uniform(-2, 2, n), rng.normal(0, 0.005, n), rng.uniform(0, 1.5, n)]
    cases = {"car": car(rng, 1000), "car far (10 km)": car(rng, 1000, 0.002) + 1e4, "noisy plane": plane(500),
             "blob": rng.normal(size=(400, 3)), "8 points (k > N)": rng.normal(size=(8, 3)),
             "duplicates": np.repeat(rng.normal(size=(50, 3)), 4, 0), "car 100": car(rng, 100), "car 5000": car(rng, 5000)}
    for name, p in cases.items():
        dot = np.abs(np.sum(numpy_normals(p) * estimate_normals(p), 1))
        print(f"| {name} | {len(p)} | {dot.min():.6f} | {median_ms(lambda: numpy_normals(p), repeats):.2f} "
              f"| {median_ms(lambda: estimate_normals(p), repeats):.2f} |")


def icp_case(rng: np.random.Generator, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(start pose, source, target, true pose) of one ICP trial."""
    truth = make_pose(Rotation.from_rotvec([0, 0, rng.uniform(-1, 1)]).as_matrix(), rng.normal(size=3) * [2, 2, 0.05])
    if kind == "car":
        src, tgt = car(rng, 2000), car(rng, 800)
    elif kind == "partial corner":
        src, tgt = car(rng, 2000), car(rng, 1500)
        tgt = tgt[(tgt[:, 0] > 20.5) & (tgt[:, 1] > -5.3)]
    elif kind in ("noisy plane", "exact plane"):
        noise = 0.01 if kind == "noisy plane" else 0.0
        wall = lambda n: np.c_[rng.uniform(-2, 2, n), rng.normal(0, noise, n) if noise else np.zeros(n), rng.uniform(0, 1.5, n)] + [20, -5, 0]
        src, tgt = wall(600), wall(300)
    else:  # "12 target points": a far car's few returns
        src = car(rng, 40, 0.0)
        tgt = src[:12] + rng.normal(scale=0.01, size=(12, 3))
    tgt = tgt @ truth[:3, :3].T + truth[:3, 3]
    # Start 1-3 degrees and 10 cm off, about the object (as a RANSAC estimate is).
    centre = src.mean(0)
    wobble = make_pose(Rotation.from_rotvec(rng.normal(size=3) * np.radians([1, 1, 3])).as_matrix(), np.zeros(3))
    about = make_pose(np.eye(3), centre) @ wobble @ make_pose(np.eye(3), -centre)
    start = truth @ about @ make_pose(np.eye(3), rng.normal(size=3) * 0.1)
    return start, src, tgt, truth


def bench_icp(rng: np.random.Generator, trials: int, repeats: int) -> None:
    print("\n| ICP case | trials | median gap cm / deg | max gap cm | median error numpy cm | median error open3d cm "
          "| max error numpy cm | max error open3d cm | numpy ms | open3d ms |\n|---|---|---|---|---|---|---|---|---|---|")
    for kind in ("car", "partial corner", "noisy plane", "exact plane", "12 target points"):
        gaps, errs, t_np, t_o3d = [], [], [], []
        for _ in range(trials):
            start, src, tgt, truth = icp_case(rng, kind)
            a = icp_point_to_plane(start, src, tgt, 10, 0.3)
            b = open3d_icp(start, src, tgt, 10, 0.3)
            gaps.append(pose_gap(a, b, src))
            errs.append((pose_gap(a, truth, src)[0], pose_gap(b, truth, src)[0]))
        t_np = median_ms(lambda: icp_point_to_plane(start, src, tgt, 10, 0.3), repeats)
        t_o3d = median_ms(lambda: open3d_icp(start, src, tgt, 10, 0.3), repeats)
        g, e = 100 * np.array(gaps)[:, 0], 100 * np.array(errs)
        print(f"| {kind} ({len(src)} -> {len(tgt)}) | {trials} | {np.median(g):.2f} / {np.median(np.array(gaps)[:, 1]):.3f} "
              f"| {g.max():.1f} | {np.median(e[:, 0]):.2f} | {np.median(e[:, 1]):.2f} | {e[:, 0].max():.1f} | {e[:, 1].max():.1f} "
              f"| {t_np:.1f} | {t_o3d:.1f} |")


def bench_ransac(rng: np.random.Generator, trials: int) -> None:
    cfg = RegistrationConfig(max_tilt=None, back_face_tolerance=None, icp_iterations=0, rescore_top_k=1, refine_iterations=0)
    print("\n| RANSAC correspondences | outliers | trials | mean inliers numpy / open3d / true | ok numpy / open3d "
          "| median error numpy / open3d cm | median numpy ms | median open3d ms |\n|---|---|---|---|---|---|---|---|")
    for count in (20, 200, 2000):
        for outliers in (0.3, 0.6, 0.85):
            rows = []
            for trial in range(trials):
                truth = make_pose(Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)]).as_matrix(), rng.normal(size=3) * [3, 3, 0.05])
                cs = car(rng, count, 0.0)
                ct = cs @ truth[:3, :3].T + truth[:3, 3] + rng.normal(scale=0.01, size=cs.shape)
                bad = rng.random(count) < outliers
                ct[bad] = ct[rng.permutation(np.flatnonzero(bad))] + rng.normal(scale=0.5, size=(bad.sum(), 3))
                feat = rng.normal(size=(count, 32))  # identical rows: every pair above the similarity threshold
                c = replace(cfg, seed=trial)
                t0 = time.perf_counter()
                a = register(cs, feat, ct, feat, c).transform
                t1 = time.perf_counter()
                b = open3d_ransac(cs, ct, c)
                t2 = time.perf_counter()
                inl = [int(np.sum(np.linalg.norm(cs @ T[:3, :3].T + T[:3, 3] - ct, axis=1) < c.inlier_distance)) for T in (a, b, truth)]
                rows.append(inl + [pose_gap(a, truth, cs)[0], pose_gap(b, truth, cs)[0], t1 - t0, t2 - t1])
            r = np.array(rows, float)
            print(f"| {count} | {outliers:.2f} | {trials} | {r[:, 0].mean():.1f} / {r[:, 1].mean():.1f} / {r[:, 2].mean():.1f} "
                  f"| {np.mean(r[:, 3] < 0.05):.2f} / {np.mean(r[:, 4] < 0.05):.2f} | {100 * np.median(r[:, 3]):.2f} / {100 * np.median(r[:, 4]):.2f} "
                  f"| {1e3 * np.median(r[:, 5]):.1f} | {1e3 * np.median(r[:, 6]):.1f} |")


def bench_tokenizer(rng: np.random.Generator, trials: int, repeats: int) -> None:
    from transformers.models.bert.tokenization_bert_legacy import BasicTokenizer, WordpieceTokenizer, load_vocab

    words = ["car", "truck", "van", "bus", "train", "human", "cycl", "##ist", "bicycle", "pedestrian", "##s", "park", "##ed", "ß", "中"]
    vocab = (["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]"] + list(string.punctuation) + list(string.ascii_lowercase + string.digits)
             + ["##" + c for c in string.ascii_lowercase + string.digits] + words)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "vocab.txt"
        path.write_text("\n".join(vocab) + "\n", encoding="utf-8")
        ours = WordPieceTokenizer(path)
        basic, wordpiece = BasicTokenizer(do_lower_case=True), WordpieceTokenizer(load_vocab(str(path)), "[UNK]")
    reference = lambda text: [p for w in basic.tokenize(text) for p in wordpiece.tokenize(w)]
    alphabet = list(string.ascii_letters + string.digits + string.punctuation + " \t") + list("éüßÅçñ中国🚗\u0301\u00a0\u3000\x1c")
    texts = ["".join(rng.choice(alphabet, rng.integers(1, 80))) for _ in range(100 * trials)]
    same = sum(ours.tokenize(t) == reference(t) for t in texts)
    caption = caption_for(PROMPT_CLASSES)
    long = " . ".join([caption] * 20)
    print("\n| tokenizer | texts | same tokens as transformers' pure-Python BERT | tokenizers us (caption / 20 captions) "
          "| pure Python us |\n|---|---|---|---|---|")
    print(f"| random text | {len(texts)} | {same} | {1e3 * median_ms(lambda: ours.tokenize(caption), repeats):.0f} / "
          f"{1e3 * median_ms(lambda: ours.tokenize(long), repeats):.0f} | {1e3 * median_ms(lambda: reference(caption), repeats):.0f} / "
          f"{1e3 * median_ms(lambda: reference(long), repeats):.0f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20, help="random problems per row")
    ap.add_argument("--repeats", type=int, default=9, help="timed repeats per row")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", choices=("normals", "icp", "ransac", "tokenizer"), action="append", help="run only these parts")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    parts = args.only or ["normals", "icp", "ransac", "tokenizer"]
    if "normals" in parts:
        bench_normals(rng, args.repeats)
    if "icp" in parts:
        bench_icp(rng, args.trials, args.repeats)
    if "ransac" in parts:
        bench_ransac(rng, args.trials)
    if "tokenizer" in parts:
        bench_tokenizer(rng, args.trials, args.repeats)


if __name__ == "__main__":
    main()
