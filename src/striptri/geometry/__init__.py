"""The geometry of one photograph: rotations and their angle conventions, the camera and its lens,
the collinearity projection and the balanced (Schmid) forms. The ground floor: imports nothing of
striptri but errors and the model."""
