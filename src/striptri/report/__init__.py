"""report.html and its figures: the adjustment report (html), the figures, and the inactive, GNSS
and film sections."""
