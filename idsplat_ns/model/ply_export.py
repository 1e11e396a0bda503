"""Gaussians as standard 3DGS ``.ply`` files (the layout of the original 3DGS code, read by common
splat viewers): ``x y z nx ny nz f_dc_0..2 f_rest_0..K opacity scale_0..2 rot_0..3``, all float32,
binary little-endian. Opacities are logits, scales are logs (metres), rotations are unit
quaternions ``w x y z``, normals are zero.

Colour: an IDSplat image is the Gaussians' composited *base colour* (``features_rgb``) corrected
by a small screen-space CNN that reads composited feature vectors and the camera's embedding
(:mod:`idsplat_ns.model.decoders`). That correction has no per-Gaussian form, so the export holds
the base colour alone, as a degree-0 spherical harmonic (``f_dc = (rgb - 0.5) / C0``), with
``f_rest`` zero (45 coefficients by default, the degree-3 layout most viewers expect). The
exported splats therefore look like the model's renders without the decoder's correction.

No nerfstudio import here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from idsplat_ns.atomic import atomic_path
from idsplat_ns.model.composition import compose_gaussians
from idsplat_ns.model.editing import SceneTensors

SH_C0 = 0.28209479177387814  # the degree-0 real spherical harmonic, 1 / (2 sqrt(pi))
DEFAULT_SH_REST = 45  # degree 3: 3 * (16 - 1) coefficients


def splat_records(gaussians: dict[str, Tensor], sh_rest: int = DEFAULT_SH_REST) -> np.ndarray:
    """A structured float32 array [N] in the 3DGS layout from raw Gaussian tensors (``means`` [N, 3],
    ``quats`` [N, 4] wxyz of any norm, ``scales`` [N, 3] log, ``opacities`` [N] logit,
    ``features_rgb`` [N, 3] logit of the base colour)."""
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(sh_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    means = gaussians["means"].detach().float().cpu()
    n = means.shape[0]
    quats = gaussians["quats"].detach().float().cpu()
    quats = quats / quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    rgb = torch.sigmoid(gaussians["features_rgb"].detach().float().cpu())
    columns = torch.cat([
        means, torch.zeros(n, 3), (rgb - 0.5) / SH_C0, torch.zeros(n, sh_rest),
        gaussians["opacities"].detach().float().cpu().reshape(n, 1), gaussians["scales"].detach().float().cpu(), quats,
    ], dim=1).numpy()  # [N, C]
    records = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        records[name] = columns[:, i]
    return records


def write_ply(path: Path, records: np.ndarray) -> Path:
    """Write a structured array as a binary little-endian PLY ``vertex`` element (atomically)."""
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(records)}"]
    header += [f"property float {name}" for name in records.dtype.names]
    header.append("end_header")
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(records.astype(records.dtype.newbyteorder("<"), copy=False).tobytes())
    return path


def select(gaussians: dict[str, Tensor], mask: Tensor) -> dict[str, Tensor]:
    """The Gaussians where ``mask`` [N] is true."""
    return {k: v[mask] for k, v in gaussians.items()}


def scene_at_time(scene: SceneTensors, time: float) -> dict[str, Tensor]:
    """Raw Gaussian tensors of the whole scene in the world at ``time`` (seconds): static ones as
    they are, each present instance's moved by its pose, absent instances left out (the rule of
    :meth:`SceneModel.posed_gaussians`)."""
    g = scene.gaussians
    traj = scene.as_trajectories()
    if traj is None:
        return dict(g)
    with torch.no_grad():
        R, t, present = traj.poses_at(time)
        means, quats, keep = compose_gaussians(g["means"], g["quats"], g["instance_ids"], R.float(), t.float(),
                                               present, traj.instance_ids)
    out = select(g, keep)
    out["means"], out["quats"] = means, quats
    return out
