"""The ``striptri`` command (DESIGN section 10), one module per command, each a thin layer over one
pipeline function: parse the options, call it, write its result. ``base`` holds the command group,
the error and signal handling every command shares (:func:`reports_errors`) and the option types."""

from striptri.cli.base import (  # noqa: F401  (the command group, and what tests and scripts reach)
    EXIT_INPUT,
    EXIT_NUMERICAL,
    _raise_on_signals,
    _restore_signals,
    main,
    reports_errors,
)
from striptri.cli import adjust, compare, convert, match, plan, simulate, structure  # noqa: F401,E402  (register the commands)
