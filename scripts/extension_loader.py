"""Load this repository as the extension package without installing it (scripts and tests).

Blender imports an installed extension as ``bl_ext.<repository>.garment_transfer``, and its modules
import each other relatively (``from ..garment_transfer.mesh import ...``). Loading the repository root
under a package name of our own keeps those relative imports working from a checkout.

Where the core is installed from this same checkout (``pip install -e .``), the extension's core
subpackage is the installed ``garment_transfer`` itself, not a second copy: every
``<package>.garment_transfer[.module]`` the extension imports is the module of that name in
``garment_transfer``, so one process has one ``MeshError``, one model cache, one of everything.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "garment_transfer_ext"
CORE = "garment_transfer"


class _CoreAlias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves ``<prefix>.garment_transfer[.x]`` to the already importable ``garment_transfer[.x]``."""

    def __init__(self, prefix):
        self.prefix = prefix + "."

    def find_spec(self, fullname, path=None, target=None):
        if fullname == self.prefix + CORE or fullname.startswith(self.prefix + CORE + "."):
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        module = importlib.import_module(spec.name[len(self.prefix):])
        self._own_spec = module.__spec__
        return module

    def exec_module(self, module):
        # The import system has just set the alias's spec on the module: give it its own back.
        module.__spec__ = self._own_spec


def _installed_core_is_this_checkout() -> bool:
    spec = importlib.util.find_spec(CORE)
    return spec is not None and spec.origin is not None and \
        Path(spec.origin).resolve().parent == (ROOT / CORE).resolve()


def load_extension(name=PACKAGE):
    """Import the repository root as package ``name`` (once) and return it; call ``register()`` on it
    to add the operators and the panel."""
    if name in sys.modules:
        return sys.modules[name]
    if _installed_core_is_this_checkout():
        sys.meta_path.insert(0, _CoreAlias(name))
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
