"""`python -m striptri` runs the command line."""

from striptri._entry import main

main()
