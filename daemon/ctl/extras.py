"""What each install extra gives ritactl's offline verbs, checked before a verb writes anything.

A verb that needs an extra calls :func:`require` first: every module the extra provides is
imported there, so a missing one exits 5 naming the extra (daemon/ctl/exitcodes.py) before
any file is opened, instead of a ModuleNotFoundError halfway through writing results (a
recompute's report.md written, its plot not). The distributions behind these modules are
pyproject.toml's extras; tests/system/test_extras.py checks that the two lists agree and
installs each extra in a clean venv.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

from daemon.ctl.exitcodes import missing_extra


@dataclass(frozen=True)
class Extra:
    """One pip extra as ritactl's verbs see it: the modules it brings (import name → distribution)."""

    name: str
    packages: str            # how the message names them
    modules: dict[str, str]  # import name → the distribution pyproject.toml lists


#: ``pip install 'rita[laptop]'``: recompute (the experiment's plot too) and the plate survey
LAPTOP = Extra("laptop", "numpy, OpenCV and matplotlib",
               {"numpy": "numpy", "cv2": "opencv-python-headless", "matplotlib": "matplotlib"})
#: ``pip install 'rita[console]'``: the operator console's web server
CONSOLE = Extra("console", "aiohttp", {"aiohttp": "aiohttp"})
EXTRAS = {e.name: e for e in (LAPTOP, CONSOLE)}


def require(verb: str, extra: Extra) -> None:
    """Import every module of ``extra``; a missing one raises CtlError (exit 5) naming the extra.

    Imported, not only looked up: a package that is present but broken (a half-removed
    install) fails here too, before the verb starts.
    """
    for module in extra.modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise missing_extra(verb, extra.name, extra.packages, exc) from None
