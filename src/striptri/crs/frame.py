"""The local Cartesian frame of a block in a map projection (docs/decisions.md, "Map coordinates").

A project in a projected CRS (``[coordinates]`` of project.toml) is adjusted in a *local
topocentric frame*: origin on the ellipsoid (h = 0) below the block's centre, Z along the ellipsoid
normal there, X and Y in the tangent plane, turned about Z so that X points along *grid* east at
the centre (true east turned by the meridian convergence gamma0 there). Near the centre the local
axes are therefore the grid's axes, without the projection's scale and the Earth's curvature.

Grid -> local, for points (E, N, H) (``always_xy``: easting, northing, height in metres):

1. ellipsoidal height ``h = H + N_geoid(lon, lat)`` for orthometric heights, ``h = H`` otherwise;
2. (E, N) -> (lon, lat) by the inverse projection (pyproj, the CRS's own geodetic CRS);
3. (lon, lat, h) -> geocentric (X, Y, Z) (PROJ ``cart`` on the CRS's ellipsoid);
4. ``xyz_local = R_local_from_ecef (xyz_ecef - xyz_ecef_origin)``.

Local -> grid is the exact inverse of each step (PROJ's ``cart`` inverse and the forward
projection), so a round trip is exact to the arithmetic of PROJ (1e-9 m).

Directions (photo rotations, small displacements) change frame with the rotation
``R_local_from_grid(P)`` at their point P: the grid's axes at P are grid east, grid north (grid
north is true north turned clockwise by the meridian convergence gamma(P)) and the ellipsoid normal
at P, carried into the local frame. It is the Jacobian of the map grid -> local at P, orthonormalised
(the projection is conformal: the Jacobian is that rotation times diag(s_E, s_N, 1) with the scales of
:meth:`LocalFrame.jacobian`); tests/test_crs_frame.py checks both against central differences.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from striptri.errors import InputError
from striptri.model import CoordinateSettings
from striptri.geometry.rotations import angles_from_R, angles_jacobian


def _pyproj():
    # imported here, not at the top: pyproj costs 0.12 s of start-up, paid only by projects with a CRS
    import pyproj

    return pyproj


def parse_crs(text: str):
    """pyproj CRS of ``text`` (EPSG code or WKT), or ValueError with the reason why it cannot serve
    as a project's CRS: unknown to PROJ, not projected (a geographic or geocentric CRS), compound
    (give the horizontal CRS and [coordinates] heights), axes not in metres."""
    pyproj = _pyproj()
    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as exc:
        raise ValueError(f"{text!r} is not a CRS PROJ knows: {exc}") from None
    if crs.is_compound:
        raise ValueError(f"{crs.name!r} is a compound CRS: give its horizontal, projected part (e.g. the EPSG code of "
                         "the map projection) and say the kind of the heights with heights = \"ellipsoidal\" or "
                         "\"orthometric\"")
    if not crs.is_projected:
        kind = "geographic (angles)" if crs.is_geographic else ("geocentric" if crs.is_geocentric else "not projected")
        raise ValueError(f"{crs.name!r} is {kind}: striptri reads ground coordinates in metres of a map projection; "
                         "give the projected CRS of the coordinates (e.g. EPSG:326zz, UTM zone zz north)")
    units = {(a.unit_name, a.unit_conversion_factor) for a in crs.axis_info[:2]}
    if any(factor != 1.0 for _, factor in units):
        raise ValueError(f"{crs.name!r} has axes in {', '.join(sorted(n for n, _ in units))}: striptri reads ground "
                         "coordinates in metres; give a CRS whose axes are in metres")
    return crs


def geoid_pipeline(grid: Path):
    """pyproj Transformer whose forward transform turns (lon, lat in degrees, H) into (lon, lat,
    H + N) with N the geoid undulation of the grid file (PROJ ``vgridshift``, multiplier 1).
    ValueError when PROJ cannot open the grid."""
    pyproj = _pyproj()
    try:
        return pyproj.Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
            f"+step +proj=vgridshift +grids={grid} +multiplier=1 "
            "+step +proj=unitconvert +xy_in=rad +xy_out=deg")
    except pyproj.exceptions.ProjError as exc:
        raise ValueError(f"PROJ cannot use the geoid grid {str(grid)!r}: {exc}") from None


@dataclass(frozen=True)
class FrameOrigin:
    """Origin of a local frame: lon0, lat0 in degrees, on the ellipsoid (h = 0); gamma0: the meridian
    convergence there (degrees, grid north clockwise from true north)."""

    lon: float
    lat: float
    gamma: float


class LocalFrame:
    """Grid (projected CRS + height kind) <-> local topocentric frame (module doc). Every method is
    vectorised over a leading batch axis; coordinates in metres, rotations as (n, 3, 3) arrays.

    settings: the project's [coordinates]; centre_grid: (3,) grid E, N, H of the block's centre (its
    height is ignored: the origin lies on the ellipsoid). Raises InputError (naming ``toml``) when a
    geoid grid does not cover a point."""

    def __init__(self, settings: CoordinateSettings, centre_grid, toml: str | Path = "project.toml"):
        pyproj = _pyproj()
        self.settings = settings
        self.toml = toml
        self.crs = parse_crs(settings.crs)
        ell = self.crs.ellipsoid
        self._a, self._rf = ell.semi_major_metre, ell.inverse_flattening
        self._e2 = 1.0 - (1.0 - 1.0 / self._rf) ** 2 if self._rf else 0.0
        self._to_geo = pyproj.Transformer.from_crs(self.crs, self.crs.geodetic_crs, always_xy=True)
        self._proj = pyproj.Proj(self.crs)
        ellps = f"+a={self._a!r} +rf={self._rf!r}" if self._rf else f"+R={self._a!r}"
        self._cart = pyproj.Transformer.from_pipeline(
            f"+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart {ellps}")
        self._geoid = geoid_pipeline(settings.geoid_grid) if settings.geoid_grid is not None else None
        centre = np.asarray(centre_grid, dtype=float).reshape(3)
        lon0, lat0 = self._to_geo.transform(centre[0], centre[1])
        gamma0 = float(self._convergence(np.array([lon0]), np.array([lat0]))[0])
        self.origin = FrameOrigin(float(lon0), float(lat0), gamma0)
        self._xyz_ecef0 = self._ecef(np.array([lon0]), np.array([lat0]), np.zeros(1))[0]
        # rows: local X (grid east at the centre), local Y (grid north there), up, in geocentric axes
        enu = _R_enu_from_ecef(np.radians(lon0), np.radians(lat0))
        self.R_local_from_ecef = _rz_plan(np.radians(gamma0)) @ enu

    # ---------------------------------------------------------------------------- the pieces

    def _ecef(self, lon, lat, h):
        x, y, z = self._cart.transform(lon, lat, h)
        return np.column_stack([x, y, z])

    def _geodetic(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Longitude and latitude (deg, (n,)) of grid points (n, 3); outside the projection's domain
        nan (PROJ's inf would make the trigonometry warn; callers find the rows not finite)."""
        lon, lat = self._to_geo.transform(g[:, 0], g[:, 1])
        lon, lat = np.asarray(lon, dtype=float), np.asarray(lat, dtype=float)
        bad = ~(np.isfinite(lon) & np.isfinite(lat))
        return np.where(bad, np.nan, lon), np.where(bad, np.nan, lat)

    def _convergence(self, lon, lat):
        """Meridian convergence at (lon, lat) (degrees, (n,)): grid north clockwise from true north."""
        gamma = np.asarray(self._proj.get_factors(lon, lat).meridian_convergence, dtype=float).reshape(-1)
        return np.where(np.isfinite(gamma), gamma, np.nan)  # outside the domain: nan, as _geodetic

    def geoid_undulation(self, lon, lat) -> np.ndarray:
        """N at (lon, lat) in degrees, (n,) -> (n,) m: the constant of [coordinates], the grid's value,
        or 0 for ellipsoidal heights."""
        lon = np.asarray(lon, dtype=float).reshape(-1)
        s = self.settings
        if s.heights == "ellipsoidal":
            return np.zeros(lon.shape)
        if self._geoid is None:
            return np.full(lon.shape, float(s.geoid_undulation))
        _, _, n = self._geoid.transform(lon, np.asarray(lat, dtype=float).reshape(-1), np.zeros(lon.shape))
        n = np.asarray(n, dtype=float)
        bad = ~np.isfinite(n) | (np.abs(n) > 1e3)
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise InputError(self.toml, None, f"[coordinates] geoid_grid: the grid {str(s.geoid_grid)!r} does not "
                                              f"cover lon {lon[k]:.6f}, lat {float(np.reshape(lat, -1)[k]):.6f} deg "
                                              "(a point of the project)")
        return n

    # ---------------------------------------------------------------------------- points

    def to_local(self, xyz_grid) -> np.ndarray:
        """Grid E, N, H (n, 3) m -> local (n, 3) m. Rows with a nan stay nan; rows outside the
        projection's domain come out not finite."""
        g = np.asarray(xyz_grid, dtype=float).reshape(-1, 3)
        out = np.full(g.shape, np.nan)
        ok = np.all(np.isfinite(g), axis=1)
        if ok.any():
            lon, lat = self._to_geo.transform(g[ok, 0], g[ok, 1])
            h = g[ok, 2] + self.geoid_undulation(lon, lat)
            with np.errstate(invalid="ignore"):  # outside the projection's domain: inf from PROJ -> nan
                out[ok] = (self._ecef(lon, lat, h) - self._xyz_ecef0) @ self.R_local_from_ecef.T
        return out

    def from_local(self, xyz_local) -> np.ndarray:
        """Local (n, 3) m -> grid E, N, H (n, 3) m (inverse of to_local). Rows with a nan stay nan."""
        q = np.asarray(xyz_local, dtype=float).reshape(-1, 3)
        out = np.full(q.shape, np.nan)
        ok = np.all(np.isfinite(q), axis=1)
        if ok.any():
            ecef = q[ok] @ self.R_local_from_ecef + self._xyz_ecef0
            lon, lat, h = self._cart.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2], direction="INVERSE")
            e, n = self._to_geo.transform(lon, lat, direction="INVERSE")
            out[ok] = np.column_stack([e, n, np.asarray(h) - self.geoid_undulation(lon, lat)])
        return out

    # ---------------------------------------------------------------------------- directions

    def R_local_from_grid(self, xyz_grid) -> np.ndarray:
        """Rotation taking the grid's axes at grid points (n, 3) (grid east, grid north, the ellipsoid
        normal) to the local frame: (n, 3, 3). The orthonormal part of :meth:`jacobian`."""
        g = np.asarray(xyz_grid, dtype=float).reshape(-1, 3)
        lon, lat = self._geodetic(g)
        R_ecef_from_enu = np.swapaxes(_R_enu_from_ecef(np.radians(lon), np.radians(lat)), -1, -2)
        R_enu_from_grid = np.swapaxes(_rz_plan(np.radians(self._convergence(lon, lat))), -1, -2)
        return self.R_local_from_ecef @ R_ecef_from_enu @ R_enu_from_grid

    def jacobian(self, xyz_grid) -> np.ndarray:
        """d xyz_local / d xyz_grid at grid points (n, 3) -> (n, 3, 3):
        ``R_local_from_grid diag(s_E, s_N, 1)`` with ``s_E = (1 + h/N_v) / k``, ``s_N = (1 + h/M) / k``
        (k the projection's point scale, conformal; M, N_v the radii of curvature in the meridian and
        the prime vertical; h the ellipsoidal height). The variation of the geoid undulation across a
        metre is neglected (below 1e-5)."""
        g = np.asarray(xyz_grid, dtype=float).reshape(-1, 3)
        lon, lat = self._geodetic(g)
        k = np.asarray(self._proj.get_factors(lon, lat).meridional_scale, dtype=float).reshape(-1)
        h = g[:, 2] + self.geoid_undulation(lon, lat)
        w = np.sqrt(1.0 - self._e2 * np.sin(np.radians(lat)) ** 2)
        n_v = self._a / w
        m = self._a * (1.0 - self._e2) / w**3
        scale = np.zeros((len(g), 3, 3))
        scale[:, 0, 0] = (1.0 + h / n_v) / k
        scale[:, 1, 1] = (1.0 + h / m) / k
        scale[:, 2, 2] = 1.0
        # grid east/north are true east/north turned by gamma: scale along the true axes, then turn
        R = self.R_local_from_grid(g)
        R_enu_from_grid = np.swapaxes(_rz_plan(np.radians(self._convergence(lon, lat))), -1, -2)
        return R @ np.swapaxes(R_enu_from_grid, -1, -2) @ scale @ R_enu_from_grid

    # ---------------------------------------------------------------------------- photos

    def rotations_to_local(self, xyz0_grid, R_grid_from_cam) -> np.ndarray:
        """R_local_from_cam = R_local_from_grid(O) R_grid_from_cam, O the centres (n, 3) in grid."""
        return self.R_local_from_grid(xyz0_grid) @ np.asarray(R_grid_from_cam, dtype=float)

    def rotations_to_grid(self, xyz0_local, R_local_from_cam) -> np.ndarray:
        """Inverse of rotations_to_local, the centres given in the local frame (n, 3)."""
        C = self.R_local_from_grid(self.from_local(xyz0_local))
        return np.swapaxes(C, -1, -2) @ np.asarray(R_local_from_cam, dtype=float)

    # ---------------------------------------------------------------------------- standard deviations

    def sigmas_to_local(self, xyz_grid, sigma_grid) -> np.ndarray:
        """Per-axis standard deviations at grid points: (n, 3), (n, 3) -> (n, 3), the square roots
        of the diagonal of ``J diag(sigma^2) J^T`` (J = :meth:`jacobian`; the correlations this
        creates are dropped: docs/decisions.md). Rows not all finite and > 0 are returned as given."""
        return _propagate_diagonal(self.jacobian(xyz_grid), sigma_grid)

    def sigmas_to_grid(self, xyz_local, sigma_local) -> np.ndarray:
        """Inverse of sigmas_to_local, the points given in the local frame."""
        return _propagate_diagonal(np.linalg.inv(self.jacobian(self.from_local(xyz_local))), sigma_local)

    def point_jacobian_to_grid(self, xyz_local) -> np.ndarray:
        """d xyz_grid / d xyz_local at points given in the local frame: (n, 3) -> (n, 3, 3), the
        inverse of :meth:`jacobian`. Rows of a point not all finite come out nan."""
        xyz = np.asarray(xyz_local, dtype=float).reshape(-1, 3)
        ok = np.all(np.isfinite(xyz), axis=1)
        J = np.linalg.inv(self.jacobian(self.from_local(np.where(ok[:, None], xyz, 0.0))))
        J[~ok] = np.nan
        return J

    def photo_jacobian_to_grid(self, xyz0_local, R_local_from_cam, convention: str) -> np.ndarray:
        """d (E0, N0, H0, angles_grid) / d (X0, Y0, Z0, angles_local) of photos (n, 3), (n, 3, 3) ->
        (n, 6, 6), angles in ``convention`` (rad). The grid angles depend on the centre too (the
        change of frame turns with the position, about 2e-7 rad per metre: meridian convergence and
        the direction of the ellipsoid normal); that block is taken by central differences over
        +-1 m (the rotation is smooth on the scale of the Earth's radius: truncation below 1e-13)."""
        xyz0 = np.asarray(xyz0_local, dtype=float).reshape(-1, 3)
        R = np.asarray(R_local_from_cam, dtype=float)
        R_grid = self.rotations_to_grid(xyz0, R)
        F = np.zeros((len(xyz0), 6, 6))
        F[:, :3, :3] = self.point_jacobian_to_grid(xyz0)
        F[:, 3:, 3:] = angle_change_jacobian(R, R_grid, convention)
        step = 1.0
        for j in range(3):
            dO = np.zeros(3)
            dO[j] = step
            d = (angles_from_R(self.rotations_to_grid(xyz0 + dO, R), convention)
                 - angles_from_R(self.rotations_to_grid(xyz0 - dO, R), convention))
            F[:, 3:, j] = (d + np.pi) % (2 * np.pi) - np.pi  # across +-pi: the short way
        F[:, 3:, :3] /= 2 * step
        return F

    def describe(self) -> str:
        o = self.origin
        return (f"topocentric at lat {o.lat:.6f}, lon {o.lon:.6f} deg, h = 0 on the ellipsoid; X along grid east there "
                f"(true east turned by the meridian convergence {o.gamma:.4f} deg), Z along the ellipsoid normal")

    def summary(self) -> dict:
        """summary.json's "frame" (docs/file-formats.md)."""
        s = self.settings
        out = {"crs": s.crs, "crs_name": self.crs.name, "heights": s.heights}
        if s.heights == "orthometric":
            out["geoid"] = (str(s.geoid_grid) if s.geoid_grid is not None else f"constant undulation {s.geoid_undulation!r} m")
        out.update({"local": self.describe(), "origin_lat_deg": self.origin.lat, "origin_lon_deg": self.origin.lon,
                    "convergence_deg": self.origin.gamma})
        return out


def angle_sigmas(R_from: np.ndarray, R_to: np.ndarray, sigma_angles: np.ndarray, convention: str) -> np.ndarray:
    """Per-axis standard deviations of the angles of ``R_to = C R_from`` (C a fixed change of frame)
    from those of ``R_from``: both perturb as ``R Exp(d)`` with the same camera-frame rotation
    vector d, so ``Cov(a_to) = J_to J_from^-1 Cov(a_from) J_from^-T J_to^T`` with
    J = rotations.angles_jacobian. (n, 3, 3), (n, 3, 3), (n, 3) rad -> (n, 3) rad (diagonal kept;
    rows not all finite and > 0 returned as given)."""
    return _propagate_diagonal(angle_change_jacobian(R_from, R_to, convention), sigma_angles)


def angle_change_jacobian(R_from: np.ndarray, R_to: np.ndarray, convention: str) -> np.ndarray:
    """d a_to / d a_from (n, 3, 3) for ``R_to = C R_from`` with C a fixed change of frame (see
    :func:`angle_sigmas`): ``J_to J_from^-1``, J = rotations.angles_jacobian."""
    return angles_jacobian(R_to, convention) @ np.linalg.inv(angles_jacobian(R_from, convention))


def _propagate_diagonal(J: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    sigma = np.asarray(sigma, dtype=float).reshape(-1, 3)
    observed = np.all(np.isfinite(sigma) & (sigma > 0), axis=1)
    out = sigma.copy()
    if observed.any():
        Jo = J[observed]
        out[observed] = np.sqrt(np.einsum("nij,nj->ni", Jo**2, sigma[observed] ** 2))
    return out


def _R_enu_from_ecef(lon, lat) -> np.ndarray:
    """Rows east, north, up of the ellipsoid's tangent frame at geodetic (lon, lat) in radians:
    (...,) -> (..., 3, 3)."""
    so, co, sa, ca = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    z = np.zeros_like(so)
    east = np.stack([-so, co, z], -1)
    north = np.stack([-sa * co, -sa * so, ca], -1)
    up = np.stack([ca * co, ca * so, sa], -1)
    return np.stack([east, north, up], -2)


def _rz_plan(gamma) -> np.ndarray:
    """Rows: grid east and grid north in true (east, north) axes, and up, for a grid north turned
    clockwise from true north by gamma (radians): (...,) -> (..., 3, 3) = R_grid_from_enu."""
    c, s = np.cos(gamma), np.sin(gamma)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)
