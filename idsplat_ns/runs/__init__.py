"""Run folders: a trained run's config and checkpoints, what commands may rely on in them, the
settings checks made before a run is written, the random state a resumed run restores, and the
edits of a trained scene.

Layer: above ``eval``, below the nerfstudio adapter and the command lines. It may import
``errors``, ``atomic``, ``data``, ``render``, ``model``, ``eval`` and nerfstudio's own
``TrainerConfig``; never ``idsplat_ns.nerfstudio``, ``cli``, ``batch`` or ``method_configs``.
"""
