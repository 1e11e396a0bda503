"""Pose accuracy of the CT smoother's variants on the synthetic street: every registered instance
that follows an annotated box is smoothed with each variant, and its poses at the training frames
are compared with the box (after the constant canonical-to-box offset that fits best: the
canonical frame is arbitrary; the box is the one holding most of the instance's points). Prints
the mean 3D, height, tilt, yaw and box-corner errors per variant (the corners of the annotated
box moved by the estimate: position and rotation weighed as a render of the vehicle weighs them).

    .venv/bin/python -m bench.bench_smoothed_poses --preset small --seeds 0 1 2 --work /tmp/trk

Registrations come from the same preprocessing as ``ns-train idsplat`` up to smoothing: the moving
instances after the parked ones are converted (cached in ``--work``, the same layout as
``bench_tracking.py``). Variants: ``default`` (``SmoothingConfig()``), ``paper``
(the paper's isotropic motion sigmas), ``tilt-only`` (the tilt sigma without the vertical one) and
``two-sided`` (without ``degenerate_one_sided``), ``no-heading-prior``, ``no-vertical-cap``, ``no-turning-curvature``. ``--variant NAME:FIELD=VALUE,...`` adds rows
(``SmoothingConfig`` fields; values are numbers, ``None``, ``True`` or ``False``), e.g.
``--variant loose-turns:curvature_sigma=1,curvature_walk_rate=0.05``.
"""

from __future__ import annotations


import numpy as np
from tqdm import tqdm

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.amodal_centre import AmodalCentreConfig
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.modes import ground_truth_masks
from idsplat_ns.instances.ground import GroundSurface
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.instances.smoothing.instance_tracks import ground_surface, registration_times, smooth_instance
from idsplat_ns.instances.smoothing import SmoothingConfig
from idsplat_ns.instances.tracks import InstanceTrack

from bench.box_errors import matching_box_poses, pose_errors
from bench.streets import street_arguments, training_streets

VARIANTS = {
    "default": SmoothingConfig(),
    "paper": SmoothingConfig(motion_vertical_sigma=None, motion_tilt_sigma=None),
    "tilt-only": SmoothingConfig(motion_vertical_sigma=None),
    "two-sided": SmoothingConfig(degenerate_one_sided=False),
    "no-heading-prior": SmoothingConfig(heading_prior_sigma=None),
    "no-vertical-cap": SmoothingConfig(degenerate_vertical_sigma=None),
    "no-turning-curvature": SmoothingConfig(turning_curvature_sigma=None),
    "no-ground": SmoothingConfig(ground_height_walk_rate=None),
}


def _parse_variant(text: str) -> tuple[str, SmoothingConfig]:
    """``NAME:FIELD=VALUE,...`` -> (name, config); a one-line error names the bad part."""
    name, _, body = text.partition(":")
    literals = {"None": None, "True": True, "False": False}
    fields = {}
    try:
        for item in filter(None, body.split(",")):
            key, eq, value = item.partition("=")
            if not eq:
                raise ValueError(f"expected FIELD=VALUE, got {item!r}")
            fields[key] = literals[value] if value in literals else int(value) if value.lstrip("-").isdigit() else float(value)
        return name, SmoothingConfig(**fields)
    except (TypeError, ValueError, IDSplatError) as exc:
        raise SystemExit(f"--variant {text!r}: {exc}") from None


def _smoothed_poses(inst: InstanceTrack, times: np.ndarray, config: SmoothingConfig,
                    ground: GroundSurface | None) -> dict:
    """Smoothed poses at the registered training frames (within the smoothed span)."""
    sm = smooth_instance(inst, registration_times(inst, times, config), config, ground)
    out = {}
    for k in np.flatnonzero(inst.valid):
        pose = sm.pose_at(float(times[k]), margin=0.1)
        if pose is not None:
            out[int(k)] = pose
    return out


def main() -> None:
    parser = street_arguments(__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", default=[], help="extra row NAME:FIELD=VALUE,... (repeatable)")
    parser.add_argument("--per-instance", action="store_true", help="also print each instance's mean 3D error per variant")
    args = parser.parse_args()
    variants = dict(VARIANTS, **dict(_parse_variant(v) for v in args.variant))
    results: dict[str, list] = {name: [] for name in variants}
    for seed, scene, train, cache in tqdm(training_streets(args, "idsplat_poses_"), total=len(args.seeds), desc="streets"):
        # The smoother's input: registered, parked ones converted, no smoothing, origins as registered.
        config = ground_truth_masks(scene, PreprocessConfig(masks=MaskConfig(kind="ground-truth"), smoothing=None, amodal=AmodalCentreConfig(enabled=False)))
        train_scene = scene.subset(train)
        registered = run_preprocessing(train_scene, config, cache, progress=False, verbose=False).tracks
        times = np.asarray(registered.frame_times, np.float64)
        built: dict = {}  # one lidar ground per ground setting of the variants
        grounds = {}  # variant name -> its ground (None: off)
        for name, config in variants.items():
            key = repr(config.ground) if config.ground_height_walk_rate is not None else None
            if key not in built:
                built[key] = ground_surface(train_scene, config)
            grounds[name] = built[key]
        for inst in registered.instances:
            if inst.num_valid < 3 or inst.point_frames is None:
                continue
            matched = matching_box_poses(inst, train_scene, registered)
            if matched is None:
                continue
            boxes, size = matched
            per_variant = {}
            for name, config in variants.items():
                poses = {k: P for k, P in _smoothed_poses(inst, times, config, grounds[name]).items() if boxes[k] is not None}
                per_variant[name] = pose_errors(poses, boxes, size) if len(poses) >= 3 else None
            if all(v is not None for v in per_variant.values()):  # the same instances in every row
                for name, v in per_variant.items():
                    results[name].append(v)
                if args.per_instance:
                    print(f"seed {seed} instance {inst.instance_id}: " + "  ".join(
                        f"{name} {v[0]:.3f} m {v[3]:.2f} deg {v[4]:.3f} mc" for name, v in per_variant.items()))
    print("\n| variant | instances | mean 3D error m | median 3D error m | mean height error m | mean tilt error deg | mean yaw error deg | mean corner error m |")
    print("|---|---|---|---|---|---|---|---|")
    for name, rows in results.items():
        a = np.array(rows)
        print(f"| {name} | {len(a)} | {a[:, 0].mean():.3f} | {np.median(a[:, 0]):.3f} | {a[:, 1].mean():.3f} | {a[:, 2].mean():.2f} | {a[:, 3].mean():.2f} | {a[:, 4].mean():.3f} |")


if __name__ == "__main__":
    main()
