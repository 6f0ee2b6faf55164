"""`python -m striptri` runs the command line."""

from striptri.cli import main

main()
