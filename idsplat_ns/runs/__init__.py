"""Run folders: a trained run's checkpoints and what commands may rely on in them.

Sits with the nerfstudio adapter and the command lines (layer 6): it may import ``errors``,
``atomic`` and torch, never ``method_configs``.
"""
