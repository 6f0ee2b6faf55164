"""Rendered film scans (issue 28; simulate.film_render) and the fiducial marks found in them
automatically (match.fiducials.find_marks_turned): scans turned by up to 2 degrees and shifted on
the scanner, with noise, the marks found within 0.2 px of the truth (measured: 0.023 px)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cv2")

from striptri.match.fiducials import find_marks, find_marks_turned, synthetic_mark  # noqa: E402
from striptri.simulate import film  # noqa: E402
from striptri.simulate.design import CameraDesign, ControlDesign, FlightDesign, SyntheticDesign  # noqa: E402
from striptri.simulate.film_render import IMAGE_HALF_MM, Cross, Scan, fiducial_truth, render_scan  # noqa: E402
from striptri.simulate.render import texture_for  # noqa: E402
from striptri.simulate.truth import make_truth  # noqa: E402

# its module-scoped fixtures are made once, on one worker (pytest-xdist --dist loadgroup)
pytestmark = pytest.mark.xdist_group("film_render")

PIXEL_MM = 0.25  # a coarse scan (4 px/mm) keeps the test quick; the finder works in pixels
SIZE = (1000, 1000)


@pytest.fixture(scope="module")
def strip():
    lens = film.FilmLens()
    el = lens.elements()
    design = SyntheticDesign(camera=CameraDesign(c=float(el[0]), xp=float(el[1]), yp=float(el[2])),
                             flight=FlightDesign(n_photos=4, overlap=0.6), control=ControlDesign(layout="ends"))
    truth = make_truth(design, np.random.default_rng(3))
    params = film.scan_params(4, PIXEL_MM, np.random.default_rng(1), centre_px=(500.0, 500.0), max_rotation_deg=2.0)
    texture = texture_for(truth.terrain, PIXEL_MM * design.scale, 230.0 * design.scale, 5)
    rng = np.random.default_rng(0)
    scans, images = [], []
    for k in range(4):
        scan = Scan(params[k], SIZE, el, film.FIDUCIALS_MM)
        grey = render_scan(truth.R_ground_from_cam[k], truth.xyz0[k], scan, truth.terrain, texture)
        images.append(np.clip(np.rint(grey + rng.normal(0.0, 3.0, grey.shape)), 0, 255))
        scans.append(scan)
    return truth, scans, images


def _fiducials():
    return {str(k + 1): tuple(xy) for k, xy in enumerate(film.FIDUCIALS_MM)}


def test_fiducial_marks_of_turned_scans_are_found_within_a_fifth_of_a_pixel(strip):
    _, scans, images = strip
    turns = np.degrees([np.arctan2(s.params[4], s.params[1]) for s in scans])
    assert np.abs(turns).max() > 1.5  # the strip holds scans turned by more than 1.5 degrees
    template = synthetic_mark("cross", int(2 * Cross().arm_mm / PIXEL_MM) + 1, line_px=Cross().line_mm / PIXEL_MM)
    errors = []
    for scan, image in zip(scans, images):
        found = find_marks_turned(image, _fiducials(), template, 1.0 / PIXEL_MM)
        assert all(m.found for m in found), [m.reason for m in found]
        errors.append([(m.col, m.row) for m in found] - fiducial_truth(scan))
        # one narrow pass about the scan's centre misses the corners of a turned scan
        if abs(np.degrees(np.arctan2(scan.params[4], scan.params[1]))) > 1.5:
            narrow = find_marks(image, _fiducials(), template, 1.0 / PIXEL_MM, search_mm=1.5)
            assert not all(m.found and abs(m.col - t[0]) < 0.2 for m, t in zip(narrow, fiducial_truth(scan)))
    assert np.abs(errors).max() < 0.2


def test_a_scan_shows_the_terrain_inside_its_frame_and_film_base_outside(strip):
    truth, scans, images = strip
    scan, image = scans[0], images[0]
    from striptri.film import transform

    # the plate centre and a point beyond the frame, through the scan transformation
    q, _, _ = transform.scan_from_plate("affine", scan.params[None], np.array([[[0.0, 0.0], [50.0, IMAGE_HALF_MM + 4]]]))
    (c0, r0), (c1, r1) = transform.colrow_from_q(q[0]).astype(int)
    assert image[r1 - 2:r1 + 3, c1 - 2:c1 + 3].mean() < 40  # unexposed base (20) and noise
    assert image[r0 - 20:r0 + 20, c0 - 20:c0 + 20].std() > 15  # the terrain's texture
