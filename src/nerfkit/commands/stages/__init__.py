"""The work of the pipeline's stages (:mod:`nerfkit.commands.pipeline`) and of the tools
around it (:mod:`nerfkit.commands.tools`) in small functions: what each stage decides, writes
and reports. The commands and the Python API call them through those two modules; nothing
here parses a command line."""
