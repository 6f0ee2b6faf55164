"""The DBAT reader: a DBAT script project (or camera file) -> :class:`DbatProject`, struct of
arrays in DBAT's own units and conventions (pixels, corner origin, y down).

A DBAT project is an XML *script* (``<document dbat_script_version=...>``) whose ``<input>`` names

* ``<ctrl_pts><file format="id,label,x,y,z[,sxyz | ,sx,sy,sz]">``: control points (fixed when no
  sigma column);
* ``<images><file format="id,path">``: the images;
* ``<image_pts><file format="im,id,x,y[,sxy | ,sx,sy]" [sxy="1"]>``: image points in pixels,
  origin at the top-left corner of the image, y down;
* ``<prior_eo><file format="id,x,y,z,omega,phi,kappa" units="degrees">``: approximate exterior
  orientation (optional);
* ``<cameras>``: a ``<camera>`` element inline or ``<file>`` naming a camera XML
  (``<document dbat_camera_version=...>``).

Text files: one record a line, comma-separated, ``#`` starts a comment. Relative paths are taken
from the ``base_dir`` of ``<input>`` (``$HERE`` = the script's folder, ``$HOME``; ``$DBAT`` cannot
be resolved here). The operations ``set_bundle_estimate_params`` (which camera parameters are
estimated) and ``set_datum`` are read; the others (resection, intersection, ...) are ignored.

Camera (DBAT's units, normally mm): ``sensor`` "W,H" or "auto,H" / "W,auto" (the missing side from
the image size and aspect), ``image`` "width,height" pixels, ``aspect`` = pixel height / pixel
width, ``cc`` principal distance (default ``focal``), ``pp`` principal point measured from the
top-left image corner, x right, y down (default: the sensor centre), ``K`` (K1, K2, K3) and ``P``
(P1, P2) of DBAT's backward (photogrammetric) Brown model (default 0).

Malformed input: :class:`InputError` naming the file and the line.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from striptri.errors import InputError
from striptri.formats.dbat.xml_tree import Element, parse_xml
from striptri.io.csvtable import read_input_bytes

DISTORTION_NAMES = ("K1", "K2", "K3", "P1", "P2")
IO_NAMES = ("cc", "px", "py", "as", "sk") + DISTORTION_NAMES


@dataclass(frozen=True)
class DbatCamera:
    """One DBAT camera. Lengths in ``unit`` (mm): cc, pp (from the top-left corner, y down),
    sensor (W, H), pixel_size (width, height). image_size (width, height) pixels. K (3,), P (2,):
    DBAT's distortion coefficients K1..K3, P1, P2. estimated: IO_NAMES -> estimated in the script."""

    id: str
    name: str
    unit: str
    cc: float
    pp: tuple[float, float]
    sensor: tuple[float, float]
    image_size: tuple[int, int]
    aspect: float
    skew: float
    K: np.ndarray
    P: np.ndarray
    model: int | None
    estimated: dict[str, bool]
    source: Path | None = None
    line: int | None = None

    @property
    def pixel_size(self) -> tuple[float, float]:
        return (self.sensor[0] / self.image_size[0], self.sensor[1] / self.image_size[1])

    @property
    def principal_point_pixels(self) -> tuple[float, float]:
        """The principal point in pixel coordinates (column, row), corner origin."""
        pw, ph = self.pixel_size
        return (self.pp[0] / pw, self.pp[1] / ph)

    def distortion(self) -> dict[str, float]:
        return dict(zip(DISTORTION_NAMES, [float(v) for v in self.K[:3]] + [float(v) for v in self.P[:2]]))

    def has_distortion(self) -> bool:
        return bool(np.any(self.K != 0) or np.any(self.P != 0))


@dataclass(frozen=True)
class DbatProject:
    """A DBAT script project as struct of arrays.

    image_ids, image_names: (nim,). Image points: ip_image (image ids), ip_point (point ids),
    ip_xy (m, 2) pixels (corner origin, y down), ip_sigma (m, 2) pixels, ip_lines (m,) file lines.
    Control: ctrl_ids, ctrl_labels, ctrl_xyz (n, 3), ctrl_sigma (n, 3) (nan = fixed).
    Prior EO: prior_ids, prior_xyz (k, 3), prior_angles (k, 3) radians (DBAT omega, phi, kappa).
    datum: the set_datum operation (e.g. {"type": "depend", "ref_cam": "1", "ref_base": "longest"})
    or None; datum_note: the text of meta/datum, if any.
    """

    path: Path
    name: str
    project_unit: str
    camera: DbatCamera
    image_ids: list[str]
    image_names: list[str]
    ip_image: list[str]
    ip_point: list[str]
    ip_xy: np.ndarray
    ip_sigma: np.ndarray
    ip_lines: np.ndarray
    ip_file: Path | None
    ctrl_ids: list[str]
    ctrl_labels: list[str]
    ctrl_xyz: np.ndarray
    ctrl_sigma: np.ndarray
    prior_ids: list[str] = field(default_factory=list)
    prior_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    prior_angles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    datum: dict | None = None
    datum_note: str = ""

    @property
    def n_images(self) -> int:
        return len(self.image_ids)

    @property
    def n_points(self) -> int:
        return len(set(self.ip_point))

    @property
    def n_image_points(self) -> int:
        return len(self.ip_point)

    @property
    def n_control(self) -> int:
        return len(self.ctrl_ids)


# --------------------------------------------------------------------------- helpers


def _numbers(path, el: Element, n: int | None, what: str) -> list[float]:
    toks = [t.strip() for t in el.value.split(",")]
    if n is not None and len(toks) != n:
        raise InputError(path, el.line, f"<{el.tag}> {what}: expected {n} comma-separated numbers, found '{el.value}'")
    return [_number(path, el.line, f"<{el.tag}>", t) for t in toks]


def _number(path, line, what, tok) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(path, line, f"{what} '{tok}' is not a number") from None
    if not math.isfinite(v):
        raise InputError(path, line, f"{what} '{tok}' is not a finite number")
    return v


def _resolve(base: Path, here: Path, text: str) -> Path:
    text = text.strip().replace("$HERE", str(here)).replace("$HOME", os.path.expanduser("~"))
    p = Path(text)
    return p if p.is_absolute() else base / p


def _base_dir(el: Element, here: Path, path: Path) -> Path:
    b = el.attrib.get("base_dir")
    if b is None:
        return here
    if "$DBAT" in b:
        raise InputError(path, el.line, "base_dir uses $DBAT (the DBAT installation), which striptri cannot resolve")
    return _resolve(here, here, b)


def _read_table(path: Path, fmt: str, fmt_line: int, script: Path, required: tuple[str, ...]):
    """Rows of a comma-separated DBAT text file with the columns of `fmt`. -> (columns, [(line, fields)])."""
    cols = [c.strip().lower() for c in fmt.split(",")]
    missing = [c for c in required if c not in cols]
    if missing:
        raise InputError(script, fmt_line, f"format '{fmt}' lacks column(s) {', '.join(missing)}")
    raw = read_input_bytes(path, "is a folder, not a DBAT data file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, raw[: exc.start].count(b"\n") + 1, "not valid UTF-8 text") from None
    rows = []
    for n, line in enumerate(text.splitlines(), start=1):
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        fields = [f.strip() for f in body.split(",")]
        if len(fields) != len(cols):
            raise InputError(path, n, f"expected {len(cols)} comma-separated fields ({fmt}), found {len(fields)}")
        rows.append((n, dict(zip(cols, fields))))
    return cols, rows


def _id(path, line, tok) -> str:
    if tok == "":
        raise InputError(path, line, "an id is empty")
    try:
        v = float(tok)
    except ValueError:
        return tok
    return str(int(v)) if v.is_integer() else tok


def _bool(path, el: Element) -> bool:
    v = el.value.lower()
    if v in ("true", "1", "yes", "on"):
        return True
    if v in ("false", "0", "no", "off"):
        return False
    raise InputError(path, el.line, f"<{el.tag}> must be true or false, found '{el.value}'")


# --------------------------------------------------------------------------- camera


def _read_camera(path: Path, cam: Element, estimated: dict[str, bool]) -> DbatCamera:
    def get(tag):
        return cam.find(tag)

    img_el = get("image")
    if img_el is None:
        raise InputError(path, cam.line, "<camera> has no <image> (width,height in pixels)")
    w, h = _numbers(path, img_el, 2, "image size")
    if w <= 0 or h <= 0 or not float(w).is_integer() or not float(h).is_integer():
        raise InputError(path, img_el.line, f"image size must be positive integers, found '{img_el.value}'")
    aspect = _numbers(path, get("aspect"), 1, "aspect")[0] if get("aspect") is not None else 1.0
    if aspect <= 0:
        raise InputError(path, get("aspect").line, f"<aspect> (pixel height / pixel width) must be > 0, found "
                                                   f"'{get('aspect').value}'")
    sens_el = get("sensor")
    if sens_el is None:
        raise InputError(path, cam.line, "<camera> has no <sensor> (width,height)")
    toks = [t.strip().lower() for t in sens_el.value.split(",")]
    if len(toks) != 2 or toks == ["auto", "auto"]:
        raise InputError(path, sens_el.line, f"<sensor> must be 'W,H', 'auto,H' or 'W,auto', found '{sens_el.value}'")
    if toks[0] == "auto":
        sh = _number(path, sens_el.line, "<sensor> height", toks[1])
        ph = sh / h
        sw = ph / aspect * w
    elif toks[1] == "auto":
        sw = _number(path, sens_el.line, "<sensor> width", toks[0])
        pw = sw / w
        sh = pw * aspect * h
    else:
        sw = _number(path, sens_el.line, "<sensor> width", toks[0])
        sh = _number(path, sens_el.line, "<sensor> height", toks[1])
    if sw <= 0 or sh <= 0:
        raise InputError(path, sens_el.line, "sensor size must be > 0")
    focal = _numbers(path, get("focal"), 1, "focal")[0] if get("focal") is not None else None
    if get("cc") is not None:
        cc = _numbers(path, get("cc"), 1, "camera constant")[0]
        cc_el = get("cc")
    elif focal is not None:
        cc = focal
        cc_el = get("focal")
    else:
        raise InputError(path, cam.line, "<camera> has neither <cc> nor <focal>")
    if cc <= 0:
        raise InputError(path, cc_el.line, f"<{cc_el.tag}> (the principal distance) must be > 0, found "
                                           f"'{cc_el.value}'; a project's camera needs c > 0")
    pp = tuple(_numbers(path, get("pp"), 2, "principal point")) if get("pp") is not None else (sw / 2, sh / 2)
    nK = int(_numbers(path, get("nK"), 1, "nK")[0]) if get("nK") is not None else 3
    nP = int(_numbers(path, get("nP"), 1, "nP")[0]) if get("nP") is not None else 2
    K = np.zeros(3)
    P = np.zeros(2)
    if get("K") is not None:
        k = _numbers(path, get("K"), None, "K")
        if len(k) > 3:
            raise InputError(path, get("K").line, f"more than 3 radial coefficients K ({len(k)})")
        K[: len(k)] = k
    if get("P") is not None:
        p = _numbers(path, get("P"), None, "P")
        if len(p) > 2:
            raise InputError(path, get("P").line, f"more than 2 decentering coefficients P ({len(p)})")
        P[: len(p)] = p
    est = {n: e for n, e in estimated.items()}
    for i in range(nK, 3):
        est[f"K{i + 1}"] = False
    for i in range(nP, 2):
        est[f"P{i + 1}"] = False
    return DbatCamera(
        id=get("id").value if get("id") is not None else "1",
        name=get("name").value if get("name") is not None else "",
        unit=get("unit").value if get("unit") is not None else "mm",
        cc=cc, pp=(float(pp[0]), float(pp[1])), sensor=(sw, sh), image_size=(int(w), int(h)),
        aspect=aspect, skew=_numbers(path, get("skew"), 1, "skew")[0] if get("skew") is not None else 0.0,
        K=K, P=P, model=int(_numbers(path, get("model"), 1, "model")[0]) if get("model") is not None else None,
        estimated=est, source=path, line=cam.line,
    )


def _estimated(path: Path, ops: Element | None) -> dict[str, bool]:
    est = {n: False for n in IO_NAMES}
    if ops is None:
        return est
    alias = {"cc": ("cc",), "pp": ("px", "py"), "px": ("px",), "py": ("py",), "aspect": ("as",),
             "skew": ("sk",), "k": ("K1", "K2", "K3"), "p": ("P1", "P2"),
             **{n.lower(): (n,) for n in DISTORTION_NAMES}}
    for op in ops.findall("operation"):
        sbep = op.find("set_bundle_estimate_params")
        io = sbep.find("io") if sbep is not None else None
        if io is None:
            continue
        for el in io.children:
            if el.tag == "all":
                v = _bool(path, el)
                est = {n: v for n in IO_NAMES}
            elif el.tag.lower() in alias:
                v = _bool(path, el)
                for n in alias[el.tag.lower()]:
                    est[n] = v
            elif el.tag != "c":
                raise InputError(path, el.line, f"unknown camera parameter <{el.tag}> in set_bundle_estimate_params")
    return est


def read_dbat_camera(camera_xml_path: str | Path) -> DbatCamera:
    """Read a DBAT camera file (``<document dbat_camera_version=...><cameras><camera>``), e.g. the
    calibrated camera DBAT writes to its result folder. Exactly one camera; nothing estimated."""
    path = Path(camera_xml_path)
    root = parse_xml(path)
    cams = root.find("cameras")
    found = cams.findall("camera") if cams is not None else []
    if len(found) != 1:
        raise InputError(path, (cams or root).line, f"{len(found)} <camera> elements; expected exactly one")
    return _read_camera(path, found[0], {n: False for n in IO_NAMES})


# --------------------------------------------------------------------------- reader


def script_inputs(script_xml_path: str | Path) -> list[Path]:
    """Every file a DBAT script makes the reader open: the script and each ``<file>`` of its
    ``<input>`` sections, resolved from ``base_dir`` as :func:`read_dbat` does. A command that writes
    an output checks it against all of them, so that it never replaces what it reads (a script whose
    base_dir points into the output folder). Raises InputError for a script that cannot be read."""
    path = Path(script_xml_path)
    here = path.resolve().parent
    root = parse_xml(path)
    inp = root.find("input") if root.tag == "document" else None
    if inp is None:
        return [path]
    base = _base_dir(inp, here, path)
    found = [path]
    for section in inp.children:
        found += [_resolve(base, here, f.value) for f in section.findall("file") if f.value]
    return found


def read_dbat(script_xml_path: str | Path) -> DbatProject:
    """Read a DBAT script project (module doc). Raises InputError(file, line, reason)."""
    path = Path(script_xml_path)
    here = path.resolve().parent
    root = parse_xml(path)
    if root.tag != "document":
        raise InputError(path, root.line, f"not a DBAT script: root element <{root.tag}>, expected <document>")
    inp = root.find("input")
    if inp is None:
        raise InputError(path, root.line, "DBAT script has no <input> section")
    base = _base_dir(inp, here, path)
    meta = root.find("meta")
    name = meta.find("name").value if meta is not None and meta.find("name") is not None else path.stem
    unit = meta.find("project_unit").value if meta is not None and meta.find("project_unit") is not None else ""
    datum_note = " ".join(meta.find("datum").value.split()) if meta is not None and meta.find("datum") is not None else ""
    ops = root.find("operations")
    estimated = _estimated(path, ops)

    def files(section: str, required: bool):
        sec = inp.find(section)
        if sec is None:
            if required:
                raise InputError(path, inp.line, f"<input> has no <{section}>")
            return []
        fs = sec.findall("file")
        if required and not fs:
            raise InputError(path, sec.line, f"<{section}> names no <file>")
        return fs

    # cameras
    cams_el = inp.find("cameras")
    if cams_el is None:
        raise InputError(path, inp.line, "<input> has no <cameras>")
    cam_els = [(path, c) for c in cams_el.findall("camera")]
    for f in cams_el.findall("file"):
        cpath = _resolve(base, here, f.value)
        croot = parse_xml(cpath)
        cc = croot.find("cameras")
        cam_els += [(cpath, c) for c in (cc.findall("camera") if cc is not None else [])]
    if len(cam_els) != 1:
        raise InputError(path, cams_el.line, f"{len(cam_els)} cameras; the reader handles exactly one camera")
    camera = _read_camera(cam_els[0][0], cam_els[0][1], estimated)

    # images
    image_ids, image_names = [], []
    for f in files("images", True):
        fpath = _resolve(base, here, f.value)
        _, rows = _read_table(fpath, f.attrib.get("format", "id,path"), f.line, path, ("id", "path"))
        for n, r in rows:
            iid = _id(fpath, n, r["id"])
            if iid in image_ids:
                raise InputError(fpath, n, f"image id {iid} given twice")
            name = r["path"].replace("\\", "/").rsplit("/", 1)[-1]
            if not name:
                raise InputError(fpath, n, f"image {iid}: the path '{r['path']}' names no file (the photo id)")
            image_ids.append(iid)
            image_names.append(name)

    # image points
    ip_image, ip_point, xy, sig, lines = [], [], [], [], []
    ip_file = None
    known = set(image_ids)
    seen = set()
    for f in files("image_pts", True):
        fpath = ip_file = _resolve(base, here, f.value)
        _, rows = _read_table(fpath, f.attrib.get("format", "im,id,x,y"), f.line, path, ("im", "id", "x", "y"))
        default = f.attrib.get("sxy")
        default_s = _number(path, f.line, "sxy attribute", default) if default is not None else 1.0
        for n, r in rows:
            im, pt = _id(fpath, n, r["im"]), _id(fpath, n, r["id"])
            if im not in known:
                raise InputError(fpath, n, f"image id {im} is not in the image list")
            if (im, pt) in seen:
                raise InputError(fpath, n, f"image {im} measures point {pt} twice")
            seen.add((im, pt))
            x, y = _number(fpath, n, "x", r["x"]), _number(fpath, n, "y", r["y"])
            if "sxy" in r:
                s = _number(fpath, n, "sxy", r["sxy"])
                sx = sy = s
            elif "sx" in r and "sy" in r:
                sx, sy = _number(fpath, n, "sx", r["sx"]), _number(fpath, n, "sy", r["sy"])
            else:
                sx = sy = default_s
            if sx <= 0 or sy <= 0:
                raise InputError(fpath, n, "image point sigma must be > 0")
            ip_image.append(im)
            ip_point.append(pt)
            xy.append((x, y))
            sig.append((sx, sy))
            lines.append(n)

    # control points
    c_ids, c_labels, c_xyz, c_sig = [], [], [], []
    for f in files("ctrl_pts", False):
        fpath = _resolve(base, here, f.value)
        _, rows = _read_table(fpath, f.attrib.get("format", "id,label,x,y,z"), f.line, path, ("id", "x", "y", "z"))
        for n, r in rows:
            cid = _id(fpath, n, r["id"])
            if cid in c_ids:
                raise InputError(fpath, n, f"control point {cid} given twice")
            c_ids.append(cid)
            c_labels.append(r.get("label", ""))
            c_xyz.append([_number(fpath, n, a, r[a]) for a in "xyz"])
            if "sxyz" in r:
                c_sig.append([_number(fpath, n, "sxyz", r["sxyz"])] * 3)
            elif all(k in r for k in ("sx", "sy", "sz")):
                c_sig.append([_number(fpath, n, k, r[k]) for k in ("sx", "sy", "sz")])
            else:
                c_sig.append([math.nan] * 3)
            if any(s <= 0 for s in c_sig[-1]):
                raise InputError(fpath, n, "control point sigma must be > 0 (leave the column out for fixed points)")

    # prior EO
    p_ids, p_xyz, p_ang = [], [], []
    for f in files("prior_eo", False):
        fpath = _resolve(base, here, f.value)
        units = f.attrib.get("units", "radians").lower()
        if units not in ("degrees", "radians"):
            raise InputError(path, f.line, f"prior_eo units '{units}': expected degrees or radians")
        _, rows = _read_table(fpath, f.attrib.get("format", "id,x,y,z,omega,phi,kappa"), f.line, path,
                              ("id", "x", "y", "z", "omega", "phi", "kappa"))
        for n, r in rows:
            p_ids.append(_id(fpath, n, r["id"]))
            p_xyz.append([_number(fpath, n, a, r[a]) for a in "xyz"])
            ang = [_number(fpath, n, a, r[a]) for a in ("omega", "phi", "kappa")]
            p_ang.append([math.radians(a) for a in ang] if units == "degrees" else ang)

    # datum
    datum = None
    if ops is not None:
        for op in ops.findall("operation"):
            sd = op.find("set_datum")
            if sd is not None:
                datum = {"type": sd.value, **sd.attrib}

    return DbatProject(
        path=path, name=name, project_unit=unit, camera=camera, image_ids=image_ids, image_names=image_names,
        ip_image=ip_image, ip_point=ip_point, ip_xy=np.asarray(xy, dtype=float).reshape(-1, 2),
        ip_sigma=np.asarray(sig, dtype=float).reshape(-1, 2), ip_lines=np.asarray(lines, dtype=np.int64),
        ip_file=ip_file, ctrl_ids=c_ids, ctrl_labels=c_labels, ctrl_xyz=np.asarray(c_xyz, dtype=float).reshape(-1, 3),
        ctrl_sigma=np.asarray(c_sig, dtype=float).reshape(-1, 3), prior_ids=p_ids,
        prior_xyz=np.asarray(p_xyz, dtype=float).reshape(-1, 3), prior_angles=np.asarray(p_ang, dtype=float).reshape(-1, 3),
        datum=datum, datum_note=datum_note,
    )
