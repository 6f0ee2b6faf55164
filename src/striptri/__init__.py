"""striptri: analytical aerial triangulation after H. H. Schmid (BRL Report 961, 1955)."""

__version__ = "0.1.0"
