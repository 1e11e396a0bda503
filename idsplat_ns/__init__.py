"""idsplat_ns: IDSplat (instance-decomposed 3D Gaussian splatting for driving scenes) for nerfstudio.

Everything outside :mod:`idsplat_ns.nerfstudio` imports without nerfstudio, so the engine (data,
instances, rendering, model maths, evaluation) runs wherever torch runs.
"""

__version__ = "0.1.0"
