"""pytest: the repository root is the extension's package (it has an __init__.py), not a test package; the lab
is imported from the checkout.

pytest would otherwise import the root __init__.py as a module named after the checkout's folder, which
fails wherever that name is no Python identifier (a clone into garment-transfer/, say).
"""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent
# The lab runs from the checkout (it is never installed): its tests import it from here.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


class _RootIsAPlainDirectory:
    # A plugin, not a conftest hook: pytest asks the hooks of the folder above the root how to collect
    # the root, and a conftest's hooks apply only from its own folder down.
    @pytest.hookimpl(tryfirst=True)
    def pytest_collect_directory(self, path, parent):
        if Path(path).resolve() == ROOT:
            return pytest.Dir.from_parent(parent, path=path)
        return None


def pytest_configure(config):
    config.pluginmanager.register(_RootIsAPlainDirectory(), "garment_transfer_root_directory")
