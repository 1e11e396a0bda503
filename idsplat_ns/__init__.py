"""idsplat_ns: IDSplat (instance-decomposed 3D Gaussian splatting for driving scenes) for nerfstudio.

The packages are one-way layers, lowest first (``[tool.importlinter]`` in pyproject.toml checks
them): ``errors``, ``ranges``, ``atomic``, ``_compat`` < ``data``, ``render`` < ``instances`` < ``model`` <
``eval`` < ``runs`` < ``nerfstudio`` (the adapter) < ``cli``, ``batch`` < ``method_configs``.
Everything below ``runs`` imports without nerfstudio, so the engine (data, instances, rendering,
model maths, evaluation) runs wherever torch runs.
"""

__version__ = "0.1.0"
