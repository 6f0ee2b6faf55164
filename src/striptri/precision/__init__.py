"""Precision after an adjustment: the residuals' cofactors and w-tests (residuals), the collinearity
form of the bundle (collinearity_form), the covariance export and the GNSS unknowns' precision."""
