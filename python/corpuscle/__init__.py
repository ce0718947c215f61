__version__ = "0.1.0"

from .io import open  # noqa: E402,F401 - corpuscle.open(path) reads a recorded run
