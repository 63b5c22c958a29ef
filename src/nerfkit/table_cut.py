"""How high above a capture's table its paint is cleared (:data:`TABLE_CUT`): plain Python, no
NumPy, so that the command line reads it at start-up (``nerfkit export --table-cut``'s default,
:class:`nerfkit.commands.options.ExportOptions`) without loading
:mod:`nerfkit.surroundings.clearing` (and torch), which uses it and re-exports it."""

from __future__ import annotations

# how high above a capture's table its paint is cleared, as a fraction of the object's height
TABLE_CUT = 0.05
