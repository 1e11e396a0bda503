"""Dataset readers (PandaSet, Waymo v1/v2, the built-in synthetic street) and the scene
representation they share.

Layer: beside ``render``, above ``errors``, ``atomic`` and ``_compat``, which are all it may import
of the project.
"""
