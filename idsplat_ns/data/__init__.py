"""Dataset parsers and the scene representation shared by all of them."""
