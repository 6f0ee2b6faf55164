"""Scanned film photographs (issue 16; docs/decisions.md "Scanned film"): interior orientation from fiducial marks
(`transform`: the 2D transformations; `fiducials`: their fit per photo and the image points carried
to the plate), the camera calibration report (`calibration`: the radial distortion table fitted to
the camera model), what they gave (`data`), their report section (`report`) and a
synthetic film strip (`simulate`). The input files are read by striptri.io.film_reader."""
