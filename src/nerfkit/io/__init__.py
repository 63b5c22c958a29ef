"""File output helpers: every file nerfkit writes goes through :mod:`nerfkit.io.atomic`."""
