"""Model maths that does not need nerfstudio: Gaussians, decoders, losses."""
