"""Optional dependencies: the heavy packages only some jobs need live in pyproject.toml's extras,
so a plain `pip install spikesim` stays small. A job that needs one asks for it here and, when
it is missing, stops with one line naming the extra that installs it (an UnavailableError,
exit status 2 on the command line) instead of an ImportError traceback."""
from __future__ import annotations

import importlib
from types import ModuleType

from .errors import UnavailableError

#: Extra -> the modules it provides; kept equal to pyproject.toml's optional-dependencies
#: (tests/test_optional.py checks).
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib",),
    "train": ("tensorboard",),
    "video": ("imageio_ffmpeg",),
    "cluster": ("ray",),
}


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import `module` for `feature`, or raise an UnavailableError naming the extra to install.

    `extra` must be one of EXTRAS (a KeyError otherwise: a bug here, not the user's)."""
    if module.split(".")[0] not in EXTRAS[extra]:
        raise KeyError(f"{module} is not provided by the extra {extra!r}: {EXTRAS[extra]}")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise UnavailableError(f"{feature} needs {module}, which does not import here ({exc}); "
                               f"install it with: pip install 'spikesim[{extra}]'") from None


__all__ = ["EXTRAS", "require"]
