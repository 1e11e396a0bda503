"""Registered nerfstudio methods and dataparsers of idsplat_ns (see idsplat.py)."""
