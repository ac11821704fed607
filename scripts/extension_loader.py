"""Load this repository as the extension package without installing it (scripts and tests).

Blender imports an installed extension as ``bl_ext.<repository>.garment_transfer``, and its modules
import each other relatively. Loading the repository root under a package name of our own keeps those
relative imports working from a checkout.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "garment_transfer_ext"


def load_extension(name=PACKAGE):
    """Import the repository root as package ``name`` (once) and return it; call ``register()`` on it
    to add the operators and the panel."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py",
                                                  submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
