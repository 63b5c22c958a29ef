"""The work of the pipeline's stages (:mod:`nerfkit.commands.pipeline`) in small functions:
what each stage decides, writes and reports. The commands and the Python API call them
through :mod:`~nerfkit.commands.pipeline`; nothing here parses a command line."""
