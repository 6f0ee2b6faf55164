"""COLMAP's camera models that striptri reads, shared by the text and binary readers
(formats.colmap, formats.colmap_binary)."""

MODELS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8}
# where each model keeps fx, fy, cx, cy and the distortion k1, k2, p1, p2 in its parameter list
# (None: not in the model, 0; fy None: fy = fx)
LAYOUT = {
    "SIMPLE_PINHOLE": (0, None, 1, 2, (None, None, None, None)),
    "PINHOLE": (0, 1, 2, 3, (None, None, None, None)),
    "SIMPLE_RADIAL": (0, None, 1, 2, (3, None, None, None)),
    "RADIAL": (0, None, 1, 2, (3, 4, None, None)),
    "OPENCV": (0, 1, 2, 3, (4, 5, 6, 7)),
}
