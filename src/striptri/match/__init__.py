"""Automatic tie points (issue 28): from the images of a block to image_points.csv.

The stages that need no image library are here first: candidate pairs from the approximate
orientations or the strip layout (:mod:`.pairs`), tracks from verified matches (:mod:`.tracks`) and
thinning to a well-spread set (:mod:`.thinning`). docs/matching.md describes the pipeline and what
is still to come (features, geometric verification, fiducials, the command).
"""
