"""The bundle's observation equations are the collinearity of :mod:`striptri.geometry.collinearity` (Schmid 14
and its analytic Jacobians, written once for the conditions, the bundle, the triangulation and the
resection). The names stay importable from here."""

from __future__ import annotations

from ..geometry.collinearity import CollinearityJacobians, collinearity_jacobians

RayJacobians = CollinearityJacobians  # the earlier name

__all__ = ["CollinearityJacobians", "RayJacobians", "collinearity_jacobians"]
