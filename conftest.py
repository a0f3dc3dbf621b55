"""pytest: the repository root is the Blender extension's package (its __init__.py imports bpy and the
glue relatively), not a test package: it is collected as a plain folder, so pytest never imports it,
whatever the checkout's folder is called (`hypergs-blender` is no valid package name)."""
import pytest


class _RootIsAFolder:
    @pytest.hookimpl(tryfirst=True)
    def pytest_collect_directory(self, path, parent):
        if path == parent.config.rootpath:
            return pytest.Dir.from_parent(parent, path=path)
        return None


def pytest_configure(config):
    config.pluginmanager.register(_RootIsAFolder(), "hypergs-root-is-a-folder")
