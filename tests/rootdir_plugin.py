"""pytest plugin (loaded with `-p tests.rootdir_plugin`, see pyproject.toml): the repository root is
also the Blender extension's package, whose __init__.py imports bpy and the glue. pytest would set it
up as a test package, importing it under the checkout folder's name: that fails for a folder such as
`wt-blender` (not a Python name) and otherwise imports bpy into the test process. Collect the root as
a plain directory instead."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def pytest_collect_directory(path, parent):
    if path == ROOT:
        return pytest.Dir.from_parent(parent, path=path)
    return None
