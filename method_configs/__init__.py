"""Registered nerfstudio methods and dataparsers of idsplat_ns (see idsplat.py).

The top layer: it may import any of ``idsplat_ns``, and nothing in ``idsplat_ns`` imports it.
"""
