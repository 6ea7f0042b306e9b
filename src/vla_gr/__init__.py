"""VLA-GR: language-conditioned robot navigation policies.

Egocentric RGB-D + an instruction in, continuous velocity commands out. See the
README for the two commands and DESIGN notes for the contracts between pieces.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vla-gr")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+local"

__all__ = ["__version__"]
