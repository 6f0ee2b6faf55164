"""DBAT (Damped Bundle Adjustment Toolbox, Börlin & Grussenmeyer) script projects: reader and
conversion to a striptri project (docs/formats.md, section DBAT).

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

Pixel centre convention: DBAT scales pixel coordinates to the sensor without a half-pixel shift;
its default principal point, half the sensor, is pixel coordinate (W/2, H/2), so the image corner
is (0, 0) and the centre of the top-left pixel is (0.5, 0.5). Plate coordinates (mm, x right, y
up, origin at the principal point): ``x = (col * ph - px) / aspect``, ``y = py - row * ph``
(``x = col * pw - px`` for square pixels). Checked on camcal: DBAT's result camera and camera
stations reproject the control points with mean residual 0.005 px; a half-pixel shift gives 0.5 px.
DBAT's omega, phi, kappa give R_ground_from_cam = Rx(omega) Ry(phi) Rz(kappa), striptri's
``rotations.R_from_opk`` (same check).

Malformed input: :class:`InputError` naming the file and the line.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from xml.parsers import expat

import numpy as np

from striptri import lens, model, rotations
from striptri.errors import InputError, NumericalFailure
from striptri.lens import NCP
from striptri.resection import resect_missing
from striptri.formats.conversions import Scene, pixel_size_note
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

    def estimates_distortion(self) -> bool:
        return any(self.estimated.get(n, False) for n in DISTORTION_NAMES)


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


# --------------------------------------------------------------------------- minimal XML tree with lines


@dataclass
class _El:
    tag: str
    attrib: dict
    line: int
    children: list = field(default_factory=list)
    text: str = ""

    def find(self, tag):
        for c in self.children:
            if c.tag == tag:
                return c
        return None

    def findall(self, tag):
        return [c for c in self.children if c.tag == tag]

    @property
    def value(self) -> str:
        return self.text.strip()


class _Refused(Exception):
    """Raised inside an expat handler: a construct the reader refuses, at a line."""

    def __init__(self, line: int, reason: str):
        super().__init__(reason)
        self.line, self.reason = line, reason


def _parse_xml(path: Path) -> _El:
    """The element tree of an XML file, with line numbers. Linear in the size of the file: the
    character data of an element is collected in chunks and joined once at its end. DTD entity
    declarations and external entities are refused, as defusedxml does (a "billion laughs"
    document, or one that reads other files through entities): InputError naming file and line."""
    raw = read_input_bytes(path, "is a folder, not a DBAT XML file")
    parser = expat.ParserCreate()
    stack: list[tuple[_El, list[str]]] = []
    root: list[_El] = []

    def start(tag, attrib):
        el = _El(tag, dict(attrib), parser.CurrentLineNumber)
        if stack:
            stack[-1][0].children.append(el)
        else:
            root.append(el)
        stack.append((el, []))

    def end(tag):
        el, chunks = stack.pop()
        el.text = "".join(chunks)

    def chars(data):
        if stack:
            stack[-1][1].append(data)

    def entity_decl(name, is_parameter_entity, value, base, system_id, public_id, notation_name):
        kind = "parameter entity" if is_parameter_entity else "entity"
        raise _Refused(parser.CurrentLineNumber, f"the document declares the {kind} '{name}'; a DBAT file has no "
                                                 "entity declarations (refused: entity expansion can make a small "
                                                 "file enormous)")

    def unparsed_entity_decl(name, base, system_id, public_id, notation_name):
        raise _Refused(parser.CurrentLineNumber, f"the document declares the unparsed entity '{name}'; refused")

    def external_entity(context, base, system_id, public_id):
        raise _Refused(parser.CurrentLineNumber, f"the document refers to the external entity '{system_id}'; "
                                                 "refused (a DBAT file names its data files in <file> elements)")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    parser.EntityDeclHandler = entity_decl
    parser.UnparsedEntityDeclHandler = unparsed_entity_decl
    parser.ExternalEntityRefHandler = external_entity
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    try:
        parser.Parse(raw, True)
    except _Refused as exc:
        raise InputError(path, exc.line, exc.reason) from None
    except expat.ExpatError as exc:
        raise InputError(path, exc.lineno, f"not well-formed XML: {expat.ErrorString(exc.code)}") from None
    if not root:
        raise InputError(path, None, "no XML element")
    return root[0]


# --------------------------------------------------------------------------- helpers


def _numbers(path, el: _El, n: int | None, what: str) -> list[float]:
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


def _base_dir(el: _El, here: Path, path: Path) -> Path:
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


def _bool(path, el: _El) -> bool:
    v = el.value.lower()
    if v in ("true", "1", "yes", "on"):
        return True
    if v in ("false", "0", "no", "off"):
        return False
    raise InputError(path, el.line, f"<{el.tag}> must be true or false, found '{el.value}'")


# --------------------------------------------------------------------------- camera


def _read_camera(path: Path, cam: _El, estimated: dict[str, bool]) -> DbatCamera:
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


def _estimated(path: Path, ops: _El | None) -> dict[str, bool]:
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
    root = _parse_xml(path)
    cams = root.find("cameras")
    found = cams.findall("camera") if cams is not None else []
    if len(found) != 1:
        raise InputError(path, (cams or root).line, f"{len(found)} <camera> elements; expected exactly one")
    return _read_camera(path, found[0], {n: False for n in IO_NAMES})


# --------------------------------------------------------------------------- reader


def read_dbat(script_xml_path: str | Path) -> DbatProject:
    """Read a DBAT script project (module doc). Raises InputError(file, line, reason)."""
    path = Path(script_xml_path)
    here = path.resolve().parent
    root = _parse_xml(path)
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
        croot = _parse_xml(cpath)
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


# --------------------------------------------------------------------------- conversion


def plate_origin(camera: DbatCamera) -> tuple[float, float]:
    """Where the plate origin lies in DBAT's scaled sensor coordinates (col * ph, row * ph): chosen
    so that DBAT's principal point is xp = yp = 0 (module doc)."""
    return camera.pp[0], camera.pp[1]


def pixels_to_plate(camera: DbatCamera, xy_pixel: np.ndarray) -> np.ndarray:
    """Pixel coordinates (column, row; corner origin, y down) -> plate mm (x right, y up, origin at
    the camera's principal point): ``x = col * ph - px``, ``y = py - row * ph``, ph = sensor H /
    image H, no half-pixel shift. The aspect acts in the camera model (b1 = 1/aspect - 1, about
    the principal point: ``(1 + b1)(x - xp)``). Checked against DBAT's own result on camcal
    (tests/test_dbat.py)."""
    xy_pixel = np.asarray(xy_pixel, dtype=float)
    ph = camera.pixel_size[1]
    x0, y0 = plate_origin(camera)
    return np.stack([xy_pixel[..., 0] * ph - x0, y0 - xy_pixel[..., 1] * ph], axis=-1)


# DBAT's interior names -> striptri's camera elements (lens.CAMERA_ELEMENTS)
_ELEMENT_OF = {"cc": "c", "px": "xp", "py": "yp", "K1": "k1", "K2": "k2", "K3": "k3", "P1": "p1", "P2": "p2",
               "as": "b1", "sk": "b2"}


def striptri_camera(camera: DbatCamera, reference: DbatCamera | None = None) -> np.ndarray:
    """striptri's camera elements (NCP,) of a DBAT camera, plate convention, plate frame of
    ``reference`` (default: the camera itself; pixels_to_plate of the reference camera).

    K, P and the skew carry over unchanged (DBAT's reprojection of camcal's control through its own
    result decides it: a sign change of P2 leaves a 0.32 px bias in y), b1 = 1/aspect - 1 (DBAT's
    'as', scaling x about the principal point); the principal point: ``xp = px - x0``,
    ``yp = y0 - py`` with (x0, y0) the reference's plate origin."""
    ref = reference or camera
    x0, y0 = plate_origin(ref)
    b1 = 1.0 / camera.aspect - 1.0
    prm = np.zeros(NCP)
    prm[lens.C] = camera.cc
    prm[lens.XP] = camera.pp[0] - x0
    prm[lens.YP] = y0 - camera.pp[1]
    prm[lens.K1:lens.K3 + 1] = camera.K
    prm[lens.P1], prm[lens.P2] = camera.P
    prm[lens.B1], prm[lens.B2] = b1, camera.skew
    return prm


def dbat_to_project(dbat: DbatProject, drop_distortion: bool = False) -> Scene:
    """A striptri project of a DBAT project; Scene.project is the model.Project.

    Plate coordinates in mm (pixels_to_plate), the camera in the plate convention with DBAT's
    model 3 (striptri_camera; its estimated elements free, the others held), image sigmas scaled
    by the pixel height, control fixed (nan) or weighted as read. drop_distortion: hold K, P at 0
    (a pinhole camera; said in Scene.notes). Approximate orientations come from prior_eo when
    present (DBAT's omega-phi-kappa is striptri's); the images without one are resected from the
    control (resection.resect_missing, as the script's spatial_resection). DBAT's datum
    ``depend`` (the first camera and one coordinate of the longest base held) becomes held
    elements of photos.csv (:func:`_depend_datum`)."""
    cam = dbat.camera
    notes: list[str] = []
    if cam.model not in (None, 3):
        notes.append(f"DBAT lens model {cam.model} read as model 3 (backward Brown, aspect before and skew after "
                     "the distortion); the other models differ in the order of aspect and skew")
    prm = striptri_camera(cam)
    sigma = np.full(NCP, np.nan)
    for name, element in _ELEMENT_OF.items():
        if cam.estimated.get(name):
            sigma[lens.CAMERA_ELEMENTS.index(element)] = math.inf
    if drop_distortion:
        dist = cam.distortion()
        nonzero = ", ".join(f"{k} = {v!r}" for k, v in dist.items() if v != 0) or "all zero"
        prm[lens.K1:lens.P2 + 1] = 0.0
        sigma[lens.K1:lens.P2 + 1] = np.nan
        notes.append(f"DBAT distortion dropped (drop_distortion): {nonzero}")
    est = [n for n in _ELEMENT_OF if cam.estimated.get(n)]
    if est:
        notes.append("camera elements estimated as in the script: " + ", ".join(_ELEMENT_OF[n] for n in est))

    photo_of = {iid: i for i, iid in enumerate(dbat.image_ids)}
    point_ids = list(dict.fromkeys(list(dbat.ctrl_ids) + list(dbat.ip_point)))
    point_of = {pid: j for j, pid in enumerate(point_ids)}
    n = len(point_ids)
    kind = np.full(n, model.TIE, dtype=np.int64)
    xyz_given = np.full((n, 3), np.nan)
    sigma_given = np.full((n, 3), np.nan)
    for k, cid in enumerate(dbat.ctrl_ids):
        j = point_of[cid]
        kind[j] = model.FULL
        xyz_given[j] = dbat.ctrl_xyz[k]
        sigma_given[j] = dbat.ctrl_sigma[k]

    nim = dbat.n_images
    xyz0 = np.full((nim, 3), np.nan)
    angles = np.zeros((nim, 3))
    prior = {pid: k for k, pid in enumerate(dbat.prior_ids)}
    have = [i for i, iid in enumerate(dbat.image_ids) if iid in prior]
    for i in have:
        k = prior[dbat.image_ids[i]]
        xyz0[i] = dbat.prior_xyz[k]
        angles[i] = dbat.prior_angles[k]
    if have:
        notes.append(f"approximate orientations of {len(have)} of {nim} images from prior_eo (DBAT's "
                     "omega-phi-kappa is striptri's omega-phi-kappa)")
    if len(have) < nim:
        notes.append(f"{nim - len(have)} images have no approximate orientation in the script: resected from the "
                     "control (DBAT's spatial_resection)")
    R = rotations.R_from_opk(angles)
    pw, ph = cam.pixel_size
    photos = model.Photos(
        ids=list(dbat.image_names), camera_index=np.zeros(nim, dtype=np.int64), strip_ids=[""] * nim,
        xyz0=xyz0, R_ground_from_cam=R, angles=angles,
        sigma_xyz0=np.full((nim, 3), np.nan), sigma_angles=np.full((nim, 3), np.nan),
    )
    datum = "control" if dbat.n_control else "inner"
    if dbat.datum and dbat.datum.get("type") == "depend":
        photos, note = _depend_datum(dbat, photos)
        notes.append(note)
        datum = "control"
    elif dbat.datum:
        notes.append(f"DBAT datum {dbat.datum} is not reproduced; striptri's datum is '{datum}'")
    project = model.Project(
        cameras=model.Cameras(ids=[cam.id], interior=prm[None, :], sigma_interior=sigma[None, :],
                              convention=np.array([lens.PLATE])),
        photos=photos,
        image_points=model.ImagePoints(
            photo_index=np.array([photo_of[i] for i in dbat.ip_image], dtype=np.int64),
            point_index=np.array([point_of[p] for p in dbat.ip_point], dtype=np.int64),
            xy=pixels_to_plate(cam, dbat.ip_xy),
            sigma_xy=dbat.ip_sigma * ph,
        ),
        points=model.ObjectPoints(ids=point_ids, kind=kind, xyz_given=xyz_given, sigma_given=sigma_given),
        settings=model.ProjectSettings(angle_unit="deg", sigma_image=float(np.median(dbat.ip_sigma) * ph)
                                       if dbat.n_image_points else 0.005,
                                       datum=datum),
        source=dbat.path,
    )
    if len(have) < nim:
        try:
            project, more = resect_missing(project)
            notes += more
        except NumericalFailure as exc:
            notes.append(f"{exc}; approximations must come from elsewhere")
    return Scene(project=project, xyz_ground=xyz_given.copy(), plate_units_per_pixel=float(ph), notes=notes)


def _depend_datum(dbat: DbatProject, photos: model.Photos):
    """DBAT's ``set_datum depend`` (ref_cam, ref_base="longest"): :func:`photo_datum` of the
    reference camera. -> (photos, note)."""
    ref_id = str(dbat.datum.get("ref_cam", dbat.image_ids[0]))
    if ref_id not in dbat.image_ids:
        raise InputError(dbat.path, None, f"set_datum names ref_cam '{ref_id}', which is not an image id")
    if not np.isfinite(photos.xyz0).all():
        raise InputError(dbat.path, None, "set_datum depend needs approximate positions of every camera (prior_eo)")
    return photo_datum(photos, dbat.image_ids.index(ref_id), dbat.project_unit)


def photo_datum(photos: model.Photos, ref: int = 0, unit: str = "m"):
    """A minimal datum by photos (DBAT's 'depend'): the six elements of photo ``ref`` held, and of
    the photo farthest from it (approximate positions) the base component of largest magnitude
    held too: six plus one, the scale from the longest base. -> (photos with sigma 0 on those
    elements, a note)."""
    i = ref
    base = photos.xyz0 - photos.xyz0[i]
    j = int(np.argmax(np.linalg.norm(base, axis=1)))
    axis = int(np.argmax(np.abs(base[j])))
    sx, sa = photos.sigma_xyz0.copy(), photos.sigma_angles.copy()
    sx[i], sa[i] = 0.0, 0.0
    sx[j, axis] = 0.0
    note = (f"datum by photos (DBAT's 'depend'): photo {photos.ids[i]} held (6 elements) and {'XYZ'[axis]}0 of "
            f"photo {photos.ids[j]} (the longest base, {np.linalg.norm(base[j]):.3f} {unit}) held")
    return replace(photos, sigma_xyz0=sx, sigma_angles=sa), note


# --------------------------------------------------------------------------- writing


_DBAT_OF = {v: k for k, v in _ELEMENT_OF.items()}  # striptri element -> DBAT name
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
    import math as _math
    from xml.sax.saxutils import escape as xml_escape

    from striptri.lens import CAMERA_ELEMENTS, IMAGE, has_distortion
    from striptri.rotations import opk_from_R

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
    est = {name: bool(_math.isinf(cams.sigma_interior[0, CAMERA_ELEMENTS.index(el)]) or
                      (cams.sigma_interior[0, CAMERA_ELEMENTS.index(el)] > 0))
           for el, name in _DBAT_OF.items()}
    if np.any(np.isfinite(cams.sigma_interior[0]) & (cams.sigma_interior[0] > 0)):
        notes.append("observed camera elements are written as estimated (a DBAT script has no prior for them)")
    camera = (
        "<camera><id>1</id>"
        f"<name>{xml_escape(cams.ids[0])}</name><unit>mm</unit>"
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
