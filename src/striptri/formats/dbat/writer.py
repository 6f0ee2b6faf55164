"""The DBAT writer: a striptri project -> the files of a DBAT script project (:func:`dbat_files`:
``project.xml`` and the text files it names), the inverse of :mod:`.reader` and
:mod:`.to_project`. Returns the file texts; writing them is the convert pipeline's job.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from xml.sax.saxutils import escape as xml_escape

import numpy as np

from striptri.geometry import lens
from striptri import model
from striptri.errors import InputError
from striptri.formats.conversions import pixel_size_note
from striptri.formats.dbat.to_project import ELEMENT_OF
from striptri.formats.scene import photo_datum
from striptri.geometry.lens import CAMERA_ELEMENTS, IMAGE, has_distortion
from striptri.geometry.rotations import opk_from_R

_DBAT_OF = {v: k for k, v in ELEMENT_OF.items()}  # striptri element -> DBAT name
_IO_TAG = {"cc": "cc", "px": "px", "py": "py", "as": "aspect", "sk": "skew", "K1": "K1", "K2": "K2", "K3": "K3",
           "P1": "P1", "P2": "P2"}
SCRIPT_FILE = "project.xml"


def _r(v) -> str:
    return repr(float(v))


def _csv(rows) -> str:
    return "".join(",".join(r) + "\n" for r in rows)


def dbat_files(project: model.Project, pixel_size: float = 1.0) -> tuple[dict[str, str], list[str]]:
    """A DBAT script project of ``project``: ``project.xml`` (the script, camera inline) and the
    text files it names (images, image points in pixels, control, prior EO). -> (files, notes).

    pixel_size: plate units per pixel (the pixel is square on the plate; the camera's b1 becomes
    DBAT's aspect). The image size is the smallest even W x H whose centre holds every measurement
    with one pixel of margin; the principal point is written from the top-left corner. Photo ids
    are the image paths; DBAT's ids are 1, 2, ... for images and the project's point ids for points.
    One camera, plate convention (DBAT's backward model 3); image-convention distortion is refused.
    Full control is written fixed or weighted; other kinds of control and observed exterior
    elements have no DBAT script form and are left out (notes). DBAT's datum "depend" is written
    when the held elements are the ones photo_datum holds."""
    cams, photos, ip, pts = project.cameras, project.photos, project.image_points, project.points
    where = Path(project.source or ".") / "cameras.csv"
    if len(cams) != 1:
        raise InputError(where, None, f"{len(cams)} cameras; the DBAT writer handles one camera")
    prm = cams.interior[0]
    if cams.convention[0] == IMAGE and has_distortion(prm[None, :]):
        raise InputError(where, None, f"camera {cams.ids[0]} has distortion in the image convention (applied to the "
                                      "projected point); DBAT corrects the measured coordinates (plate convention)")
    if any("," in pid or "#" in pid for pid in list(photos.ids) + list(pts.ids)):
        raise InputError(where, None, "an id contains ',' or '#', which DBAT's text files cannot hold")
    s = float(pixel_size)
    notes = []
    extent = np.maximum(np.abs(ip.xy).max(axis=0) if len(ip) else np.zeros(2), np.abs(prm[1:3]))
    W, H = (2 * (np.ceil(extent / s).astype(int) + 1)).tolist()
    px0, py0 = W * s / 2.0, H * s / 2.0
    aspect = 1.0 / (1.0 + prm[lens.B1])
    est = {name: bool(math.isinf(cams.sigma_interior[0, CAMERA_ELEMENTS.index(el)]) or
                      (cams.sigma_interior[0, CAMERA_ELEMENTS.index(el)] > 0))
           for el, name in _DBAT_OF.items()}
    if np.any(np.isfinite(cams.sigma_interior[0]) & (cams.sigma_interior[0] > 0)):
        notes.append("observed camera elements are written as estimated (a DBAT script has no prior for them)")
    camera = (
        "<camera><id>1</id>"
        f"<name>{xml_escape(cams.ids[0])}</name><unit>{project.settings.plate_unit}</unit>"
        f"<sensor>{_r(W * s / aspect)},{_r(H * s)}</sensor><image>{W},{H}</image><aspect>{_r(aspect)}</aspect>"
        f"<cc>{_r(prm[lens.C])}</cc><focal>{_r(prm[lens.C])}</focal>"
        f"<pp>{_r(px0 + prm[lens.XP])},{_r(py0 - prm[lens.YP])}</pp>"
        f"<model>3</model><nK>3</nK><nP>2</nP>"
        f"<K>{_r(prm[lens.K1])},{_r(prm[lens.K2])},{_r(prm[lens.K3])}</K><P>{_r(prm[lens.P1])},{_r(prm[lens.P2])}</P>"
        f"<skew>{_r(prm[lens.B2])}</skew></camera>"
    )
    image_rows = [[str(i + 1), pid] for i, pid in enumerate(photos.ids)]
    col = (ip.xy[:, 0] + px0) / s
    row = (py0 - ip.xy[:, 1]) / s
    sig = ip.sigma_xy / s
    mark_rows = [[str(int(p) + 1), pts.ids[q], repr(float(c)), repr(float(r)), repr(float(a)), repr(float(b))]
                 for p, q, c, r, (a, b) in zip(ip.photo_index, ip.point_index, col, row, sig)]
    full = (pts.kind == model.FULL) & np.isfinite(pts.xyz_given).all(axis=1)
    weighted = full & np.isfinite(pts.sigma_given).all(axis=1)
    fixed = full & ~weighted
    if np.any((pts.kind != model.FULL) & (pts.kind != model.TIE)):
        notes.append("plan, height and check points are written as tie points (a DBAT script has full control only)")
    ctrl_fixed = [[pts.ids[j], pts.ids[j]] + [repr(float(v)) for v in pts.xyz_given[j]] for j in np.flatnonzero(fixed)]
    ctrl_weighted = [[pts.ids[j], pts.ids[j]] + [repr(float(v)) for v in pts.xyz_given[j]]
                     + [repr(float(v)) for v in pts.sigma_given[j]] for j in np.flatnonzero(weighted)]
    have = np.isfinite(photos.xyz0).all(axis=1)
    opk = np.degrees(opk_from_R(photos.R_ground_from_cam))
    prior_rows = [[str(i + 1)] + [repr(float(v)) for v in photos.xyz0[i]] + [repr(float(v)) for v in opk[i]]
                  for i in np.flatnonzero(have)]
    if np.any(np.isfinite(photos.sigma_xyz0) & (photos.sigma_xyz0 > 0)) or np.any(
            np.isfinite(photos.sigma_angles) & (photos.sigma_angles > 0)):
        notes.append("observed exterior elements (GNSS, IMU) are written as approximations only")
    datum = ""
    held_all = np.flatnonzero((photos.sigma_xyz0 == 0).all(axis=1) & (photos.sigma_angles == 0).all(axis=1))
    n_held = int((photos.sigma_xyz0 == 0).sum() + (photos.sigma_angles == 0).sum())
    if len(held_all) == 1 and n_held == 7 and have.all():
        ref = int(held_all[0])
        expected, _ = photo_datum(replace(photos, sigma_xyz0=np.full_like(photos.sigma_xyz0, np.nan),
                                          sigma_angles=np.full_like(photos.sigma_angles, np.nan)), ref)
        if np.array_equal(expected.sigma_xyz0 == 0, photos.sigma_xyz0 == 0):
            datum = (f"<operation><set_datum ref_cam=\"{ref + 1}\" ref_base=\"longest\">depend</set_datum>"
                     "</operation>")
    elif n_held:
        notes.append("held exterior elements other than DBAT's 'depend' datum are not written")
    io = "".join(f"<{_IO_TAG[n]}>{'true' if e else 'false'}</{_IO_TAG[n]}>" for n, e in est.items())
    ctrl = ""
    if ctrl_fixed:
        ctrl += '<file format="id,label,x,y,z">control.txt</file>'
    if ctrl_weighted:
        ctrl += '<file format="id,label,x,y,z,sx,sy,sz">control_weighted.txt</file>'
    script = (
        '<?xml version="1.0" encoding="UTF-8"?>\n<document dbat_script_version="1.0.0">\n'
        f"<meta><name>{xml_escape(Path(str(project.source or 'striptri')).name)}</name><project_unit>m</project_unit>"
        "<software>striptri convert</software></meta>\n"
        '<input base_dir="$HERE">\n'
        + (f"<ctrl_pts>{ctrl}</ctrl_pts>\n" if ctrl else "")
        + '<images image_base_dir="$HERE"><file format="id,path">images.txt</file></images>\n'
        + '<image_pts><file format="im,id,x,y,sx,sy">markpts.txt</file></image_pts>\n'
        + ('<prior_eo><file format="id,x,y,z,omega,phi,kappa" units="degrees">prior_eo.txt</file></prior_eo>\n'
           if prior_rows else "")
        + f"<cameras>{camera}</cameras>\n</input>\n"
        + "<operations>\n<operation><set_bundle_estimate_params>"
        + f"<io>{io}</io><eo><all>true</all></eo><op><all>true</all></op>"
        + "</set_bundle_estimate_params></operation>\n"
        + (datum + "\n" if datum else "")
        + "<operation>bundle_adjustment</operation>\n</operations>\n</document>\n"
    )
    files = {SCRIPT_FILE: script, "images.txt": "# id, path\n" + _csv(image_rows),
             "markpts.txt": "# image id, point id, x, y, sx, sy (pixels, top-left origin, y down)\n" + _csv(mark_rows)}
    if ctrl_fixed:
        files["control.txt"] = "# id, label, x, y, z\n" + _csv(ctrl_fixed)
    if ctrl_weighted:
        files["control_weighted.txt"] = "# id, label, x, y, z, sx, sy, sz\n" + _csv(ctrl_weighted)
    if prior_rows:
        files["prior_eo.txt"] = "# id, x, y, z, omega, phi, kappa (degrees)\n" + _csv(prior_rows)
    return files, notes + pixel_size_note(project.settings.plate_unit, s, "DBAT")
