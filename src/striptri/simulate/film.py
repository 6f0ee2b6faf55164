"""A synthetic strip of scanned film photographs (issue 16; data/film_strip, scripts/make_film_strip.py).

Truth apart from noise (STYLE.md): :func:`film_truth` makes the true strip (striptri.simulate),
the camera's true lens (a calibration report: c, PBS, PPA, a radial distortion polynomial), the
fiducial marks and one scan transformation per photo; :func:`film_project_files` measures it with
an explicit random generator: fiducials and image points in scan pixels with Gaussian noise, the
distortion table printed as USGS prints it (micrometres, rounded to 1 um, at field angles 7.5 ...
40 deg).

The lens: the camera model's plate convention (striptri.geometry.lens) with the report's K0 folded into c;
measured plate points are found from the ideal ones by fixed-point iteration of the correction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from striptri import model
from striptri.film import calibration as calib
from striptri.film import transform
from striptri.io.csvtable import format_csv
from striptri.io.project_writer import project_files
from striptri.geometry.lens import NCP, brown
from striptri.simulate.design import CameraDesign, ControlDesign, FlightDesign, SyntheticDesign
from striptri.simulate.noise import NoiseOptions, perturb
from striptri.simulate.pipeline import truth_tables
from striptri.simulate.truth import make_truth

# an RC-type 23 cm camera: four corner and four mid-side fiducials (plate mm, invented values)
FIDUCIALS_MM = np.array([[-106.003, -105.998], [105.997, -106.004], [106.002, 106.001], [-105.999, 106.002],
                         [0.001, -112.998], [112.999, 0.002], [-0.002, 113.003], [-113.001, -0.001]])
FIDUCIAL_IDS = ("1", "2", "3", "4", "5", "6", "7", "8")
FIELD_ANGLES_DEG = np.array([7.5, 15.0, 22.7, 30.0, 35.0, 40.0])  # as USGS reports print them


@dataclass(frozen=True)
class FilmLens:
    """The true calibration (synthetic): focal_length_mm (the report's CFL), pbs_mm, ppa_mm (2,),
    k0, k (3,) (SMAC-style correction coefficients, mm units), p1, p2."""

    focal_length_mm: float = 152.847
    pbs_mm: tuple = (0.006, -0.004)
    ppa_mm: tuple = (0.011, 0.003)
    k0: float = 5.1e-5
    k: tuple = (-1.05e-8, 2.3e-13, 0.0)
    p1: float = 0.0
    p2: float = 0.0

    def elements(self) -> np.ndarray:
        """The camera model's elements (fold of k0 into c, striptri.film.calibration)."""
        fit = calib.RadialFit(np.zeros(0), np.zeros(0), np.array(self.k), np.zeros(0), np.zeros(0), 0.0, 3, self.k0)
        return calib.camera_elements(self.focal_length_mm, self.pbs_mm, fit, self.p1, self.p2)

    def printed_table_um(self) -> np.ndarray:
        """The distortion at FIELD_ANGLES_DEG as a report prints it: -(K0 r + K1 r^3 + ...), 1 um."""
        r = self.focal_length_mm * np.tan(np.radians(FIELD_ANGLES_DEG))
        return np.round(calib.model_distortion_mm(r, np.array(self.k), self.k0) * calib.UM_PER_MM)


@dataclass(frozen=True)
class FilmOptions:
    """n_photos; pixel_mm: scan pixel size (mm); sigma_point_px, sigma_fiducial_px: measurement noise
    (px); transformation: the kind written into project.toml; n_check: check points along the strip.
    [film] sigma_px is sigma_point_px; a different sigma_fiducial_px is written in a sigma column of
    fiducial_measurements.csv (1e-4 px for noise-free fiducials)."""

    n_photos: int = 30
    pixel_mm: float = 0.020
    sigma_point_px: float = 0.5
    sigma_fiducial_px: float = 0.5
    transformation: str = "affine"
    n_check: int = 6
    scan_centre_px: tuple = (6000.0, 6000.0)
    scan_offset_px: float = 30.0
    max_rotation_deg: float = 1.0


def distort(xy_ideal: np.ndarray, elements: np.ndarray, iterations: int = 50) -> np.ndarray:
    """Measured plate points whose plate-convention correction gives xy_ideal (m, 2) (fixed point)."""
    pp = elements[1:3]
    u = xy_ideal - pp
    m = u.copy()
    for _ in range(iterations):
        value, _, _ = brown(m, np.broadcast_to(elements, m.shape[:-1] + (NCP,)))
        m = m + (u - value)
    return m + pp


def scan_params(n: int, pixel_mm: float, rng: np.random.Generator, centre_px: tuple = (6000.0, 6000.0),
                max_rotation_deg: float = 1.0, offset_px: float = 30.0) -> np.ndarray:
    """One affine scan transformation per photo (q = F(xy), striptri.film.transform): 1/pixel_mm px per
    mm, rotation up to max_rotation_deg, film shrinkage up to 2e-4 per axis, the plate origin within
    offset_px of centre_px (col, row)."""
    s = 1.0 / pixel_mm
    angle = np.radians(rng.uniform(-1, 1, n) * max_rotation_deg)
    sx, sy = s * (1 - rng.uniform(0, 2e-4, n)), s * (1 - rng.uniform(0, 2e-4, n))
    t = np.column_stack([centre_px[0] + rng.uniform(-offset_px, offset_px, n),
                         -centre_px[1] + rng.uniform(-offset_px, offset_px, n)])
    return np.column_stack([t[:, 0], sx * np.cos(angle), -sy * np.sin(angle),
                            t[:, 1], sx * np.sin(angle), sy * np.cos(angle)])


def film_truth(options: FilmOptions, lens: FilmLens, seed: int):
    """(exact project in plate mm with the true ideal plates, truth tables, scan parameters (P, 6),
    the noise stream, the Truth)."""
    streams = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(streams[0])
    el = lens.elements()
    design = SyntheticDesign(camera=CameraDesign(c=float(el[0]), xp=float(el[1]), yp=float(el[2])),
                             flight=FlightDesign(n_photos=options.n_photos, overlap=0.6),
                             control=ControlDesign(layout="ends", n_check=options.n_check))
    truth = make_truth(design, rng)
    # 4 control points at the start of the strip: the full points of the last columns become tie points
    full = np.flatnonzero(truth.kind == model.FULL)
    far = full[np.argsort(truth.xyz_ground[full, 0])][4:]
    kind = truth.kind.copy()
    kind[far] = model.TIE
    truth = replace(truth, kind=kind)
    project = perturb(truth, NoiseOptions(sigma_image=0.0, stated_sigma_image=0.005), rng)
    params = scan_params(options.n_photos, options.pixel_mm, rng, options.scan_centre_px, options.max_rotation_deg,
                         options.scan_offset_px)
    return project, truth_tables(truth), params, streams[1], truth


def film_project_files(options: FilmOptions = FilmOptions(), lens: FilmLens = FilmLens(), seed: int = 16,
                       noise_seed: int | None = None):
    """The files of a film project (name -> text) and its truth tables (name -> columns).

    seed: the truth and, unless noise_seed is given, the noise; noise_seed: another noise
    realisation of the same truth (Monte Carlo).

    Scans: image points and fiducials through the lens (distort) and each photo's scan
    transformation, plus Gaussian noise (sigma_point_px, sigma_fiducial_px) from the noise stream.
    """
    files, truth, _, _ = film_files_and_truth(options, lens, seed, noise_seed)
    return files, truth


def film_files_and_truth(options: FilmOptions = FilmOptions(), lens: FilmLens = FilmLens(), seed: int = 16,
                         noise_seed: int | None = None, rendered: bool = False):
    """film_project_files' (files, truth tables), and the Truth and scan parameters (P, 6).
    rendered: the project of rendered scans (simulate.film_render): image_points.csv keeps only the
    control and check points (the tie points are left to striptri match), fiducial_measurements.csv
    is left out (the marks are to be found in the scans) and the truth gets fiducial_marks.csv, the
    marks' true scan positions (photo_id, fiducial_id, col, row)."""
    project, truth, params, noise_stream, true = film_truth(options, lens, seed)
    rng = np.random.default_rng(noise_stream if noise_seed is None else noise_seed)
    el = lens.elements()
    ip = project.image_points
    xy_measured = distort(ip.xy, el)
    q, _, _ = transform.scan_from_plate("affine", params[ip.photo_index], xy_measured[:, None])
    colrow = transform.colrow_from_q(q[:, 0]) + rng.normal(0.0, options.sigma_point_px, (len(ip.xy), 2))
    n = len(project.photos.ids)
    qf, _, _ = transform.scan_from_plate("affine", params, np.broadcast_to(FIDUCIALS_MM, (n,) + FIDUCIALS_MM.shape))
    fid_colrow = transform.colrow_from_q(qf) + rng.normal(0.0, options.sigma_fiducial_px, qf.shape)
    files = project_files(replace(project, image_points=replace(ip, xy=colrow)))
    point_ids = project.points.ids
    files["image_points.csv"] = format_csv({
        "photo_id": [project.photos.ids[p] for p in ip.photo_index],
        "point_id": [point_ids[p] for p in ip.point_index],
        "x": np.round(colrow[:, 0], 4), "y": np.round(colrow[:, 1], 4)})
    files["cameras.csv"] = format_csv({"camera_id": ["RC"], "c": [lens.focal_length_mm], "xp": [0.0], "yp": [0.0]})
    files["photos.csv"] = files["photos.csv"].replace(",C1,", ",RC,")
    files["fiducials.csv"] = format_csv({"camera_id": ["RC"] * len(FIDUCIAL_IDS), "fiducial_id": list(FIDUCIAL_IDS),
                                         "x": FIDUCIALS_MM[:, 0], "y": FIDUCIALS_MM[:, 1]})
    files["fiducial_measurements.csv"] = format_csv({
        "photo_id": [pid for pid in project.photos.ids for _ in FIDUCIAL_IDS],
        "fiducial_id": list(FIDUCIAL_IDS) * n,
        "col": np.round(fid_colrow[..., 0].ravel(), 4), "row": np.round(fid_colrow[..., 1].ravel(), 4),
        **({} if options.sigma_fiducial_px == options.sigma_point_px else
           {"sigma": np.full(n * len(FIDUCIAL_IDS), max(options.sigma_fiducial_px, 1e-4))})})
    files["calibration.toml"] = calibration_toml(lens)
    files["project.toml"] = files["project.toml"].replace("sigma_image = 0.005\n", "sigma_image = 0.005\n") + (
        f"\n[film]\nimage_points = \"scan_px\"\ntransformation = \"{options.transformation}\"\n"
        f"sigma_px = {options.sigma_point_px:g}\n")
    truth = dict(truth)
    truth["scans.csv"] = {"photo_id": list(project.photos.ids),
                          **{f"a{j}": params[:, j] for j in range(3)}, **{f"b{j}": params[:, 3 + j] for j in range(3)}}
    if rendered:
        keep = project.points.kind[ip.point_index] != model.TIE
        files["image_points.csv"] = format_csv({
            "photo_id": [project.photos.ids[p] for p in ip.photo_index[keep]],
            "point_id": [point_ids[p] for p in ip.point_index[keep]],
            "x": np.round(colrow[keep, 0], 4), "y": np.round(colrow[keep, 1], 4)})
        del files["fiducial_measurements.csv"]
        exact = transform.colrow_from_q(qf)
        truth["fiducial_marks.csv"] = {"photo_id": [pid for pid in project.photos.ids for _ in FIDUCIAL_IDS],
                                       "fiducial_id": list(FIDUCIAL_IDS) * n,
                                       "col": exact[..., 0].ravel(), "row": exact[..., 1].ravel()}
    return files, truth, true, params


def calibration_toml(lens: FilmLens) -> str:
    """calibration.toml of the lens, the table as a USGS report prints it (docs/file-formats.md)."""
    def vec(v):
        return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"
    return ("# synthetic calibration report (striptri.simulate.film), in the format of USGS reports\n"
            "[camera.RC]\n"
            f"focal_length_mm = {lens.focal_length_mm}\n"
            f"pbs_mm = {vec(lens.pbs_mm)}\n"
            f"ppa_mm = {vec(lens.ppa_mm)}\n"
            f"field_angle_deg = {vec(FIELD_ANGLES_DEG)}\n"
            f"radial_distortion_um = {vec(lens.printed_table_um())}\n")
